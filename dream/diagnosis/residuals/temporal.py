"""Residual analyses over time and frame order.

- `time_offset` leaves residuals proportional to the keypoints' image velocity
  (`analyse_velocity`, `analyse_time`).
- `camera_moved` leaves a step in the residuals at one frame (`analyse_change_point`).
"""

from __future__ import annotations

import math
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


def _segment_sums(res: ResidualSet) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frames with used keypoints (V,) and their per-(keypoint, component) counts, sums and
    sums of squares (V, 2K), in frame order."""
    r = np.nan_to_num(res.residual)
    used = np.repeat(res.used[..., None], 2, -1)                   # (F, K, 2)
    valid = np.flatnonzero(res.used.any(1))
    n = used[valid].reshape(len(valid), -1).astype(float)
    s1 = np.where(used, r, 0.0)[valid].reshape(len(valid), -1)
    s2 = np.where(used, r * r, 0.0)[valid].reshape(len(valid), -1)
    return valid, n, s1, s2


def _within_ss(n: np.ndarray, s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """Sum over groups of the within-group sum of squares, from counts and sums (..., G)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        ss = np.where(n > 0, s2 - s1 * s1 / np.maximum(n, 1), 0.0)
    return np.maximum(ss, 0.0).sum(-1)


def analyse_change_point(res: ResidualSet) -> dict:
    """The best single split of the frame sequence into before / after.

    Model: every (keypoint, component) has its own mean residual, constant (null) or with one
    step at the split (alternative); the split maximises the Gaussian likelihood ratio
    `lr = N log(RSS0 / RSS1)` over splits leaving >= MIN_SEGMENT_FRAMES frames with used
    keypoints on each side. A camera that moved between two frames shows as such a step.

    Returns: `index` and `frame` (the first frame after the split), `lr`, `f_stat` (the F
    statistic of the step at that split), `p_value` (its F-test p-value times the number of
    candidate splits, clipped to 1: a conservative score, not an exact p-value), `significant`
    (p_value < ALPHA), `explained_fraction` (1 - RSS1/RSS0), `step_px` (RMS over keypoints of
    the length of the after - before mean difference), `mean_before_px` / `mean_after_px`
    (mean used residual of each segment), and `per_frame_mean_px` (F x [du, dv] or None).
    Frames are taken in the given order.
    """
    out: dict[str, Any] = {"index": None, "frame": None, "lr": None, "f_stat": None,
                           "p_value": None, "significant": False, "explained_fraction": None,
                           "step_px": None, "mean_before_px": None, "mean_after_px": None,
                           "num_candidates": 0,
                           "per_frame_mean_px": float_list(per_frame_mean(res))}
    valid, n, s1, s2 = _segment_sums(res)
    V = len(valid)
    if V < 2 * MIN_SEGMENT_FRAMES:
        return out
    cn, c1, c2 = np.cumsum(n, 0), np.cumsum(s1, 0), np.cumsum(s2, 0)
    tot_n, tot_1, tot_2 = cn[-1], c1[-1], c2[-1]
    rss0 = float(_within_ss(tot_n, tot_1, tot_2))
    N = float(tot_n.sum())
    splits = np.arange(MIN_SEGMENT_FRAMES, V - MIN_SEGMENT_FRAMES + 1)   # first valid after
    bn, b1, b2 = cn[splits - 1], c1[splits - 1], c2[splits - 1]
    an, a1, a2 = tot_n - bn, tot_1 - b1, tot_2 - b2
    rss1 = _within_ss(bn, b1, b2) + _within_ss(an, a1, a2)
    if rss0 <= 0:
        return out
    with np.errstate(divide="ignore"):
        lr = N * np.log(rss0 / np.maximum(rss1, 1e-300))
    best = int(np.argmax(lr))
    s = int(splits[best])
    extra = int(np.count_nonzero((bn[best] > 0) & (an[best] > 0)))
    params = int(np.count_nonzero(bn[best] > 0) + np.count_nonzero(an[best] > 0))
    dof = N - params
    f_stat = p = None
    if extra > 0 and dof > 0:
        if rss1[best] > 0:
            f_stat = float(((rss0 - rss1[best]) / extra) / (rss1[best] / dof))
            p = min(1.0, float(stats.f.sf(f_stat, extra, dof)) * len(splits))
        else:
            f_stat, p = math.inf, 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        mb = np.where(bn[best] > 0, b1[best] / np.maximum(bn[best], 1), np.nan).reshape(-1, 2)
        ma = np.where(an[best] > 0, a1[best] / np.maximum(an[best], 1), np.nan).reshape(-1, 2)
    diff = np.hypot(*(ma - mb).T)
    diff = diff[np.isfinite(diff)]
    seg_b = b1[best].reshape(-1, 2).sum(0) / max(1.0, bn[best].reshape(-1, 2)[:, 0].sum())
    seg_a = a1[best].reshape(-1, 2).sum(0) / max(1.0, an[best].reshape(-1, 2)[:, 0].sum())
    index = int(valid[s])
    out.update(index=index, frame=res.frame_names[index], lr=finite_or_none(lr[best]),
               f_stat=finite_or_none(f_stat), p_value=p,
               significant=bool(p is not None and p < ALPHA),
               explained_fraction=finite_or_none(1.0 - rss1[best] / rss0),
               step_px=finite_or_none(np.sqrt(np.mean(diff ** 2))) if diff.size else None,
               mean_before_px=float_list(seg_b), mean_after_px=float_list(seg_a),
               num_candidates=int(len(splits)))
    return out
