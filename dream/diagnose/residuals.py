"""Residual analysis of a calibrated sequence: where the nominal model misses, and how.

Every effect of the catalog (`dream.extension`) leaves a signature in the keypoint residuals
`r = uv_observed - uv_predicted` (pixels):

- `keypoint_bias`: a constant offset of one keypoint (`per_keypoint`, Hotelling's T^2 test).
- `lens_distortion` / `intrinsics_error`: a radial component growing as r^3 (k1) or as r (a
  focal scale error) with the distance r from the principal point (`radial`).
- `joint_offset`: residuals that vary with a joint's angle (`per_joint`).
- `time_offset`: residuals proportional to the keypoints' image velocity (`time`).
- `camera_moved`: a step in the residuals at one frame (`change_point`).

All functions are pure and return plain JSON-serialisable values (floats, ints, strings,
bools, lists, dicts; `None` where a statistic is undefined, never NaN).

The p-values treat the used observations as independent. On real data residuals are
correlated within a frame and across neighbouring frames, so they are optimistic: read them
as scores for ranking hypotheses, and let held-out prediction decide (`dream.diagnose`).

Public API:
    ResidualSet(...)                     observed vs predicted keypoints of one model
    analyse(res) -> dict                 all sections below
    per_frame_rms(res) -> (F,)           px, NaN where a frame has no used keypoint
    per_frame_mean(res) -> (F, 2)        px, NaN where a frame has no used keypoint
    image_velocity(res) -> (F, K, 2)     px/s of uv_predicted, NaN where unknown
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from dream.arrays import read_only
from dream.camera import CameraIntrinsics
from dream.errors import InputError

log = logging.getLogger(__name__)

ALPHA = 0.01                 # family-wise significance level of every "significant" flag
MIN_KEYPOINT_OBS = 3         # observations of a keypoint needed for its bias test (2D mean)
MIN_REGRESSION_OBS = 4       # observations needed for a correlation or a regression
MIN_SEGMENT_FRAMES = 3       # frames (with used keypoints) on each side of a change point
MIN_JOINT_RANGE = 1e-6       # rad (or m): a joint that moves less than this is treated as fixed
MIN_RADIUS_NORMALISED = 1e-6  # points this close to the principal point have no direction
MAX_VELOCITY_GAP_FACTOR = 5.0  # no finite difference across a gap > this x the median dt
COMPONENTS = ("u", "v")


def _finite_or_none(x: Any) -> float | None:
    """A float, or None when `x` is NaN/infinite/None."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _list(a: np.ndarray) -> list:
    """Nested list of floats with None in place of NaN."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 0:
        return _finite_or_none(a)  # type: ignore[return-value]
    return [_list(x) for x in a]


@dataclass(frozen=True, eq=False)
class ResidualSet:
    """Observed vs predicted keypoints of a calibrated sequence (one model).

    Attributes:
        frame_names: F frame names, in sequence order.
        keypoint_names: K keypoint names.
        joint_names: J joint names.
        uv_observed: (F, K, 2) px, NaN where not observed.
        uv_predicted: (F, K, 2) px by the model (finite where observed).
        used: (F, K) bool: observed and an inlier of the fit.
        joints: (F, J) rad (m for prismatic joints), the readings the model was driven with.
        times_s: (F,) s, or None.
        camera: the intrinsics the residuals were measured with.
    """

    frame_names: tuple[str, ...]
    keypoint_names: tuple[str, ...]
    joint_names: tuple[str, ...]
    uv_observed: np.ndarray
    uv_predicted: np.ndarray
    used: np.ndarray
    joints: np.ndarray
    times_s: np.ndarray | None
    camera: CameraIntrinsics

    def __post_init__(self) -> None:
        fix = "build the residual set from one calibrated sequence"
        for name in ("frame_names", "keypoint_names", "joint_names"):
            names = tuple(getattr(self, name))
            if not all(isinstance(n, str) for n in names):
                raise InputError(f"{name} must be strings, got {names!r}", fix=fix)
            object.__setattr__(self, name, names)
        F, K, J = len(self.frame_names), len(self.keypoint_names), len(self.joint_names)
        if F == 0 or K == 0:
            raise InputError(f"a residual set needs frames and keypoints, got F={F}, K={K}",
                             fix=fix)
        if not isinstance(self.camera, CameraIntrinsics):
            raise InputError(f"camera must be CameraIntrinsics, got {type(self.camera).__name__}",
                             fix=fix)
        shapes = {"uv_observed": (F, K, 2), "uv_predicted": (F, K, 2), "used": (F, K),
                  "joints": (F, J)}
        for name, shape in shapes.items():
            a = np.asarray(getattr(self, name))
            if a.shape != shape:
                raise InputError(f"{name} has shape {a.shape}, expected {shape} "
                                 f"(F={F} frames, K={K} keypoints, J={J} joints)", fix=fix)
            object.__setattr__(self, name, read_only(a, bool if name == "used" else float))
        if not np.all(np.isfinite(self.joints)):
            raise InputError("joints hold NaN or infinite values", fix="give finite joint readings")
        ok = np.all(np.isfinite(self.uv_observed), -1) & np.all(np.isfinite(self.uv_predicted), -1)
        if np.any(self.used & ~ok):
            f, k = np.argwhere(self.used & ~ok)[0]
            raise InputError(f"keypoint '{self.keypoint_names[k]}' of frame "
                             f"'{self.frame_names[f]}' is used but its observed or predicted "
                             f"pixel is not finite", fix="mark it unused or give finite pixels")
        if self.times_s is not None:
            t = np.asarray(self.times_s)
            if t.shape != (F,) or not np.all(np.isfinite(t.astype(float))):
                raise InputError(f"times_s has shape {t.shape}, expected ({F},) finite seconds",
                                 fix="give one finite timestamp per frame, or None")
            object.__setattr__(self, "times_s", read_only(t))

    @property
    def residual(self) -> np.ndarray:
        """(F, K, 2) px: uv_observed - uv_predicted (NaN where not observed)."""
        return self.uv_observed - self.uv_predicted

    @property
    def num_used(self) -> int:
        return int(np.count_nonzero(self.used))


def per_frame_rms(res: ResidualSet) -> np.ndarray:
    """(F,) px: RMS of the used residual vectors of each frame, NaN where none is used."""
    sq = np.where(res.used, np.sum(np.nan_to_num(res.residual) ** 2, -1), 0.0)
    n = np.count_nonzero(res.used, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(sq.sum(1) / np.maximum(n, 1)), np.nan)


def per_frame_mean(res: ResidualSet) -> np.ndarray:
    """(F, 2) px: mean used residual vector of each frame, NaN where none is used."""
    r = np.where(res.used[..., None], np.nan_to_num(res.residual), 0.0)
    n = np.count_nonzero(res.used, axis=1)
    return np.where((n > 0)[:, None], r.sum(1) / np.maximum(n, 1)[:, None], np.nan)


def image_velocity(res: ResidualSet) -> np.ndarray:
    """(F, K, 2) px/s: time derivative of `uv_predicted` by finite differences.

    Frames are taken in time order; a frame's velocity is the central difference of its
    neighbours in time (one-sided at the ends, or where one neighbour is missing). Differences
    across a time step longer than `MAX_VELOCITY_GAP_FACTOR` x the median step, or of zero
    length, are not used. NaN where no difference is available, and everywhere without times.
    """
    F, K = res.used.shape
    out = np.full((F, K, 2), np.nan)
    if res.times_s is None or F < 2:
        return out
    order = np.argsort(res.times_s, kind="stable")
    t = res.times_s[order]
    uv = res.uv_predicted[order]
    dt = np.diff(t)
    positive = dt[dt > 0]
    if positive.size == 0:
        return out
    max_gap = MAX_VELOCITY_GAP_FACTOR * float(np.median(positive))
    step_ok = (dt > 0) & (dt <= max_gap)                          # (F-1,)
    with np.errstate(invalid="ignore", divide="ignore"):
        fwd = np.where(step_ok[:, None, None], np.diff(uv, axis=0) / dt[:, None, None], np.nan)
    prev = np.concatenate([np.full((1, K, 2), np.nan), fwd])      # velocity from frame i-1 to i
    nxt = np.concatenate([fwd, np.full((1, K, 2), np.nan)])       # velocity from frame i to i+1
    both = np.isfinite(prev) & np.isfinite(nxt)
    # central difference weighted by the step lengths = (uv[i+1] - uv[i-1]) / (t[i+1] - t[i-1])
    w_prev = np.concatenate([[0.0], dt])[:, None, None]
    w_next = np.concatenate([dt, [0.0]])[:, None, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        central = (np.nan_to_num(prev) * w_prev + np.nan_to_num(nxt) * w_next) / (w_prev + w_next)
    v = np.where(both, central, np.where(np.isfinite(prev), prev, nxt))
    out[order] = v
    return out


def _used_residuals(res: ResidualSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Used residuals (N, 2) px with their frame (N,) and keypoint (N,) indices."""
    f, k = np.nonzero(res.used)
    return res.residual[f, k], f, k


