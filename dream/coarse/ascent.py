"""The masks' IoU climbed along the pose's own uncertainty (pure).

The search's finish is a silhouette polish: it moves the outline onto the masks' contour
points. Where something the robot model lacks lies next to the outline (a held object), those
points stop it short of the pose that explains the masks best: on rendered scenes with a held
object the IoU rose steadily along the straight line from the pose written, 11-28 mm off,
towards the truth. A coordinate search on the IoU from there gets nowhere (at most 1.1 mm
nearer over steps of 8 px down to 0.25 px along the camera's axes): the rise follows a ridge,
a combination of moves that no single axis makes.

The pose's covariance (the jackknife's spread over frame groups and links, the restarts', the
image cues' disagreement) has its largest axes along the combinations of moves the masks
determine least, which is where such a ridge runs. So the IoU is climbed by a pattern search in
the covariance's whitened basis: a step of `ascent_steps_sigma` of each principal axis's
1-sigma, either way along each axis in turn, kept where the IoU rises, until no step rises;
then the next, smaller step. The climb stays inside the covariance's `ascent_max_chi2`
ellipsoid around its start and scores at most `ascent_max_evaluations` poses. Where it ends
against that ellipsoid's wall with the IoU still rising through it, the IoU's optimum lies
farther off than the pose's own spread allows: the masks hold something the model does not
explain that pulls the pose along, and the climb is not kept.

    >>> import numpy as np
    >>> Ascent(0.61, 0.63, 40, 1.5, 0.004, 0.001, True, np.eye(4)).to_dict()["iou_after"]
    0.63
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.calibration import MOTION_MASKS, SearchMasks
from dream.coarse.scales import Scales
from dream.coarse.search import finish_scale
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.metrics import pose_errors
from dream.pnp import apply_increment
from dream.silhouette import vertices_in_base

MIN_VARIANCE = 1e-18    # principal axes with less variance than this are not climbed along


@dataclass(frozen=True)
class Ascent:
    """The climb's outcome: the IoU at its start and end, the poses scored, how far it moved
    (`mahalanobis`: in units of the covariance's 1-sigma; `moved_m`, `moved_rad`: camera
    centre and rotation), whether it is `kept` (`ascend`) and the pose to write, `T_cam_base`:
    where it ended, or where it started where it is not kept."""

    iou_before: float
    iou_after: float
    evaluations: int
    mahalanobis: float
    moved_m: float
    moved_rad: float
    kept: bool
    T_cam_base: np.ndarray

    def __post_init__(self) -> None:
        if self.iou_after < self.iou_before or self.evaluations < 1 or self.mahalanobis < 0:
            raise InputError("an ascent ends no lower than it starts, after at least one pose "
                             "scored, at a non-negative distance")

    def to_dict(self) -> dict:
        return {"iou_before": self.iou_before, "iou_after": self.iou_after,
                "evaluations": self.evaluations, "mahalanobis": self.mahalanobis,
                "moved_m": self.moved_m, "moved_rad": self.moved_rad, "kept": self.kept}


def whitened_axes(covariance: np.ndarray) -> np.ndarray:
    """(6, K) the covariance's principal axes scaled to their 1-sigma, largest first (axes of
    no variance left out): a move of x (K,) in their units is the increment `axes @ x`.

    >>> whitened_axes(np.diag([4.0, 1.0, 0, 0, 0, 9.0])).round(6).T.tolist()
    [[0.0, 0.0, 0.0, 0.0, 0.0, 3.0], [2.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0]]
    """
    C = np.asarray(covariance, dtype=float)
    if C.shape != (6, 6) or not np.all(np.isfinite(C)):
        raise InputError(f"the covariance has shape {C.shape}, expected a finite (6, 6)")
    variance, axes = np.linalg.eigh((C + C.T) / 2)
    order = np.argsort(variance)[::-1]
    kept = order[variance[order] > MIN_VARIANCE]
    return axes[:, kept] * np.sqrt(variance[kept])


def ascend(iou: Callable[[np.ndarray], float], T_cam_base: np.ndarray, covariance: np.ndarray,
           settings: SearchSettings | None = None) -> Ascent:
    """The pattern search of the module doc on `iou` (a pose's score, T_cam_base -> float) from
    `T_cam_base` along the principal axes of `covariance` (6, 6; xi of `dream.pnp`). Where it
    ends against the ellipsoid's wall and a smallest step through the wall still raises the
    IoU, the masks' optimum lies outside what the pose's own spread allows (something in the
    masks the model does not explain pulls it away): the climb is not kept."""
    settings = settings or SearchSettings()
    T_start = np.asarray(T_cam_base, dtype=float)
    axes = whitened_axes(covariance)
    budget = _Budget(iou, T_start, axes, settings.ascent_max_evaluations)
    x = np.zeros(axes.shape[1])
    best = start_iou = budget.score(x)
    for step in settings.ascent_steps_sigma:
        improved = True
        while improved and budget.left():
            improved = False
            for trial in _steps(x, step):
                if trial @ trial <= settings.ascent_max_chi2 and budget.left():
                    score = budget.score(trial)
                    if score > best:
                        best, x, improved = score, trial, True
    walled = [t for t in _steps(x, settings.ascent_steps_sigma[-1])
              if t @ t > settings.ascent_max_chi2]
    kept = not any(budget.left() and budget.score(t) > best for t in walled)
    T = apply_increment(T_start, axes @ x)
    m, rad = pose_errors(T, T_start)
    return Ascent(float(start_iou), float(best), budget.used, float(np.sqrt(x @ x)), float(m),
                  float(rad), kept, T if kept else T_start)


def _steps(x: np.ndarray, step: float) -> list[np.ndarray]:
    """x moved by `step` either way along each axis in turn."""
    trials = []
    for k in range(len(x)):
        for sign in (1.0, -1.0):
            trial = x.copy()
            trial[k] += sign * step
            trials.append(trial)
    return trials


class _Budget:
    """The IoU of moves x (in the whitened axes' units) from T_start, counted against the
    climb's budget of poses scored."""

    def __init__(self, iou: Callable[[np.ndarray], float], T_start: np.ndarray,
                 axes: np.ndarray, limit: int):
        self.iou, self.T_start, self.axes, self.limit = iou, T_start, axes, limit
        self.used = 0

    def left(self) -> bool:
        return self.used < self.limit

    def score(self, x: np.ndarray) -> float:
        self.used += 1
        return float(self.iou(apply_increment(self.T_start, self.axes @ x)))


def ascended(camera: CameraIntrinsics, inputs: SearchMasks, T_cam_base: np.ndarray,
             covariance: np.ndarray, settings: SearchSettings | None = None,
             progress: Callable[[str], None] | None = None) -> Ascent:
    """`ascend` on the search's masks at the finish scale (every frame of the finish, what the
    arm carries left out, the pixels the robot holds in most frames too with motion masks)."""
    settings = settings or SearchSettings()
    start = time.perf_counter()
    finish: Scales = finish_scale(vertices_in_base(inputs.meshes, inputs.joints), inputs.meshes,
                                  inputs.masks, camera, settings,
                                  held=inputs.source == MOTION_MASKS, region=inputs.region)
    ascent = ascend(finish.iou, T_cam_base, covariance, settings)
    if progress is not None:
        progress(f"IoU climbed along the pose's 1-sigma axes: {ascent.iou_before:.4f} -> "
                 f"{ascent.iou_after:.4f}, moved {ascent.moved_m * 1e3:.1f} mm and "
                 f"{np.rad2deg(ascent.moved_rad):.2f} deg ({ascent.mahalanobis:.1f} sigma, "
                 f"{ascent.evaluations} poses, {time.perf_counter() - start:.1f} s)"
                 + ("" if ascent.kept else "; still rising through the ellipsoid's wall: "
                    "not kept"))
    return ascent
