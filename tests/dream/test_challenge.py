"""Another cue's optimum against the search's winner on the masks (`dream.coarse.challenge`):
a right pose wins over a wrong winner, a wrong one loses to a right winner, a pose next to
the winner is not a challenge, and the masks choose the pose written between the two."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from dream.coarse.calibration import DATA_MASKS, SearchMasks
from dream.coarse.challenge import Challenge, between, challenged
from dream.coarse.search import Candidate, SearchOutcome, pose_iou
from dream.coarse.settings import SearchSettings
from dream.metrics import pose_errors
from dream.transforms import make_T
from tests.dream.test_coarse import SMALL, off_by, rendered_masks
from tests.dream.test_edges import CAMERA

WRONG_M, WRONG_RAD = 0.15, np.deg2rad(8.0)     # a winner in the wrong basin


def outcome_at(T: np.ndarray, iou: float) -> SearchOutcome:
    """A search's outcome whose winner is `T` (its checks left empty)."""
    none = np.zeros((0, 6))
    return SearchOutcome(Candidate(T, "guess", iou, iou), None, (Candidate(T, "guess", iou, iou),),
                         {"guess": 1}, 0, 0, np.zeros((0, 4, 4)), none, none, (), 1.0)


def test_a_right_optimum_wins_over_a_wrong_winner_and_a_wrong_one_loses(panda, meshes):
    T_true, joints, masks = rendered_masks(panda, meshes)
    inputs = SearchMasks(meshes, np.arange(len(joints)), joints, masks, DATA_MASKS, (),
                         np.arange(len(joints)))
    settings = replace(SMALL, basin_starts=1)
    T_wrong = off_by(T_true, WRONG_M, WRONG_RAD, 0)
    iou_wrong = pose_iou(meshes, joints, masks, CAMERA, T_wrong, settings)
    lines: list[str] = []
    outcome, challenge = challenged(CAMERA, inputs, outcome_at(T_wrong, iou_wrong),
                                    off_by(T_true, 0.01, np.deg2rad(0.5), 1), "the edge alignment",
                                    settings,
                                    lines.append)
    assert isinstance(challenge, Challenge) and challenge.won
    assert challenge.iou_challenger > 0.9 > challenge.iou_winner
    assert challenge.distance_m > 0.1 and "the edge alignment's optimum" in lines[0]
    m, rad = pose_errors(outcome.best.T_cam_base, T_true)
    assert m < 0.005 and rad < np.deg2rad(0.3), (m, np.rad2deg(rad))
    assert outcome.basin_starts == 1 and len(outcome.frames_xi) and "guess" in outcome.hypotheses
    assert pose_errors(challenge.T_cam_base_between, T_true)[0] < 0.01

    right = outcome_at(T_true, 1.0)
    kept, lost = challenged(CAMERA, inputs, right, T_wrong, "the edge alignment", settings)
    assert lost is not None and not lost.won and lost.iou_challenger < lost.iou_winner
    assert kept.best is right.best
    near, none = challenged(CAMERA, inputs, right, off_by(T_true, 0.002, 0.001, 2),
                            "the edge alignment", settings)
    assert none is None and near is right


class PeakAt:
    """A stand-in for `Scales` whose IoU peaks where the camera's x translation is `peak_m`."""

    def __init__(self, peak_m: float):
        self.peak_m = peak_m

    def iou(self, T: np.ndarray) -> float:
        return 1.0 - abs(float(T[0, 3]) - self.peak_m)


def test_the_masks_choose_the_pose_between_the_two_optima():
    T_a, T_b = np.eye(4), make_T(np.eye(3), np.array([0.1, 0.0, 0.0]))
    share, T, iou = between(PeakAt(0.03), T_a, T_b)
    assert np.isclose(share, 0.3) and np.allclose(T[:3, 3], [0.03, 0, 0]) and np.isclose(iou, 1.0)
    assert between(PeakAt(-0.05), T_a, T_b)[0] == 0.0       # never beyond the two ends
    assert between(PeakAt(0.5), T_a, T_b)[0] == 1.0
    flat = between(PeakAt(0.0), T_a, T_a)
    assert flat[0] == 0.0 and np.allclose(flat[1], T_a)     # equals: the winner


def test_the_masks_own_optimum_is_the_finished_challenger_where_every_frame_prefers_it():
    """The search run again returned to the winner, but the other cue's optimum finished on
    the masks explains every frame clearly better: that is the masks' optimum the cues'
    disagreement is measured from; a challenger about as good, one that won, or one never
    finished leaves it the winner."""
    T_winner, T_finished = np.eye(4), np.eye(4)
    T_finished[0, 3] = 0.04

    def challenge(iou_challenger: float, won: bool = False, finished=T_finished) -> Challenge:
        return Challenge("the edge alignment", 0.73, iou_challenger, 0.042, 0.03, won, 1.0,
                         iou_challenger, T_finished, finished)

    settings = SearchSettings()
    clearly = 0.73 + 2 * settings.min_gap
    assert challenge(clearly).masks_optimum(T_winner, settings) is T_finished
    for same in (challenge(0.731), challenge(clearly, won=True),
                 challenge(clearly, finished=None)):
        assert same.masks_optimum(T_winner, settings) is T_winner