def _keypoint_bias(r: np.ndarray, num_tests: int) -> dict:
    """Hotelling's one-sample T^2 test of a zero mean on residuals (n, 2) of one keypoint."""
    n = len(r)
    out: dict[str, Any] = {"n": n, "mean_px": None, "rms_px": None, "std_px": None,
                           "t2": None, "mean_over_se": None, "p_value": None,
                           "p_value_corrected": None, "significant": False}
    if n == 0:
        return out
    mean = r.mean(0)
    out["mean_px"] = _list(mean)
    out["rms_px"] = _finite_or_none(np.sqrt(np.mean(np.sum(r ** 2, -1))))
    if n < MIN_KEYPOINT_OBS:
        return out
    cov = np.cov(r.T, ddof=1)
    out["std_px"] = _list(np.sqrt(np.diag(cov)))
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
    r, _, k = _used_residuals(res)
    K = len(res.keypoint_names)
    return {name: _keypoint_bias(r[k == i], K) for i, name in enumerate(res.keypoint_names)}


def _slope_through_origin(x: np.ndarray, y: np.ndarray) -> dict:
    """Least squares y ~ b x (no intercept): b, its standard error, t, two-sided p."""
    n = len(x)
    sxx = float(x @ x)
    if n < MIN_REGRESSION_OBS or sxx <= 0:
        return {"slope": None, "se": None, "t": None, "p_value": None}
    b = float(x @ y) / sxx
    dof = n - 1
    s2 = float(np.sum((y - b * x) ** 2)) / dof
    se = math.sqrt(s2 / sxx) if s2 > 0 else 0.0
    t = b / se if se > 0 else (math.inf if b != 0 else 0.0)
    p = float(2 * stats.t.sf(abs(t), dof)) if math.isfinite(t) else 0.0
    return {"slope": b, "se": se, "t": _finite_or_none(t), "p_value": p}


