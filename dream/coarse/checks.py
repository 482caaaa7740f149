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
from dream.robot.tree import KinematicTree
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
    basin_ious: np.ndarray | None = None


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
    `jackknife_groups` frame groups left out and with each link in view (each group of
    neighbouring links, `link_groups`) left out: (G, 6) and (L, 6) increments from `T_best`,
    and the L links (a group's names joined by "+", in `tree_order`); (0, 6) where there
    are fewer than `MIN_GROUPS` groups of a kind (or `jackknife_groups` is 0)."""
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
    counts = links_in_view(P, meshes, usable, camera, T_best, settings.jackknife_link_points)
    rank = tree_order(meshes.robot.tree)
    counts = dict(sorted(counts.items(), key=lambda item: rank[meshes.links[item[0]]]))
    groups_of_links = link_groups(counts, settings.jackknife_link_groups)
    links_xi = np.array([refined(every, usable & ~np.isin(meshes.vertex_link, group))
                         for group in groups_of_links]) if len(groups_of_links) >= MIN_GROUPS \
        else none
    names = tuple("+".join(meshes.links[k] for k in group) for group in groups_of_links)
    return frames_xi, links_xi, names if len(links_xi) else ()


def tree_order(tree: KinematicTree) -> dict[str, int]:
    """Each link's place in a depth-first walk of the kinematic tree from its root (children
    in the URDF's order): a chain's links follow each other, whatever order the file lists
    them in.

    >>> from dream.robot import load_robot
    >>> order = tree_order(load_robot("panda").tree)
    >>> order["panda_link0"], order["panda_link1"] < order["panda_hand"]
    (0, True)
    """
    children: dict[str, list[str]] = {}
    for joint in tree.joints:
        children.setdefault(joint.parent, []).append(joint.child)
    order: dict[str, int] = {}
    stack = [tree.root]
    while stack:
        link = stack.pop()
        order[link] = len(order)
        stack.extend(reversed(children.get(link, [])))
    return order


def link_groups(counts: dict[int, int], most: int) -> list[list[int]]:
    """The links in view (`counts`: link index -> its usable points in the image, in the
    kinematic tree's order, `tree_order`) as at most `most` groups of neighbours in that
    order, each about an equal
    share of the points: one link a group where they are few. The delete-one jackknife scales
    its groups' scatter by their number, so on a robot of a hundred small links (fingers,
    casters) the finish's own scatter would dwarf what any link says.

    >>> link_groups({0: 10, 1: 10, 2: 10}, 5)
    [[0], [1], [2]]
    >>> link_groups({0: 40, 1: 5, 2: 5, 3: 30, 4: 20}, 3)
    [[0], [1, 2, 3], [4]]
    >>> link_groups({0: 1000, 1: 5, 2: 5, 3: 5}, 3)        # never fewer than MIN_GROUPS
    [[0, 1], [2], [3]]
    """
    links = list(counts)
    if len(links) <= most:
        return [[k] for k in links]
    cumulative = np.cumsum([counts[k] for k in links], dtype=float)
    share = cumulative / cumulative[-1]
    # the group of each link: which of `most` equal shares its points' middle falls in
    middle = share - np.array([counts[k] for k in links]) / cumulative[-1] / 2
    which = np.minimum((middle * most).astype(int), most - 1)
    groups = [[k for k, g in zip(links, which, strict=True) if g == group]
              for group in np.unique(which)]
    if len(groups) >= MIN_GROUPS:
        return groups
    # one link holds most of the points: as many groups of as many links each instead
    return [[int(k) for k in part] for part in np.array_split(np.array(links), most)]


def links_in_view(P: np.ndarray, meshes: RobotMeshes, usable: np.ndarray,
                  camera: CameraIntrinsics, T_cam_base: np.ndarray, min_points: int
                  ) -> dict[int, int]:
    """The links with at least `min_points` usable vertex projections inside the image over
    the frames at `T_cam_base` (the links whose outline can shape the pose), each with that
    count, in the order of `meshes.links`."""
    uv = project(camera, transform_points(T_cam_base, P))          # (F, V, 2)
    inside = camera.in_image(uv) & usable[None]
    counts = np.bincount(np.broadcast_to(meshes.vertex_link, inside.shape)[inside],
                         minlength=len(meshes.links))
    return {k: int(counts[k]) for k in range(len(meshes.links)) if counts[k] >= min_points}
