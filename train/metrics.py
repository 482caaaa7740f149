"""Keypoint metrics of predicted belief maps, through the real peak finder (`dream.peaks`).

Errors are in network-input pixels. A keypoint is scored when its ground truth lies inside the
input frame; one not found counts as a miss in PCK and has no L2 error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.errors import InputError
from dream.peaks import PeakSettings, find_peaks_batch


@dataclass(frozen=True)
class KeypointErrors:
    """Per-keypoint results of a batch.

    Attributes:
        error_px: (N, K) L2 error in input pixels; NaN where not scored or not found.
        scored: (N, K) bool: the ground truth is inside the input frame.
        found: (N, K) bool: the peak finder found the keypoint.
    """

    error_px: np.ndarray
    scored: np.ndarray
    found: np.ndarray


def keypoint_errors(belief: np.ndarray, uv_true_input: np.ndarray, stride: int,
                    input_width: int, input_height: int,
                    params: PeakSettings | None = None) -> KeypointErrors:
    """Peaks of (N, K, h, w) belief maps against (N, K, 2) true keypoints in input pixels."""
    belief = np.asarray(belief)
    uv_true = np.asarray(uv_true_input, dtype=float)
    if belief.ndim != 4 or uv_true.shape != belief.shape[:2] + (2,):
        raise InputError(f"belief {belief.shape} and keypoints {uv_true.shape} must be "
                         f"(N, K, h, w) and (N, K, 2)")
    N, K = belief.shape[:2]
    uv_pred = np.full((N, K, 2), np.nan)
    found = np.zeros((N, K), bool)
    for n, in_map in enumerate(find_peaks_batch(belief, params)):
        peaks = in_map.to_input(stride)
        uv_pred[n], found[n] = peaks.uv_input, peaks.found
    with np.errstate(invalid="ignore"):
        scored = ((uv_true[..., 0] >= -0.5) & (uv_true[..., 0] <= input_width - 0.5)
                  & (uv_true[..., 1] >= -0.5) & (uv_true[..., 1] <= input_height - 0.5))
    error = np.linalg.norm(uv_pred - uv_true, axis=-1)
    error = np.where(scored & found, error, np.nan)
    return KeypointErrors(error, scored, found)


def summarize(results: list[KeypointErrors], pck_threshold_px: float) -> dict[str, float]:
    """Median and mean L2 (input px, found keypoints), PCK at the threshold and the detection
    rate, over the scored keypoints of all batches. NaN when nothing was scored."""
    if not results:
        return {"l2_median_px": float("nan"), "l2_mean_px": float("nan"), "pck": float("nan"),
                "found_rate": float("nan")}
    error = np.concatenate([r.error_px.ravel() for r in results])
    scored = np.concatenate([r.scored.ravel() for r in results])
    found = np.concatenate([r.found.ravel() for r in results])
    n = int(scored.sum())
    good = error[np.isfinite(error)]
    nan = float("nan")
    return {
        "l2_median_px": float(np.median(good)) if len(good) else nan,
        "l2_mean_px": float(np.mean(good)) if len(good) else nan,
        "pck": float(np.sum(good <= pck_threshold_px) / n) if n else nan,
        "found_rate": float(np.sum(found & scored) / n) if n else nan,
    }