def _corr(x: np.ndarray, y: np.ndarray) -> float | None:
    """Pearson correlation, None when undefined (fewer than 3 points or no variance)."""
    if len(x) < 3:
        return None
    xc, yc = x - x.mean(), y - y.mean()
    den = math.sqrt(float(xc @ xc) * float(yc @ yc))
    return None if den <= 0 else float(xc @ yc) / den


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
    r, f, k = _used_residuals(res)
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
    fit3 = _slope_through_origin(rn ** 3, e)
    fit1 = _slope_through_origin(rn, e)
    joint = None
    if len(rn) >= MIN_REGRESSION_OBS:
        A = np.stack([rn, rn ** 3], -1)
        coef, *_ = np.linalg.lstsq(A, e, rcond=None)
        joint = {"slope_r": float(coef[0]), "slope_r3": float(coef[1])}
    n = len(rn)
    return {
        "n": n,
        "radius_max": _finite_or_none(rn.max()) if n else None,
        "slope_r3": fit3,
        "slope_r": fit1,
        "joint": joint,
        "corr_r3": _corr(rn ** 3, e),
        "corr_r": _corr(rn, e),
        "significant_r3": bool(fit3["p_value"] is not None and fit3["p_value"] < ALPHA),
        "significant_r": bool(fit1["p_value"] is not None and fit1["p_value"] < ALPHA),
        "radial_rms_px": _finite_or_none(np.sqrt(np.mean(e_px ** 2))) if n else None,
        "tangential_rms_px": _finite_or_none(np.sqrt(np.mean(e_tan_px ** 2))) if n else None,
    }


