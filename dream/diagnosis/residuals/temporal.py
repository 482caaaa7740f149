"""Residual analyses over time and frame order.

- `time_offset` leaves residuals proportional to the keypoints' image velocity
  (`analyse_velocity`, `analyse_time`).
- `camera_moved` leaves a step in the residuals at one frame, beyond what follows the arm's
  pose (`analyse_change_point`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

from dream.arrays import finite_or_none
from dream.diagnosis.residuals.regression import ALPHA, corr, slope_through_origin
from dream.diagnosis.residuals.residual_set import (
    ResidualSet,
    float_list,
    image_velocity,
    per_frame_mean,
    per_frame_rms,
    used_residuals,
)

MIN_SEGMENT_FRAMES = 3       # frames (with used keypoints) on each side of a change point
NULL_FRAMES_PER_PARAM = 3    # frames per regressor of the pose-following null before it is used
MIN_JOINT_SPREAD_RAD = 1e-3  # a joint that spreads less than this is taken as still
RANK_TOLERANCE = 1e-9        # singular values below this x the largest span nothing
STEP_NORM_TOLERANCE = 1e-9   # a step the null explains to this (per frame) is not tested


def _lag1_autocorr(x: np.ndarray) -> float | None:
    """Lag-1 autocorrelation of a series (NaNs dropped first); None when undefined."""
    x = x[np.isfinite(x)]
    if len(x) < 3:
        return None
    xc = x - x.mean()
    den = float(xc @ xc)
    return None if den <= 0 else float(xc[:-1] @ xc[1:]) / den


def analyse_velocity(res: ResidualSet) -> dict:
    """Residual against the keypoints' image velocity (see `image_velocity`).

    Sign convention: least squares residual ~ coefficient_s * velocity over all used keypoints
    and both components, with residual = observed - predicted and velocity = d uv_predicted /
    dt (px/s). If the joint readings lag the images by s seconds (the arm's state at image time
    t is the reading stamped t + s, `dream.extension` `time_offset` = s), the observed keypoint
    is where the model puts it s seconds later: residual ~= s * velocity, so `coefficient_s`
    estimates `time_offset` directly (> 0: readings lag the images).
    """
    r, f, k = used_residuals(res)
    v = image_velocity(res)[f, k]
    ok = np.all(np.isfinite(v), -1)
    x, y = v[ok].ravel(), r[ok].ravel()
    fit = slope_through_origin(x, y)
    speed = np.hypot(v[ok, 0], v[ok, 1])
    return {"n": int(np.count_nonzero(ok)), "coefficient_s": fit["slope"], "se_s": fit["se"],
            "t": fit["t"], "p_value": fit["p_value"], "corr": corr(x, y),
            "significant": bool(fit["p_value"] is not None and fit["p_value"] < ALPHA),
            "median_speed_px_s": finite_or_none(np.median(speed)) if speed.size else None,
            "sign_convention": "residual (observed - predicted) ~= coefficient_s * "
                               "d(uv_predicted)/dt; coefficient_s > 0: the joint readings lag "
                               "the images by coefficient_s seconds (time_offset)"}


def analyse_time(res: ResidualSet) -> dict | None:
    """Residuals over time (None without timestamps).

    `times_s` and `rms_px`: per-frame RMS in time order; `rms_lag1_autocorr` and
    `mean_lag1_autocorr` ([u, v]): lag-1 autocorrelation of the per-frame RMS and mean
    residual (near 0 for white noise, near 1 for a slowly varying error); `velocity`: see
    `analyse_velocity`.
    """
    if res.times_s is None:
        return None
    order = np.argsort(res.times_s, kind="stable")
    rms = per_frame_rms(res)[order]
    mean = per_frame_mean(res)[order]
    return {"times_s": float_list(res.times_s[order]),
            "frames": [res.frame_names[i] for i in order],
            "rms_px": float_list(rms),
            "rms_lag1_autocorr": _lag1_autocorr(rms),
            "mean_lag1_autocorr": [_lag1_autocorr(mean[:, 0]), _lag1_autocorr(mean[:, 1])],
            "velocity": analyse_velocity(res)}


def _joint_basis(res: ResidualSet, valid: np.ndarray) -> tuple[np.ndarray, str]:
    """(V, P) regressors of a misfit that follows the arm's pose, and the null's name.

    A wrong model of a fixed camera and its robot (joint offsets, link lengths, intrinsics,
    distortion, a keypoint's bias) leaves each keypoint's residual a function of the joint
    readings, which a smooth motion changes smoothly: tested against a constant, such a
    misfit reads as a step. The null is therefore 1, sin q and cos q of the joints that move;
    with no joint moving, or fewer than NULL_FRAMES_PER_PARAM frames per regressor, it falls
    back to the constant (the name says why).
    """
    q = np.asarray(res.joints, dtype=float)[valid]
    moving = np.nanstd(q, axis=0) > MIN_JOINT_SPREAD_RAD
    if not moving.any():
        return np.ones((len(valid), 1)), "constant: the arm does not move"
    q = np.nan_to_num(q[:, moving])
    basis = np.column_stack([np.ones(len(valid)), np.sin(q), np.cos(q)])
    if len(valid) < NULL_FRAMES_PER_PARAM * basis.shape[1]:
        return np.ones((len(valid), 1)), "constant: too few frames to test against the pose"
    return basis, "joints"


def _range(X: np.ndarray) -> np.ndarray:
    """Orthonormal basis (n, r) of the columns of X (r its numerical rank)."""
    U, s, _ = np.linalg.svd(X, full_matrices=False)
    return U[:, s > RANK_TOLERANCE * s[0]]


def _step_gains(res: ResidualSet, valid: np.ndarray, splits: np.ndarray, basis: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, float, int, int, list[str]]:
    """The residual sum of squares a step at each split removes beyond `basis` (S,), the
    (keypoint, component) series each step reaches (S,), the null's RSS, the observations,
    the null's parameters, and the keypoints seen in too few frames for `basis` (tested against
    their constant instead). Each (keypoint, component) series has its own coefficients."""
    gain, reached = np.zeros(len(splits)), np.zeros(len(splits))
    rss0, n_obs, params, sparse = 0.0, 0, 0, []
    for k in range(res.used.shape[1]):
        rows = np.flatnonzero(res.used[valid, k])
        if len(rows) < 2:
            continue
        X = basis[rows]
        if len(rows) < NULL_FRAMES_PER_PARAM * X.shape[1]:
            if X.shape[1] > 1:
                sparse.append(res.keypoint_names[k])
            X = X[:, :1]                         # the constant, the basis's first column
        Q = _range(X)
        E = (rows[:, None] >= splits[None, :]).astype(float)         # (n, S) the step
        E -= Q @ (Q.T @ E)
        ee = np.einsum("ns,ns->s", E, E)
        ok = ee > STEP_NORM_TOLERANCE * len(rows)
        for c in range(2):
            y = res.residual[valid[rows], k, c]
            y = y - Q @ (Q.T @ y)
            rss0 += float(y @ y)
            n_obs += len(rows)
            params += Q.shape[1]
            gain += np.where(ok, (y @ E) ** 2 / np.maximum(ee, 1e-300), 0.0)
            reached += ok
    return gain, reached, rss0, n_obs, params, sparse


def _segment_means(res: ResidualSet, frames: np.ndarray) -> tuple[np.ndarray, list]:
    """Each (keypoint, component)'s mean used residual over `frames` (K, 2), NaN where none,
    and the mean over all their used residuals ([du, dv])."""
    used = res.used[frames]
    r = np.where(used[..., None], np.nan_to_num(res.residual[frames]), 0.0)
    n = used.sum(0)[:, None].astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        per = np.where(n > 0, r.sum(0) / np.maximum(n, 1.0), np.nan)
    overall = r.reshape(-1, 2).sum(0) / max(1.0, float(used.sum()))
    return per, float_list(overall)


def analyse_change_point(res: ResidualSet) -> dict:
    """The best single split of the frame sequence into before / after.

    Model: every (keypoint, component) residual follows the arm's pose (`null`: "joints",
    1, sin q, cos q of the moving joints; "constant: " and why otherwise, see `_joint_basis`;
    `against_constant`: keypoints seen in too few frames for the joints, tested against their
    constant) with or without one step at the split; the split is the one whose step has the
    smallest F-test p-value, over splits leaving >= MIN_SEGMENT_FRAMES frames with used
    keypoints on each side. A camera that moved between two frames shows as such a step; a
    misfit that follows the pose does not.

    Returns: `index` and `frame` (the first frame after the split), `null`,
    `against_constant`, `f_stat` (the F
    statistic of the step at that split), `p_value` (its F-test p-value times the number of
    candidate splits, clipped to 1: a conservative score, not an exact p-value), `significant`
    (p_value < ALPHA), `explained_fraction` (of the null's residual sum of squares),
    `step_px` (RMS over keypoints of the length of the after - before mean difference),
    `mean_before_px` / `mean_after_px` (mean used residual of each segment), and
    `per_frame_mean_px` (F x [du, dv] or None). Frames are taken in the given order.
    """
    out: dict[str, Any] = {"index": None, "frame": None, "null": None,
                           "against_constant": [], "f_stat": None,
                           "p_value": None, "significant": False, "explained_fraction": None,
                           "step_px": None, "mean_before_px": None, "mean_after_px": None,
                           "num_candidates": 0,
                           "per_frame_mean_px": float_list(per_frame_mean(res))}
    valid = np.flatnonzero(res.used.any(1))
    V = len(valid)
    if V < 2 * MIN_SEGMENT_FRAMES:
        return out
    splits = np.arange(MIN_SEGMENT_FRAMES, V - MIN_SEGMENT_FRAMES + 1)   # first valid after
    basis, null = _joint_basis(res, valid)
    gain, reached, rss0, n_obs, params, sparse = _step_gains(res, valid, splits, basis)
    dof = n_obs - params - reached
    testable = (reached > 0) & (dof > 0)
    if rss0 <= 0 or not testable.any():
        return out
    with np.errstate(invalid="ignore", divide="ignore"):
        f_all = np.where(testable, (gain / np.maximum(reached, 1))
                         / (np.maximum(rss0 - gain, 0.0) / np.maximum(dof, 1)), -np.inf)
        p_all = np.where(testable, stats.f.sf(f_all, np.maximum(reached, 1),
                                              np.maximum(dof, 1)), np.inf)
    # splits reach different numbers of series: ranked by p, not by F (other dof)
    best = int(np.lexsort((-f_all, p_all))[0])
    f_stat = float(f_all[best])
    p = min(1.0, float(p_all[best]) * len(splits))
    index = int(valid[splits[best]])
    before, mean_b = _segment_means(res, valid[:splits[best]])
    after, mean_a = _segment_means(res, valid[splits[best]:])
    diff = np.hypot(*(after - before).T)
    diff = diff[np.isfinite(diff)]
    out.update(index=index, frame=res.frame_names[index], null=null,
               against_constant=sparse,
               f_stat=finite_or_none(f_stat), p_value=p, significant=bool(p < ALPHA),
               explained_fraction=finite_or_none(gain[best] / rss0),
               step_px=finite_or_none(np.sqrt(np.mean(diff ** 2))) if diff.size else None,
               mean_before_px=mean_b, mean_after_px=mean_a, num_candidates=int(len(splits)))
    return out
