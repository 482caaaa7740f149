"""Residual analyses on the image: overall size, per keypoint, and radial.

- `keypoint_bias` leaves a constant offset of one keypoint (`analyse_keypoints`, Hotelling's
  T^2 test).
- `lens_distortion` / `intrinsics_error` leave a radial component growing as r^3 (k1) or as r
  (a focal scale error) with the distance r from the principal point (`analyse_radial`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import stats

from dream.arrays import finite_or_none
from dream.diagnosis.residuals.regression import (
    ALPHA,
    MIN_REGRESSION_OBS,
    corr,
    slope_through_origin,
)
from dream.diagnosis.residuals.residual_set import (
    ResidualSet,
    float_list,
    used_residuals,
)

MIN_KEYPOINT_OBS = 3         # observations of a keypoint needed for its bias test (2D mean)
MIN_RADIUS_NORMALISED = 1e-6  # points this close to the principal point have no direction


def analyse_overall(res: ResidualSet) -> dict:
    """n used, frames, RMS (px), median and 95th percentile of |r| (px), mean vector (px)."""
    r, f, _ = used_residuals(res)
    mag = np.hypot(r[:, 0], r[:, 1])
    n = len(r)
    return {"n_used": n, "n_observed": int(np.count_nonzero(np.all(np.isfinite(
                res.uv_observed), -1))),
            "n_frames": len(res.frame_names), "n_frames_used": int(len(np.unique(f))),
            "n_keypoints": len(res.keypoint_names),
            "rms_px": finite_or_none(np.sqrt(np.mean(mag ** 2))) if n else None,
            "median_abs_px": finite_or_none(np.median(mag)) if n else None,
            "p95_abs_px": finite_or_none(np.percentile(mag, 95)) if n else None,
            "mean_px": float_list(r.mean(0)) if n else None}


def _keypoint_bias(r: np.ndarray, num_tests: int) -> dict:
    """Hotelling's one-sample T^2 test of a zero mean on residuals (n, 2) of one keypoint."""
    n = len(r)
    out: dict[str, Any] = {"n": n, "mean_px": None, "rms_px": None, "std_px": None,
                           "t2": None, "mean_over_se": None, "p_value": None,
                           "p_value_corrected": None, "significant": False}
    if n == 0:
        return out
    mean = r.mean(0)
    out["mean_px"] = float_list(mean)
    out["rms_px"] = finite_or_none(np.sqrt(np.mean(np.sum(r ** 2, -1))))
    if n < MIN_KEYPOINT_OBS:
        return out
    cov = np.cov(r.T, ddof=1)
    out["std_px"] = float_list(np.sqrt(np.diag(cov)))
    # Regularise a degenerate covariance (noise-free or one-dimensional residuals).
    cov = cov + np.eye(2) * max(1e-12, 1e-9 * float(np.trace(cov)))
    t2 = float(n * mean @ np.linalg.solve(cov, mean))
    f_stat = (n - 2) / (2 * (n - 1)) * t2
    p = float(stats.f.sf(f_stat, 2, n - 2))
    p_corr = min(1.0, p * num_tests)
    out.update(t2=t2, mean_over_se=math.sqrt(max(t2, 0.0)), p_value=p,
               p_value_corrected=p_corr, significant=bool(p_corr < ALPHA))
    return out


def analyse_keypoints(res: ResidualSet) -> dict:
    """Per keypoint: n, mean residual (px), RMS, and Hotelling's T^2 test of the mean.

    A keypoint bias shows as a significant constant offset. `mean_over_se` is sqrt(T^2), the
    mean's length in standard errors (Mahalanobis); `p_value_corrected` is Bonferroni-corrected
    over the keypoints and `significant` means `p_value_corrected < ALPHA`.
    """
    r, _, k = used_residuals(res)
    K = len(res.keypoint_names)
    return {name: _keypoint_bias(r[k == i], K) for i, name in enumerate(res.keypoint_names)}


def analyse_radial(res: ResidualSet) -> dict:
    """Radial residual against the distance from the principal point.

    Pixels are normalised (x = (u - cx) / fx, y = (v - cy) / fy), so that the radius `r` is
    the normalised image radius at the predicted keypoint and the radial residual `e` the
    normalised residual's component along the direction away from the principal point. Then:

    - `slope_r3`: least squares e ~ b r^3. A missing lens distortion gives e = k1 r^3 + ...,
      so `slope_r3.slope` estimates k1 (dimensionless; > 0: the observed points lie further
      from the principal point than predicted, a pincushion pattern).
    - `slope_r`: least squares e ~ b r. A focal length error gives e = (f_true/f - 1) r, so
      `slope_r.slope` estimates the relative focal scale error.
    - `joint`: both regressors together (they are strongly correlated; read with care).
    - `corr_r`, `corr_r3`: Pearson correlation of e with r and with r^3.
    - `radial_rms_px`, `tangential_rms_px`: RMS of the two components in pixels.

    `significant_r3` / `significant_r`: two-sided p < ALPHA.
    """
    r, f, k = used_residuals(res)
    cam = res.camera
    uvp = res.uv_predicted[f, k]
    xy = np.stack([(uvp[:, 0] - cam.cx) / cam.fx, (uvp[:, 1] - cam.cy) / cam.fy], -1)
    rn = np.hypot(xy[:, 0], xy[:, 1])
    keep = rn > MIN_RADIUS_NORMALISED
    xy, rn, r = xy[keep], rn[keep], r[keep]
    direction = xy / rn[:, None] if len(rn) else xy
    r_norm = r / np.array([cam.fx, cam.fy])
    e = np.sum(r_norm * direction, -1)
    e_px = np.sum(r * direction, -1)
    e_tan_px = direction[:, 0] * r[:, 1] - direction[:, 1] * r[:, 0]
    fit3 = slope_through_origin(rn ** 3, e)
    fit1 = slope_through_origin(rn, e)
    joint = None
    if len(rn) >= MIN_REGRESSION_OBS:
        A = np.stack([rn, rn ** 3], -1)
        coef, *_ = np.linalg.lstsq(A, e, rcond=None)
        joint = {"slope_r": float(coef[0]), "slope_r3": float(coef[1])}
    n = len(rn)
    return {
        "n": n,
        "radius_max": finite_or_none(rn.max()) if n else None,
        "slope_r3": fit3,
        "slope_r": fit1,
        "joint": joint,
        "corr_r3": corr(rn ** 3, e),
        "corr_r": corr(rn, e),
        "significant_r3": bool(fit3["p_value"] is not None and fit3["p_value"] < ALPHA),
        "significant_r": bool(fit1["p_value"] is not None and fit1["p_value"] < ALPHA),
        "radial_rms_px": finite_or_none(np.sqrt(np.mean(e_px ** 2))) if n else None,
        "tangential_rms_px": finite_or_none(np.sqrt(np.mean(e_tan_px ** 2))) if n else None,
    }
