"""Whether a polished pose is kept: the IoU gain and the keypoint guard.

The silhouette IoU (exact rasterisation, full resolution) is measured on every frame given
before and after. The polished pose is kept only when the mean IoU grows by more than
`min_iou_gain` and the keypoint fit is not broken (`KeypointGuard`, `decide`):
- "rmse" (a fixed camera, all frames): the RMS reprojection error of the calibration's
  inlier keypoints stays within max(`max_rmse_factor` x before, before + `rmse_margin_px`).
- "all-median" (a fixed camera, all frames; `polish_calibration`): the median pixel distance
  of all the keypoint detections, inliers of the keypoint fit or not, stays within
  max(`max_median_factor` x before, before + `median_margin_px`); and, where the keypoint fit
  kept at least half of the detections (`dream.quality.MIN_KEPT_SHARE`), the RMSE of its
  inliers follows the "rmse" rule too. A keypoint fit that kept a small consensus of a biased
  set may fit its inliers closely at a wrong pose; their RMSE would then refuse every pose
  that leaves them, the right one included. A fit that kept most detections is trusted, and
  the median of all detections alone is too loose along the optical axis.
- "median" (one frame's own pose, `--frames each`): the median pixel distance of the frame's
  n inlier keypoints may reach at most its value at the keypoint pose divided by
  `fit_shrinkage(n)` = sqrt((2n - 6) / 2n), plus `frame_median_margin_px`. A single frame's
  4-7 keypoints fix its 6 pose parameters with little redundancy: the fit follows a
  misplaced keypoint and leaves the others' residuals near zero, so any better pose raises
  the RMSE by far more than the noise; and the fit absorbs part of the noise itself (half
  of it, in RMS, for 4 keypoints), which the division gives back. The median still rises
  when the pose leaves most of the keypoints, as it does when silhouette and keypoints
  disagree.
- "none" (a fixed camera, all frames, masks that come with the data): masks a person or a
  segmentation made for these images are evidence of their own, so detections that disagree
  with the polished pose do not veto it; their median distance is reported as the detector's
  disagreement (`dream.polish.calibration`). Masks the tool made itself (the network's mask
  head, motion masks) keep the "all-median" guard.
Otherwise the keypoint pose is kept and the reason says why.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.errors import InputError
from dream.polish.settings import PolishSettings


@dataclass(frozen=True)
class KeypointSet:
    """The keypoint observations that guard the polish: inliers of the calibration.

    Attributes:
        P_base: (N, 3) keypoint positions in the base frame, m.
        uv: (N, 2) their observed pixels.
    """

    P_base: np.ndarray
    uv: np.ndarray

    def __post_init__(self) -> None:
        P = np.array(self.P_base, dtype=float)
        uv = np.array(self.uv, dtype=float)
        if P.ndim != 2 or P.shape[1] != 3 or uv.shape != (len(P), 2):
            raise InputError(f"keypoints have shapes {P.shape} and {uv.shape}, expected (N, 3) "
                             "and (N, 2)")
        if len(P) == 0 or not (np.all(np.isfinite(P)) and np.all(np.isfinite(uv))):
            raise InputError("the keypoint guard needs at least one finite observation")
        P.setflags(write=False)
        uv.setflags(write=False)
        object.__setattr__(self, "P_base", P)
        object.__setattr__(self, "uv", uv)

    def distances_px(self, camera: CameraIntrinsics, T_cam_base: np.ndarray) -> np.ndarray:
        """(N,) pixel distances between the projections at `T_cam_base` and the observations
        (inf where a point does not project)."""
        uv = project(camera, self.P_base @ T_cam_base[:3, :3].T + T_cam_base[:3, 3])
        d = np.linalg.norm(uv - self.uv, axis=1)
        return np.where(np.isfinite(d), d, np.inf)

    def rmse_px(self, camera: CameraIntrinsics, T_cam_base: np.ndarray) -> float:
        """RMS pixel distance between the projections at `T_cam_base` and the observations."""
        return float(np.sqrt(np.mean(self.distances_px(camera, T_cam_base) ** 2)))

    def median_px(self, camera: CameraIntrinsics, T_cam_base: np.ndarray) -> float:
        """Median pixel distance between the projections and the observations."""
        return float(np.median(self.distances_px(camera, T_cam_base)))


class KeypointGuard:
    """Which statistic of the inlier keypoints decides that a polish breaks their fit
    (module doc)."""

    RMSE = "rmse"               # many frames of a fixed camera, the fit's inliers
    ALL_MEDIAN = "all-median"   # many frames of a fixed camera, every detection
    MEDIAN = "median"           # one frame alone
    NONE = "none"               # the data's own masks decide; the detections are only reported
    VETOING = (RMSE, ALL_MEDIAN, MEDIAN)   # those whose keypoints can refuse a polish
    ALL = (*VETOING, NONE)


def fit_shrinkage(n_keypoints: int) -> float:
    """The factor by which a least-squares pose fit (6 parameters) shrinks the residuals of the
    n keypoints it was fitted to (2 n coordinates): their RMS is sqrt((2 n - 6) / 2 n) times
    the detection noise's (1 where n <= 3: no redundancy to measure)."""
    m = 2 * n_keypoints
    return float(np.sqrt((m - 6) / m)) if m > 6 else 1.0


