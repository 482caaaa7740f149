"""The checks of a coarse search's winner (step 4 of `dream.coarse.search`'s module doc;
pure): the basin check's restarts around it and the jackknives of its finish over frame
groups and over links left out.

    >>> rng = np.random.default_rng(0)
    >>> ends = basin_ends(lambda T: T, np.eye(4), SearchSettings(basin_starts=3), rng, 0.05)
    >>> ends.shape, round(float(np.linalg.norm(ends[0, :3, 3])), 3)
    ((3, 4, 4), 0.05)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.coarse.carried import CarriedRegion
from dream.coarse.scales import finish_scale
from dream.coarse.settings import SearchSettings
from dream.pnp import increment_between
from dream.refined_uncertainty import MIN_GROUPS, frame_groups
from dream.silhouette import RobotMeshes
from dream.transforms import R_from_rotvec, invert_T, transform_points


@dataclass(frozen=True)
class Checks:
    """Step 4 of the module doc: the basin check and the jackknives (`SearchOutcome`'s fields
    of the same names)."""

    basin_ends: np.ndarray
    basin_returned: int
    frames_xi: np.ndarray
    links_xi: np.ndarray
    jackknife_links: tuple[str, ...]
    basin_m: float
    basin_return_m: float


def basin_ends(refine: Callable[[np.ndarray], np.ndarray], T_best: np.ndarray,
               settings: SearchSettings, rng: np.random.Generator, start_m: float
               ) -> np.ndarray:
    """(basin_starts, 4, 4) where `refine` (the winner's own refinement) ends from starts
    `start_m` / `basin_rad` from T_best in random directions."""
    T_base_cam = invert_T(T_best)
    ends = []
    for _ in range(settings.basin_starts):
        T = T_base_cam.copy()
        T[:3, 3] += start_m * _unit(rng)
        T[:3, :3] = T_base_cam[:3, :3] @ R_from_rotvec(settings.basin_rad * _unit(rng))
        ends.append(refine(invert_T(T)))
    return np.array(ends).reshape(-1, 4, 4)


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def jackknife(P: np.ndarray, meshes: RobotMeshes, masks: np.ndarray,
              camera: CameraIntrinsics, settings: SearchSettings, usable: np.ndarray | None,
              held: bool, T_best: np.ndarray, region: CarriedRegion | None = None
              ) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """The winner's finish at `finish_width_px`, from `T_best`, with each of the
    `jackknife_groups` frame groups left out and with each link in view left out: (G, 6) and
    (L, 6) increments from `T_best`, and the L links; (0, 6) where there are fewer than
    `MIN_GROUPS` groups of a kind (or `jackknife_groups` is 0)."""
    none = np.zeros((0, 6))
    if not settings.jackknife_groups:
        return none, none, ()
    usable = np.ones(len(meshes.vertices), bool) if usable is None else np.asarray(usable)

    def refined(frames: np.ndarray, use: np.ndarray) -> np.ndarray:
        scales = finish_scale(P[frames], meshes, masks[frames], camera, settings, use, held,
                              None if region is None else region.frames(frames))
        return increment_between(T_best, scales.refine(T_best))

    every = np.arange(len(P))
    groups = frame_groups(len(P), settings.jackknife_groups)
    frames_xi = np.array([refined(np.setdiff1d(every, members), usable)
                          for members in groups.values()]) if len(groups) >= MIN_GROUPS \
        else none
    links = links_in_view(P, meshes, usable, camera, T_best, settings.jackknife_link_points)
    links_xi = np.array([refined(every, usable & (meshes.vertex_link != k))
                         for k in links]) if len(links) >= MIN_GROUPS else none
    return frames_xi, links_xi, tuple(meshes.links[k] for k in links) if len(links_xi) else ()


def links_in_view(P: np.ndarray, meshes: RobotMeshes, usable: np.ndarray,
                  camera: CameraIntrinsics, T_cam_base: np.ndarray, min_points: int
                  ) -> list[int]:
    """The links with at least `min_points` usable vertex projections inside the image over
    the frames at `T_cam_base` (the links whose outline can shape the pose)."""
    uv = project(camera, transform_points(T_cam_base, P))          # (F, V, 2)
    inside = camera.in_image(uv) & usable[None]
    counts = np.bincount(np.broadcast_to(meshes.vertex_link, inside.shape)[inside],
                         minlength=len(meshes.links))
    return [k for k in range(len(meshes.links)) if counts[k] >= min_points]
