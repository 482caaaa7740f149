"""Observed vs predicted keypoints of one model (`ResidualSet`) and their per-frame summaries.

The residual is `r = uv_observed - uv_predicted` (pixels). Values meant for JSON go through
`float_list` (None in place of NaN, as `dream.arrays.finite_or_none`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.arrays import finite_or_none, read_only
from dream.camera import CameraIntrinsics
from dream.errors import InputError

MAX_VELOCITY_GAP_FACTOR = 5.0  # no finite difference across a gap > this x the median dt


def float_list(a: np.ndarray) -> list:
    """Nested list of floats with None in place of NaN."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 0:
        return finite_or_none(a)  # type: ignore[return-value]
    return [float_list(x) for x in a]


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


def used_residuals(res: ResidualSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Used residuals (N, 2) px with their frame (N,) and keypoint (N,) indices."""
    f, k = np.nonzero(res.used)
    return res.residual[f, k], f, k
