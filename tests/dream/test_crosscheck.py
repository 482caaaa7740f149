"""The silhouettes' cross-check's arbitration between a kept edge alignment and the keypoint
pose it started from (`dream.coarse.crosscheck.undoes_alignment`)."""

from __future__ import annotations

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
