"""What the extended model still does not explain, and whether it looks like detector error.

A model error (a lens, a link, a lag) moves many keypoints in a pattern; a detector that
misplaces one or two keypoints on these photos (a gripper it has not seen, a board in the hand)
leaves its misfit on them alone. After the search, the remaining squared residual is split by
keypoint: when at most `CONFINED_MAX_KEYPOINTS` keypoints carry at least `CONFINED_SHARE` of it,
and at least `CONFINED_RATIO` times their share of the observations, the report says the
remaining misfit looks like detector error on them; otherwise it is spread over the keypoints.

    >>> import numpy as np
    >>> r = np.zeros((10, 3, 2)); r[:, 2] = 5.0
    >>> remaining_misfit(r, np.ones((10, 3), bool), ("a", "b", "c"), 4.0, 3.0)["confined_to"]
    ['c']
"""

from __future__ import annotations

from typing import Any

import numpy as np

CONFINED_SHARE = 0.5
CONFINED_MAX_KEYPOINTS = 2
CONFINED_RATIO = 2.0


def remaining_misfit(residual: np.ndarray, mask: np.ndarray, keypoint_names: tuple[str, ...],
                     baseline_rmse_px: float, final_rmse_px: float) -> dict[str, Any]:
    """diagnosis.json's `remaining`: the share of the baseline's held-out mean squared error
    left unexplained, the per-keypoint shares of the remaining squared residual (F, K, 2) over
    `mask` (F, K), and the keypoints it is confined to (empty: spread)."""
    sq = np.where(mask[..., None], np.nan_to_num(residual), 0.0) ** 2
    per_keypoint = sq.sum(axis=(0, 2))
    counts = mask.sum(axis=0)
    total = float(per_keypoint.sum())
    share = per_keypoint / total if total > 0 else np.zeros(len(keypoint_names))
    obs_share = counts / max(int(counts.sum()), 1)
    order = np.argsort(-share)
    top = order[:int(np.searchsorted(np.cumsum(share[order]), CONFINED_SHARE) + 1)]
    confined = (total > 0 and len(top) <= CONFINED_MAX_KEYPOINTS
                and share[top].sum() >= CONFINED_RATIO * obs_share[top].sum())
    names = [keypoint_names[k] for k in top] if confined else []
    rms = np.sqrt(per_keypoint / np.maximum(counts, 1))
    looks = (f"detector error on {', '.join(names)}: {share[top].sum():.0%} of the remaining "
             f"misfit on {obs_share[top].sum():.0%} of the observations, which no model effect "
             "explains" if confined else "spread over the keypoints: noise, or an effect the "
             "catalog lacks")
    unexplained = (final_rmse_px / baseline_rmse_px) ** 2 if baseline_rmse_px > 0 else None
    return {"unexplained_share": unexplained, "rmse_px": final_rmse_px,
            "per_keypoint": {n: {"share": float(share[k]), "rmse_px": float(rms[k])}
                             for k, n in enumerate(keypoint_names)},
            "confined_to": names, "looks_like": looks}