def _standardised(columns: list[np.ndarray]) -> np.ndarray:
    """(n, m) design of centred, unit-variance columns; columns without variance dropped."""
    keep = []
    for c in columns:
        c = c - c.mean()
        s = float(np.sqrt(np.mean(c ** 2)))
        if s > 0 and s > 1e-12 * max(1.0, float(np.max(np.abs(c)))):
            keep.append(c / s)
    return np.stack(keep, -1) if keep else np.zeros((len(columns[0]), 0))


def _harmonic_fit(q: np.ndarray, y: np.ndarray) -> tuple[float | None, float | None]:
    """R^2 and F-test p-value of y ~ 1 + sin(q - q0) + cos(q - q0) against y ~ 1."""
    n = len(q)
    if n < MIN_REGRESSION_OBS + 1:
        return None, None
    qc = q - q.mean()
    X = _standardised([np.sin(qc), 1.0 - np.cos(qc)])
    m = X.shape[1]
    yc = y - y.mean()
    tss = float(yc @ yc)
    if m == 0 or tss <= 0:
        return None, None
    coef, *_ = np.linalg.lstsq(X, yc, rcond=None)
    rss = float(np.sum((yc - X @ coef) ** 2))
    r2 = max(0.0, 1.0 - rss / tss)
    dof = n - 1 - m
    if rss <= 0:
        return r2, 0.0
    f_stat = (r2 / m) / ((1.0 - r2) / dof)
    return r2, float(stats.f.sf(f_stat, m, dof))


def _joint_stats(res: ResidualSet, j: int, r: np.ndarray, f: np.ndarray,
                 k: np.ndarray) -> dict:
    q_all = res.joints[:, j]
    out: dict[str, Any] = {"range": _finite_or_none(np.ptp(q_all)), "max_abs_corr": None,
                           "corr": None, "keypoint": None, "component": None,
                           "corr_p_value": None, "harmonic_r2": None,
                           "harmonic_keypoint": None, "harmonic_component": None,
                           "harmonic_p_value": None, "significant": False}
    if np.ptp(q_all) < MIN_JOINT_RANGE:
        return out
    K = len(res.keypoint_names)
    num_tests = 4 * K   # correlation and harmonic fit, of u and v, of every keypoint
    best_corr = (-1.0, None, None, None, 0)   # |corr|, corr, keypoint, component, n
    best_harm = (-1.0, None, None, None)   # r2, p, keypoint, component
    for ki in range(K):
        sel = k == ki
        q = q_all[f[sel]]
        if len(q) < MIN_REGRESSION_OBS or np.ptp(q) < MIN_JOINT_RANGE:
            continue
        for c in range(2):
            y = r[sel, c]
            rho = _corr(q, y)
            if rho is not None and abs(rho) > best_corr[0]:
                best_corr = (abs(rho), rho, ki, c, len(q))
            r2, p = _harmonic_fit(q, y)
            if r2 is not None and r2 > best_harm[0]:
                best_harm = (r2, p, ki, c)
    if best_corr[2] is not None:
        rho, n = best_corr[1], best_corr[4]
        if abs(rho) >= 1.0:
            p_corr = 0.0
        else:
            t = rho * math.sqrt((n - 2) / (1.0 - rho * rho))
            p_corr = float(2 * stats.t.sf(abs(t), n - 2))
        out.update(max_abs_corr=abs(rho), corr=rho, keypoint=res.keypoint_names[best_corr[2]],
                   component=COMPONENTS[best_corr[3]],
                   corr_p_value=min(1.0, p_corr * num_tests))
    if best_harm[2] is not None:
        p_h = None if best_harm[1] is None else min(1.0, best_harm[1] * num_tests)
        out.update(harmonic_r2=best_harm[0], harmonic_keypoint=res.keypoint_names[best_harm[2]],
                   harmonic_component=COMPONENTS[best_harm[3]], harmonic_p_value=p_h)
    out["significant"] = bool(
        (out["corr_p_value"] is not None and out["corr_p_value"] < ALPHA)
        or (out["harmonic_p_value"] is not None and out["harmonic_p_value"] < ALPHA))
    return out


