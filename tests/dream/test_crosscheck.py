"""The silhouettes' cross-check's arbitration between a kept edge alignment and the keypoint
pose it started from (`dream.coarse.crosscheck.undoes_alignment`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dream.coarse.away import AwayPixels
from dream.coarse.crosscheck import Crosscheck, undoes_alignment
from dream.coarse.settings import SearchSettings
from dream.metrics import pose_errors
from tests.dream.test_challenge import outcome_at

SETTINGS = SearchSettings()
FOUND, MISSED = SETTINGS.min_found_iou + 0.3, SETTINGS.min_found_iou - 0.2


def along_depth(metres: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.05, 1.2 + metres]
    return T


def check_at(T_aligned: np.ndarray, T_optimum: np.ndarray, optimum_iou: float) -> Crosscheck:
    """A cross-check made at `T_aligned` whose optimum is `T_optimum` at `optimum_iou`, with
    nothing moving away from the robot."""
    m, rad = pose_errors(T_aligned, T_optimum)
    away = AwayPixels(np.full(3, 100), np.zeros(3), np.full(3, 0.7), np.full(3, 0.7))
    return Crosscheck(outcome_at(T_optimum, optimum_iou), 0.6, float(m), float(rad),
                      "motion masks", 3, away, 0.6)


@pytest.mark.parametrize(("slide_m", "optimum_iou", "undone"), [
    (0.02, FOUND, True),        # slid 2 cm off the silhouettes' optimum at the keypoint pose
    (0.004, FOUND, False),      # within the cues' agreement: the alignment stands
    (0.02, MISSED, True),       # masks holding a person too still arbitrate
])
def test_the_silhouettes_undo_only_a_slide_beyond_the_cues_agreement(slide_m, optimum_iou, undone):
    T_keypoints, T_aligned = along_depth(0.0), along_depth(slide_m)
    T_optimum = along_depth(0.0005)
    undo, to_keypoints, to_aligned = undoes_alignment(
        check_at(T_aligned, T_optimum, optimum_iou), T_keypoints, T_aligned, SETTINGS)
    assert undo is undone
    assert to_keypoints == pytest.approx(0.0005)
    assert to_aligned == pytest.approx(slide_m - 0.0005)


def test_an_optimum_nearer_the_aligned_pose_keeps_it():
    T_keypoints, T_aligned = along_depth(0.0), along_depth(0.03)
    undo, _, _ = undoes_alignment(check_at(T_aligned, along_depth(0.028), FOUND), T_keypoints,
                                  T_aligned, SETTINGS)
    assert not undo


def test_the_intrinsics_move_runs_from_the_optimum_to_the_pose_through_all_they_ask():
    """A focal length asked for (the pose through it 3 cm along the axis) and a principal point
    flagged from there (2 cm further): the covariance holds the whole 5 cm move, not the two
    parts apart; where the outlines agree with the given intrinsics, nothing; a distortion
    asked for alone, its move and its spread."""
    from dream.camera import CameraIntrinsics
    from dream.coarse.distortion import DistortionEstimate
    from dream.coarse.focal import FocalEstimate
    from dream.coarse.principal import PrincipalEstimate
    from dream.pnp import increment_between

    camera = CameraIntrinsics(300.0, 300.0, 159.5, 119.5, 320, 240)
    T_optimum, T_focal, T_principal = along_depth(0.0), along_depth(0.03), along_depth(0.05)
    check = check_at(T_optimum, T_optimum, FOUND)
    focal = FocalEstimate(0.95, 0.01, 0.60, 0.62, 2, True, "asked", camera, camera, T_focal,
                          np.zeros(6), 0.0)
    principal = PrincipalEstimate(np.array([12.0, -8.0]), np.ones(2), 0.05, 2, True, "flagged",
                                  camera, T_principal, increment_between(T_focal, T_principal))
    asked = replace(check, focal=focal, principal=principal).intrinsics_covariance
    assert asked[5, 5] == pytest.approx(0.05 ** 2)
    agreeing = replace(check, focal=replace(focal, adopted=False),
                       principal=replace(principal, flagged=False))
    assert not np.any(agreeing.intrinsics_covariance)
    # a lens distortion asked for first (2 cm), and nothing after it: its move and spread
    lens = DistortionEstimate(-0.14, 0.001, 0.0, float("nan"), 0.6, 0.65, 2, True, "asked",
                              camera, camera, along_depth(0.02), np.eye(6)[:, [5]],
                              np.full((1, 1), 1e-4))
    distorted = replace(agreeing, distortion=lens).intrinsics_covariance
    assert distorted[5, 5] == pytest.approx(0.02 ** 2 + 1e-4)
    assert replace(agreeing, distortion=lens).to_dict()["distortion"]["asked"]


def test_a_focal_1_sigma_without_enough_frame_groups_is_written_as_null():
    import json

    from dream.camera import CameraIntrinsics
    from dream.coarse.focal import FocalEstimate

    camera = CameraIntrinsics(300.0, 300.0, 159.5, 119.5, 320, 240)
    focal = FocalEstimate(1.01, float("nan"), 0.6, 0.6, 1, False, "r", camera, camera,
                          np.eye(4), np.zeros(6), 0.01)
    assert json.loads(json.dumps(focal.to_dict(), allow_nan=False))["sigma_relative"] is None
