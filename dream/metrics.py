"""Accuracy metrics as DREAM defines them: ADD and its AUC, keypoint L2 and PCK AUC, pose error."""

from __future__ import annotations

import numpy as np

from dream.errors import InputError
from dream.transforms import invert_T, rotation_angle_between, transform_points

ADD_AUC_THRESHOLD_M = 0.1       # DREAM: area under the ADD accuracy curve up to 10 cm
ADD_AUC_STEP_M = 1e-5           # DREAM's integration step
PCK_AUC_THRESHOLD_PX = 20.0     # area under the PCK curve up to 20 px
PCK_AUC_STEP_PX = 0.01
MIN_INFRAME_KEYPOINTS = 4       # frames with fewer in-frame keypoints are left out of ADD AUC


def auc(values: np.ndarray, max_threshold: float, step: float) -> float:
    """Area under the curve 'fraction of values <= threshold' for thresholds 0..max, normalised
    to [0, 1] (DREAM's `add_auc`). Failures are +inf and count as misses."""
    values = np.asarray(values, dtype=float).ravel()
    if values.size == 0:
        return float("nan")
    if np.any(np.isnan(values)):
        raise InputError("metric values contain NaN; mark failures with +inf")
    thresholds = np.arange(0.0, max_threshold, step)
    fractions = np.searchsorted(np.sort(values), thresholds, side="right") / values.size
    return float(np.trapezoid(fractions, dx=step) / max_threshold)


def add_per_frame(P_base: np.ndarray, T_cam_base_est: np.ndarray,
                  T_cam_base_true: np.ndarray) -> np.ndarray:
    """ADD (m) of each frame: mean distance in the camera frame between keypoints placed with
    the estimated and the true extrinsic.

    P_base (F, K, 3); T_est (F, 4, 4) with NaN for frames without an estimate (ADD = inf);
    T_true (F, 4, 4).
    """
    P_base = np.asarray(P_base, dtype=float)
    if P_base.ndim != 3 or P_base.shape[-1] != 3:
        raise InputError(f"P_base has shape {P_base.shape}, expected (F, K, 3)")
    F = P_base.shape[0]
    T_est = np.asarray(T_cam_base_est, dtype=float)
    T_true = np.asarray(T_cam_base_true, dtype=float)
    if T_est.shape != (F, 4, 4) or T_true.shape != (F, 4, 4):
        raise InputError(f"poses have shapes {T_est.shape}, {T_true.shape}; expected ({F}, 4, 4)")
    failed = ~np.all(np.isfinite(T_est.reshape(F, -1)), axis=1)
    T_est = np.where(failed[:, None, None], np.eye(4), T_est)
    d = np.linalg.norm(transform_points(T_est[:, None], P_base)
                       - transform_points(T_true[:, None], P_base), axis=-1)
    out = np.nanmean(d, axis=1)
    out[failed] = np.inf
    return out


def pose_errors(T_cam_base_est: np.ndarray,
                T_cam_base_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-position error in the base frame (m) and rotation error (rad), shapes (...)."""
    T_base_cam_est = invert_T(T_cam_base_est)
    T_base_cam_true = invert_T(T_cam_base_true)
    translation = np.linalg.norm(T_base_cam_est[..., :3, 3] - T_base_cam_true[..., :3, 3], axis=-1)
    rotation = rotation_angle_between(T_base_cam_est[..., :3, :3], T_base_cam_true[..., :3, :3])
    return translation, rotation


def keypoint_errors(uv_detected: np.ndarray, uv_true: np.ndarray,
                    in_frame: np.ndarray) -> np.ndarray:
    """L2 pixel errors of the in-frame ground-truth keypoints (flattened); a keypoint that was
    not detected counts as +inf."""
    uv_detected = np.asarray(uv_detected, dtype=float)
    uv_true = np.asarray(uv_true, dtype=float)
    if uv_detected.shape != uv_true.shape or uv_true.shape[:-1] != np.shape(in_frame):
        raise InputError("detections, truth and in-frame mask have mismatched shapes")
    d = np.linalg.norm(uv_detected - uv_true, axis=-1)
    d = np.where(np.isfinite(d), d, np.inf)
    return d[np.asarray(in_frame, bool)]


def summarise(values: np.ndarray) -> dict[str, float | None]:
    """Mean and median of finite values, and the count of failures."""
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    return {"mean": float(finite.mean()) if finite.size else None,
            "median": float(np.median(finite)) if finite.size else None,
            "failures": int((~np.isfinite(values)).sum()), "count": int(values.size)}