def analyse_joints(res: ResidualSet) -> dict:
    """Per joint: how much the residuals depend on that joint's angle.

    For every keypoint and component (u, v): the Pearson correlation of the residual with the
    joint angle, and the R^2 of a harmonic fit residual ~ 1 + sin(q) + cos(q) (a joint offset
    d moves a keypoint by about d * d(uv)/dq, which turns with the joint: a first harmonic of
    q). Reported: the strongest of each (`max_abs_corr`, `corr`, `keypoint`, `component`;
    `harmonic_r2`, `harmonic_keypoint`, `harmonic_component`) with p-values Bonferroni-corrected
    over the 4K tests of the joint; `significant` when either is below ALPHA. `range` is the
    joint's range over the sequence; a joint that does not move gives None (no evidence).
    """
    r, f, k = _used_residuals(res)
    return {name: _joint_stats(res, j, r, f, k) for j, name in enumerate(res.joint_names)}


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
    r, f, k = _used_residuals(res)
    v = image_velocity(res)[f, k]
    ok = np.all(np.isfinite(v), -1)
    x, y = v[ok].ravel(), r[ok].ravel()
    fit = _slope_through_origin(x, y)
    speed = np.hypot(v[ok, 0], v[ok, 1])
    return {"n": int(np.count_nonzero(ok)), "coefficient_s": fit["slope"], "se_s": fit["se"],
            "t": fit["t"], "p_value": fit["p_value"], "corr": _corr(x, y),
            "significant": bool(fit["p_value"] is not None and fit["p_value"] < ALPHA),
            "median_speed_px_s": _finite_or_none(np.median(speed)) if speed.size else None,
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
    return {"times_s": _list(res.times_s[order]),
            "frames": [res.frame_names[i] for i in order],
            "rms_px": _list(rms),
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
                           "num_candidates": 0, "per_frame_mean_px": _list(per_frame_mean(res))}
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
    out.update(index=index, frame=res.frame_names[index], lr=_finite_or_none(lr[best]),
               f_stat=_finite_or_none(f_stat), p_value=p,
               significant=bool(p is not None and p < ALPHA),
               explained_fraction=_finite_or_none(1.0 - rss1[best] / rss0),
               step_px=_finite_or_none(np.sqrt(np.mean(diff ** 2))) if diff.size else None,
               mean_before_px=_list(seg_b), mean_after_px=_list(seg_a),
               num_candidates=int(len(splits)))
    return out


def analyse_overall(res: ResidualSet) -> dict:
    """n used, frames, RMS (px), median and 95th percentile of |r| (px), mean vector (px)."""
    r, f, _ = _used_residuals(res)
    mag = np.hypot(r[:, 0], r[:, 1])
    n = len(r)
    return {"n_used": n, "n_observed": int(np.count_nonzero(np.all(np.isfinite(
                res.uv_observed), -1))),
            "n_frames": len(res.frame_names), "n_frames_used": int(len(np.unique(f))),
            "n_keypoints": len(res.keypoint_names),
            "rms_px": _finite_or_none(np.sqrt(np.mean(mag ** 2))) if n else None,
            "median_abs_px": _finite_or_none(np.median(mag)) if n else None,
            "p95_abs_px": _finite_or_none(np.percentile(mag, 95)) if n else None,
            "mean_px": _list(r.mean(0)) if n else None}


def analyse(res: ResidualSet) -> dict:
    """All residual statistics of `res` as a JSON-serialisable dict.

    Sections: `overall` (`analyse_overall`), `per_keypoint` (`analyse_keypoints`), `radial`
    (`analyse_radial`), `per_joint` (`analyse_joints`), `time` (`analyse_time`, None without
    timestamps), `change_point` (`analyse_change_point`), and `alpha` (the level of the
    `significant` flags).
    """
    if not isinstance(res, ResidualSet):
        raise InputError(f"analyse needs a ResidualSet, got {type(res).__name__}")
    log.debug("analysing %d used residuals of %d frames", res.num_used, len(res.frame_names))
    return {"alpha": ALPHA,
            "overall": analyse_overall(res),
            "per_keypoint": analyse_keypoints(res),
            "radial": analyse_radial(res),
            "per_joint": analyse_joints(res),
            "time": analyse_time(res),
            "change_point": analyse_change_point(res)}