def decide(iou0: float, iou1: float, kp0: float, kp1: float, n_guard: int,
           params: PolishSettings, guard: str,
           fit_rmse: tuple[float, float] | None = None) -> tuple[bool, str]:
    """Keep or not (module doc); kp0 / kp1: the guard's keypoint statistic over its
    `n_guard` keypoints (0: no guard); `fit_rmse`: with the "all-median" guard, the RMSE of
    the keypoint fit's inliers before and after, held to the "rmse" rule too (None: not)."""
    gain = iou1 - iou0
    ious = f"mean IoU {iou0:.4f} -> {iou1:.4f}"
    if not gain > params.min_iou_gain:
        return False, (f"not kept: {ious} gains {gain:+.4f}, not more than "
                       f"{params.min_iou_gain:g}")
    if guard == KeypointGuard.NONE:
        return True, f"kept: {ious} on the data's masks"
    if n_guard == 0:
        return True, f"kept: {ious} (no keypoints to check)"
    if guard == KeypointGuard.RMSE:
        allowed = max(params.max_rmse_factor * kp0, kp0 + params.rmse_margin_px)
        stats = f"keypoint RMSE {kp0:.3f} -> {kp1:.3f} px"
    elif guard == KeypointGuard.ALL_MEDIAN:
        allowed = max(params.max_median_factor * kp0, kp0 + params.median_margin_px)
        stats = f"median distance of all {n_guard} keypoint detections {kp0:.3f} -> {kp1:.3f} px"
    else:
        # the keypoint pose was fitted to these keypoints: its median understates their noise
        allowed = kp0 / fit_shrinkage(n_guard) + params.frame_median_margin_px
        stats = f"keypoint median distance {kp0:.3f} -> {kp1:.3f} px"
    if not kp1 <= allowed:
        return False, f"not kept: {ious} but {stats}, above the {allowed:.3f} px allowed"
    if guard == KeypointGuard.ALL_MEDIAN and fit_rmse is not None:
        rmse0, rmse1 = fit_rmse
        limit = max(params.max_rmse_factor * rmse0, rmse0 + params.rmse_margin_px)
        if not rmse1 <= limit:
            return False, (f"not kept: {ious}, {stats}, but the keypoint fit's inlier RMSE "
                           f"{rmse0:.3f} -> {rmse1:.3f} px, above the {limit:.3f} px allowed")
        stats += f", inlier RMSE {rmse0:.3f} -> {rmse1:.3f} px (at most {limit:.3f})"
    return True, f"kept: {ious}, {stats} (at most {allowed:.3f} px allowed)"
