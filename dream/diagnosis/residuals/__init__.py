"""Residual analysis of a calibrated sequence: where the nominal model misses, and how.

Every effect of the catalog (`dream.extension`) leaves a signature in the keypoint residuals
`r = uv_observed - uv_predicted` (pixels):

- `keypoint_bias`: a constant offset of one keypoint (`per_keypoint`, Hotelling's T^2 test;
  module `image`).
- `lens_distortion` / `intrinsics_error`: a radial component growing as r^3 (k1) or as r (a
  focal scale error) with the distance r from the principal point (`radial`; module `image`).
- `joint_offset`: residuals that vary with a joint's angle (`per_joint`; module `joints`).
- `time_offset`: residuals proportional to the keypoints' image velocity (`time`; module
  `temporal`).
- `camera_moved`: a step in the residuals at one frame (`change_point`; module `temporal`).

All functions are pure and return plain JSON-serialisable values (floats, ints, strings,
bools, lists, dicts; `None` where a statistic is undefined, never NaN).

The p-values treat the used observations as independent. On real data residuals are
correlated within a frame and across neighbouring frames, so they are optimistic: read them
as scores for ranking hypotheses, and let held-out prediction decide (`dream.diagnosis`).

Public API:
    ResidualSet(...)                     observed vs predicted keypoints of one model
    analyse(res) -> dict                 all sections below
    per_frame_rms(res) -> (F,)           px, NaN where a frame has no used keypoint
    per_frame_mean(res) -> (F, 2)        px, NaN where a frame has no used keypoint
    image_velocity(res) -> (F, K, 2)     px/s of uv_predicted, NaN where unknown
"""

from __future__ import annotations

import logging

from dream.diagnosis.residuals.image import analyse_keypoints, analyse_overall, analyse_radial
from dream.diagnosis.residuals.joints import analyse_joints
from dream.diagnosis.residuals.regression import ALPHA
from dream.diagnosis.residuals.residual_set import (
    ResidualSet,
    image_velocity,
    per_frame_mean,
    per_frame_rms,
)
from dream.diagnosis.residuals.temporal import (
    analyse_change_point,
    analyse_time,
    analyse_velocity,
)
from dream.errors import InputError

__all__ = ["ALPHA", "ResidualSet", "analyse", "analyse_change_point", "analyse_joints",
           "analyse_keypoints", "analyse_overall", "analyse_radial", "analyse_time",
           "analyse_velocity", "image_velocity", "per_frame_mean", "per_frame_rms"]

log = logging.getLogger(__name__)


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
