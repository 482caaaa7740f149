"""The masks of the coarse search at each of its scales, and its silhouette polish there: the
rendered IoU of a pose and the polish's refinement with its round check; `finish_scale`, the one
scale its winner is finished at (pure; `dream.coarse.search`).

Where the arm carries something the URDF lacks, single frames' motion masks go wrong more
often (the object hides part of the arm, or what its carving missed joins the outline), and a
few such frames can hold the finish off the pose the others agree on: on a rendered scene with
a held object, the IoU and the contour cost were both better at the truth than at the finish's
pose, 17 mm off, and three frames pulled it there. So with a carried region the finish measures
each frame's pull on its pose (`frame_influence`) and, where some frames pull far harder than
the median frame (`outlying_frames`), finishes again without them.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.carried import CarriedRegion
from dream.coarse.evidence import held_pixels, held_vertices, region_vertices
from dream.coarse.settings import SearchSettings
from dream.polish.objective import (
    Contour,
    Objective,
    scaled_camera,
    select_contour,
    shrink_mask,
    signed_distance,
)
from dream.polish.refine import refine_pose
from dream.polish.settings import PolishSettings
from dream.silhouette import RobotMeshes, render_frames, silhouette_iou

log = logging.getLogger(__name__)

# The silhouettes of the last poses rendered, kept per `Scales`: a finish renders the pose it
# ends at again to score it (its IoU, the found test's, its contour points), and a refinement
# renders the pose it starts from after its caller did.
RENDERS_KEPT = 4


class Scales:
    """The masks at each local scale, and the rendered IoU of a pose at the finest. With
    `held` (motion masks), the pixels the robot covers in more than half of the frames at a
    pose are the background model's (`held_pixels`): the vertices that lie there
    (`held_vertices`) give the refinement no contour points, and the pixels are taken out of
    the silhouettes scored. With `region` (what the arm carries), its pixels at a pose are
    taken out of both the silhouettes and the masks scored, and the vertices that project
    there in a frame are no contour points of that frame. With `outliers` (the factor and
    the share of `outlying_frames`), each refinement ends with the frames that pull its pose
    far harder than the others left out (module doc)."""

    def __init__(self, P: np.ndarray, meshes: RobotMeshes, masks: np.ndarray,
                 camera: CameraIntrinsics, settings: SearchSettings, usable: np.ndarray | None,
                 held: bool = False, region: CarriedRegion | None = None,
                 outliers: tuple[float, float] | None = None):
        self.P, self.faces, self.usable, self.held = P, meshes.faces, usable, held
        self.region, self.outliers = region, outliers
        self.levels = []
        for width in dict.fromkeys(min(w, camera.width) for w in settings.local_widths_px):
            height = max(1, int(round(camera.height * width / camera.width)))
            small = scaled_camera(camera, width, height)
            self.levels.append((small, np.stack([shrink_mask(m, width, height)
                                                 for m in masks])))
        self.params = replace(PolishSettings(), outer_iterations=settings.local_rounds)
        self.iou_tolerance = settings.round_iou_tolerance
        self._distances: dict[int, np.ndarray] = {}
        self._objectives: dict[int, Objective] = {}
        self._renders: dict[tuple[int, bytes], _AtPose] = {}

    def distances(self, level: int) -> np.ndarray:
        """(F, h, w) the `signed_distance`s of the masks at `level`, computed once."""
        level = range(len(self.levels))[level]
        if level not in self._distances:
            self._distances[level] = np.stack([signed_distance(m)
                                               for m in self.levels[level][1]])
        return self._distances[level]

    def objective(self, level: int) -> Objective:
        """The polish's `Objective` on the masks at `level` (its camera), built once."""
        level = range(len(self.levels))[level]
        if level not in self._objectives:
            self._objectives[level] = Objective(self.distances(level), self.levels[level][0],
                                                self.params)
        return self._objectives[level]

    def _at_pose(self, T: np.ndarray, level: int) -> _AtPose:
        """What `level` shows at `T`: kept from one of the last `RENDERS_KEPT` poses asked
        for, or new."""
        level = range(len(self.levels))[level]
        key = (level, np.ascontiguousarray(T, dtype=float).tobytes())
        at = self._renders.pop(key, None)
        if at is None:
            at = _AtPose(render_frames(self.P, self.faces, T, self.levels[level][0]))
            at.rendered.flags.writeable = False
        self._renders[key] = at
        while len(self._renders) > RENDERS_KEPT:
            del self._renders[next(iter(self._renders))]
        return at

    def _rendered(self, T: np.ndarray, level: int) -> np.ndarray:
        """(F, h, w) the silhouettes at `level` from `T`, read-only."""
        return self._at_pose(T, level).rendered

    def _usable_at(self, T: np.ndarray, level: int
                   ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """`_usable` at `level` from `T`, worked out once for the silhouettes kept there."""
        at = self._at_pose(T, level)
        if at.usable is None:
            at.usable = self._usable(T, self.levels[level][0], at.rendered)
        return at.usable

    def refine(self, T: np.ndarray, levels: slice = slice(None)) -> np.ndarray:
        """The silhouette polish at each of `levels` in turn; a round that lowers the IoU at
        its level by more than `round_iou_tolerance` is undone and ends that level
        (`refine_pose`'s `keep`)."""
        return self.refine_reporting(T, levels)[0]

    def refine_reporting(self, T: np.ndarray, levels: slice = slice(None)
                         ) -> tuple[np.ndarray, np.ndarray]:
        """`refine`, and the positions among `P` of the frames its end left out (sorted; empty
        where none pulled far harder than the others, or where leaving them out did not
        explain all the masks better)."""
        for level in range(len(self.levels))[levels]:
            camera, masks = self.levels[level]
            rendered = self._rendered(T, level)
            usable, ignored = self._usable_at(T, level)
            T = refine_pose(self.P, self.faces, masks, camera, T, self.params, usable, NoWorse(
                self, level, self.iou_of(rendered, level, T, ignored), self.iou_tolerance),
                self.objective(level), partial(self._rendered, level=level))[0]
        return (T, np.zeros(0, int)) if self.outliers is None \
            else self._without_outlying_frames(T)

    def _without_outlying_frames(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The finest level's refinement again from `T` without the frames that pull `T` far
        harder than the others (`outlying_frames`), kept where it explains all the frames'
        masks better (their IoU at the finest level); `T` where no frame pulls so or it does
        not (a frame that pulls hard can also be right: on a rendered scene with a held
        object, without this guard, the search ended 13.5 mm off at an IoU of 0.5345 where it
        had ended 7.7 mm off at 0.5355); with the frames left out (empty where none)."""
        influence = frame_influence(self.objective(-1), self.contour(T), T, len(self.P))
        drop = outlying_frames(influence, *self.outliers)
        if not len(drop):
            return T, drop
        log.info("finish again without %d of %d frames that pull the pose %.0f-%.0fx as hard "
                 "as the median frame", len(drop), len(self.P),
                 influence[drop].min() / np.median(influence),
                 influence[drop].max() / np.median(influence))
        T_kept = self.frames(np.setdiff1d(np.arange(len(self.P)), drop)).refine(
            T, slice(-1, None))
        return (T_kept, drop) if self.iou(T_kept) > self.iou(T) else (T, np.zeros(0, int))

    def frames(self, keep: np.ndarray) -> Scales:
        """These scales on the frames `keep` only, without the outlying-frames check."""
        out = copy.copy(self)
        out.P = self.P[keep]
        out.levels = [(camera, masks[keep]) for camera, masks in self.levels]
        out._distances = {level: d[keep] for level, d in self._distances.items()}
        out._objectives, out._renders = {}, {}
        out.region = None if self.region is None else self.region.frames(keep)
        if self.usable is not None and self.usable.ndim == 2:
            out.usable = self.usable[keep]
        out.outliers = None
        return out

    def _usable(self, T: np.ndarray, camera: CameraIntrinsics, rendered: np.ndarray
                ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(the vertices that may be contour points at T, per frame where it varies; the
        carried region's pixels at T, None without one) at a level's `camera`, given the
        silhouettes `rendered` there (class doc)."""
        usable = self.usable
        if self.held:
            held = held_vertices(self.P, T, camera, held_pixels(rendered))
            usable = ~held if usable is None else usable & ~held
        ignored = None if self.region is None else self.region.pixels(T, camera)
        if ignored is not None:
            out = ~region_vertices(self.P, T, camera, ignored)
            usable = out if usable is None else usable & out
        return usable, ignored

    def contour(self, T: np.ndarray) -> Contour:
        """The finest level's contour points at T, as its refinement selects them."""
        return select_contour(self.P, self.faces, T, self.levels[-1][0], self.params,
                              self._usable_at(T, -1)[0], self._rendered(T, -1))

    def iou_at(self, T: np.ndarray, level: int) -> float:
        return self.iou_of(self._rendered(T, level), level, T)

    def iou_of(self, rendered: np.ndarray, level: int, T: np.ndarray,
               ignored: np.ndarray | None = None, keep_held: bool = False) -> float:
        """The mean IoU of silhouettes (F, h, w) rendered at `level`'s camera from `T` with
        its masks (without the pixels held in most frames, with `held` unless `keep_held`;
        without the carried region's, with `region`: `ignored`, where its pixels at `T` are
        already rendered)."""
        camera, masks = self.levels[level]
        if self.held and not keep_held:
            rendered = rendered & ~held_pixels(rendered)[None]
        if self.region is not None:
            kept = ~(self.region.pixels(T, camera) if ignored is None else ignored)
            rendered, masks = rendered & kept, masks & kept
        return float(np.mean([silhouette_iou(r, m) for r, m in zip(rendered, masks,
                                                                   strict=True)]))

    def iou(self, T: np.ndarray) -> float:
        return self.iou_at(T, -1)

    def found_iou(self, T: np.ndarray) -> float:
        """`iou` with the pixels held in most frames kept in the silhouettes: what the found
        test reads besides it (`SearchSettings.robot_found`). Where a link turns in place or
        an arm's colours shift as it moves, the motion masks hold much of what the silhouettes
        cover in most frames (at the right pose of rendered scenes: 33-72 % of those pixels
        in 11 of 16), and scored against silhouettes without them, the right pose's IoU falls
        below the found test (a PR2 3 m away: 0.30; with them, 0.66). Kept in the silhouettes
        and not left out of the masks, they count against a pose whose masks miss them."""
        return self.iou_of(self._rendered(T, -1), -1, T, keep_held=True)


@dataclass(eq=False)
class _AtPose:
    """The silhouettes of a `Scales` level at one pose (read-only) and, once asked for, the
    vertices that may be contour points there (`Scales._usable_at`)."""

    rendered: np.ndarray
    usable: tuple[np.ndarray | None, np.ndarray | None] | None = None


class NoWorse:
    """`refine_pose`'s `keep` at one of `Scales`' levels: a round's pose is kept where its
    IoU there lies less than `tolerance` below the best so far (a sub-pixel step moves the IoU
    up or down by whole pixels)."""

    def __init__(self, scales: Scales, level: int, start_iou: float, tolerance: float):
        self.scales, self.level, self.tolerance = scales, level, tolerance
        self.best = start_iou

    def __call__(self, T: np.ndarray, silhouettes: np.ndarray) -> bool:
        iou = self.scales.iou_of(silhouettes, self.level, T)
        if iou < self.best - self.tolerance:
            return False
        self.best = max(self.best, iou)
        return True


def finish_scale(P: np.ndarray, meshes: RobotMeshes, masks: np.ndarray,
                 camera: CameraIntrinsics, settings: SearchSettings,
                 usable: np.ndarray | None = None, held: bool = False,
                 region: CarriedRegion | None = None) -> Scales:
    """The one scale the winner is finished at (its IoU is still scored at the local scales'
    finest, as its rivals'): `finish_width_px` (capped at the
    camera's width) on the frames of `P` (F, V, 3) and `masks` (F, H, W); with a carried
    `region`, its refinements end without the outlying frames (`SearchSettings.
    frame_influence`, module doc)."""
    outliers = ((settings.frame_influence, settings.max_outlying_share)
                if region is not None and settings.frame_influence > 0 else None)
    return Scales(P, meshes, masks, camera, replace(
        settings, local_widths_px=(settings.finish_width_px,)), usable, held, region, outliers)


def frame_influence(objective: Objective, contour: Contour, T: np.ndarray, frames: int
                    ) -> np.ndarray:
    """(frames,) each frame's pull on the pose `T`: g_f' H^+ g_f, where g_f is the gradient
    of the frame's contour residuals' robust cost (IRLS weights of `objective`) and H the
    Gauss-Newton matrix of all of them, i.e. how far (in the fit's own metric) the step that
    frame alone asks for would move the pose. 0 for a frame without contour points, all 0
    where the points cannot be projected."""
    out = objective.residuals(contour, T, jacobian=True)
    if out is None:
        return np.zeros(frames)
    r, J = out
    w = objective.weight(r)
    g = np.zeros((frames, J.shape[1]))
    np.add.at(g, contour.frame, J * (w * r)[:, None])
    H = J.T @ (J * w[:, None])
    return np.einsum("fi,ij,fj->f", g, np.linalg.pinv(H), g)


def outlying_frames(influence: np.ndarray, factor: float, max_share: float) -> np.ndarray:
    """The frames whose `influence` (F,) exceeds `factor` x the median frame's, at most
    `max_share` of the frames (the largest), sorted.

    >>> outlying_frames(np.array([1.0, 1.2, 0.9, 30.0, 1.1, 12.0]), 10.0, 0.2).tolist()
    [3]
    >>> outlying_frames(np.array([1.0, 1.2, 0.9, 30.0, 1.1, 12.0]), 10.0, 0.5).tolist()
    [3, 5]
    """
    influence = np.asarray(influence, float)
    median = float(np.median(influence)) if len(influence) else 0.0
    if not median > 0:
        return np.zeros(0, int)
    over = np.flatnonzero(influence > factor * median)
    most = int(max_share * len(influence))
    return np.sort(over[np.argsort(influence[over])[::-1][:most]])
