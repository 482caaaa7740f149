"""The quality verdict of a calibration: how much of its keypoint evidence the pose stands on.

A robust keypoint fit discards the detections that disagree with it. When most of them
disagree, the fit may stand on a small consensus of a biased set (a detector that misplaces
keypoints on these photos, joint readings that do not match the images): it can fit those few
to a fraction of a pixel at a pose centimetres off, and its small RMSE and 1-sigma then say
nothing about the error. The verdict says so instead of passing a confident pose, and names
the image refinement (`--polish`, `--refine edges`) when one was kept: its pose does not rest on
that consensus.

RESULT.json's `quality` object: `detections` (keypoints found), `kept` (inliers of the fit),
`kept_share`, `verdict` ("ok" or "doubtful") and `warnings` (sentences).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from dream.calibration import CalibrationResult, Observations
from dream.errors import InputError

# Below this share of the detections kept by the fit, the verdict is "doubtful". With the
# bundled model on rendered fixed-camera scenes (benchmarks/edge_align.py's seeds 100-119)
# the all-frames fit keeps 66-89 % of the detections.
MIN_KEPT_SHARE = 0.5
OK, DOUBTFUL = "ok", "doubtful"


@dataclass(frozen=True)
class Quality:
    """The verdict on a calibration (module doc).

    Attributes:
        detections: keypoint detections found. kept: of them, inliers of the fit.
        verdict: OK or DOUBTFUL. warnings: why, one sentence each with what to do.
    """

    detections: int
    kept: int
    verdict: str
    warnings: tuple[str, ...]

    def __post_init__(self) -> None:
        if not 0 <= self.kept <= self.detections:
            raise InputError(f"kept ({self.kept}) must lie in [0, detections "
                             f"({self.detections})]")
        if self.verdict not in (OK, DOUBTFUL):
            raise InputError(f"verdict must be '{OK}' or '{DOUBTFUL}', got '{self.verdict}'")

    @property
    def kept_share(self) -> float:
        return self.kept / self.detections if self.detections else 0.0

    def to_dict(self) -> dict[str, Any]:
        """RESULT.json's `quality` object."""
        return {"detections": self.detections, "kept": self.kept,
                "kept_share": self.kept_share, "verdict": self.verdict,
                "warnings": list(self.warnings)}


def keypoint_quality(detections: int, kept: int, refined_by: str | None = None,
                     min_kept_share: float = MIN_KEPT_SHARE) -> Quality:
    """The verdict from the counts of detections found and kept (pure); `refined_by` names an
    image refinement that was kept ("the silhouette polish", "the edge alignment").

    >>> keypoint_quality(70, 20).verdict
    'doubtful'
    >>> keypoint_quality(210, 180).warnings
    ()
    """
    if not 0 < min_kept_share <= 1:
        raise InputError(f"min_kept_share must lie in (0, 1], got {min_kept_share}")
    share = kept / detections if detections else 0.0
    if share >= min_kept_share:
        return Quality(detections, kept, OK, ())
    warning = (f"only {kept} of {detections} keypoint detections ({share:.0%}) agree with the "
               "keypoint pose: it may follow a biased few, and its RMSE and 1-sigma do not "
               "measure its error")
    if refined_by:
        warning += f"; the pose kept is {refined_by}'s, which does not rest on them"
        return Quality(detections, kept, OK, (warning,))
    return Quality(detections, kept, DOUBTFUL, (warning + "; check the overlays (--overlays "
                                                "DIR) or refine with the images (--polish "
                                                "with masks, --refine edges without)",))


def result_quality(result: CalibrationResult, obs: Observations,
                   refined_by: str | None = None) -> Quality:
    """`keypoint_quality` of a calibration: its detections found and its inliers."""
    found = obs.found
    return keypoint_quality(int(found.sum()), int(np.sum(result.inlier & found)), refined_by)
