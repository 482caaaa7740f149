"""Image evidence during the diagnosis's search: an effect significant on the keypoints that the
images contradict (`dream.diagnosis.images.OutlineJudge.veto`) is not accepted."""

from __future__ import annotations

import numpy as np
import pytest

from dream.diagnosis.fit import Model, candidate_params
from dream.diagnosis.fit.model import FitResult
from dream.diagnosis.images import OutlineJudge, outline_judge
from dream.diagnosis.run import diagnose_sequence, problem_from
from dream.errors import InputError
from dream.io import read_sequence
from dream.pipeline import observations_from_labels
from dream.silhouette import load_robot_meshes
from dream.transforms import T_from_rotvec_t
from tests.dream.test_diagnose import _case
from tests.dream.test_edges import image_dataset

OFF_M = 0.02   # a fit this far off the true camera puts the outline beside the arm's edges


class _Against:
    """A judge that objects to every effect, and counts what it was asked."""

    def __init__(self):
        self.asked = 0

    def veto(self, candidate, current):
        self.asked += 1
        return "the images contradict it: test"


def test_a_vetoed_effect_is_not_accepted():
    seq, robot, _ = _case("link_length", 7040)
    judge = _Against()
    doc, diagnosis, _ = diagnose_sequence(seq, robot, observations_from_labels(seq, robot),
                                          judge=judge)
    assert judge.asked >= 1 and doc["verdict"] == [] and diagnosis.extension.is_empty
    entry = next(e for e in doc["effects"] if e["name"] == "link_length")
    assert "the images contradict it" in entry["evidence"]


def _fit(problem, T: np.ndarray, move_m: float | None = None) -> FitResult:
    """A fit at T; with `move_m`, a camera that moved by that much along x at the middle
    frame."""
    params, x, change = (), np.zeros(6), None
    if move_m is not None:
        params = tuple(candidate_params("camera_moved", problem))
        x = np.concatenate([np.zeros(6), [0.0, 0.0, 0.0, move_m, 0.0, 0.0]])
        change = problem.num_frames // 2
    n = len(x)
    return FitResult(Model(problem, params, T, change), x, np.full((n, n), np.nan),
                     np.zeros(problem.uv.shape), 0.0, 0)


def test_the_judge_scores_each_fit_at_its_own_and_at_its_aligned_extrinsic(panda, tmp_path):
    """An extrinsic 2 cm off lowers the outline's agreement at that extrinsic (a veto), but
    not once aligned to the edges."""
    T_true = image_dataset(panda, load_robot_meshes(panda), tmp_path)
    seq = read_sequence(tmp_path / "data")
    problem = problem_from(seq, panda, observations_from_labels(seq, panda))
    judge = outline_judge(seq, problem)
    assert isinstance(judge, OutlineJudge)
    T_off = T_from_rotvec_t(np.zeros(3), np.array([OFF_M, 0.0, 0.0])) @ T_true
    true, off = _fit(problem, T_true), _fit(problem, T_off)
    assert judge.score(true).agreement > judge.score(off).agreement + 0.05
    assert judge.aligned_score(off).agreement == pytest.approx(
        judge.aligned_score(true).agreement, abs=0.02)
    assert judge.aligned_score(off) is judge.aligned_score(off)   # remembered per fit
    assert "contradict" in judge.veto(off, true)
    assert judge.veto(true, off) is None and judge.veto(true, true) is None
    known = np.arange(len(seq)) < len(seq) - 2     # e.g. a held log's last update before them
    assert outline_judge(seq, problem, known=known).chosen.max() < len(seq) - 2
    with pytest.raises(InputError, match="known must be"):
        outline_judge(seq, problem, known=known[1:])


def test_a_camera_move_is_scored_with_each_frames_pose(panda, tmp_path):
    T_true = image_dataset(panda, load_robot_meshes(panda), tmp_path)
    seq = read_sequence(tmp_path / "data")
    problem = problem_from(seq, panda, observations_from_labels(seq, panda))
    judge = outline_judge(seq, problem)
    still = judge.score(_fit(problem, T_true)).agreement
    assert judge.score(_fit(problem, T_true, 0.0)).agreement == pytest.approx(still)
    assert judge.score(_fit(problem, T_true, OFF_M)).agreement < still - 0.05
    assert "contradict" in judge.veto(_fit(problem, T_true, OFF_M), _fit(problem, T_true))


@pytest.mark.parametrize("effect, value", [("link_length", 0.05), ("intrinsics_error", 0.05)])
def test_the_judge_draws_the_fits_own_links_and_camera(panda, tmp_path, effect, value):
    """A link 5 cm longer, or a focal length 5 % longer, moves the drawn outline off the
    arm's edges at the true pose."""
    T_true = image_dataset(panda, load_robot_meshes(panda), tmp_path)
    seq = read_sequence(tmp_path / "data")
    problem = problem_from(seq, panda, observations_from_labels(seq, panda))
    judge = outline_judge(seq, problem)
    params = tuple(candidate_params(effect, problem))[:1]
    nan = np.full((7, 7), np.nan)

    def fit(v: float) -> FitResult:
        return FitResult(Model(problem, params, T_true), np.append(np.zeros(6), v), nan,
                         np.zeros(problem.uv.shape), 0.0, 0)

    assert judge.score(fit(0.0)).agreement == pytest.approx(judge.score(_fit(problem, T_true))
                                                            .agreement)
    assert judge.score(fit(value)).agreement < judge.score(fit(0.0)).agreement - 0.02


def test_the_judge_refuses_a_link_length_that_no_extrinsic_makes_up_for(panda, tmp_path):
    """The forearm 5 cm longer bends the drawn arm: aligning the extrinsic cannot hide it."""
    T_true = image_dataset(panda, load_robot_meshes(panda), tmp_path)
    seq = read_sequence(tmp_path / "data")
    problem = problem_from(seq, panda, observations_from_labels(seq, panda))
    judge = outline_judge(seq, problem)
    params = tuple(p for p in candidate_params("link_length", problem)
                   if p.name == "panda_joint5")
    nan = np.full((7, 7), np.nan)

    def fit(v: float) -> FitResult:
        return FitResult(Model(problem, params, T_true), np.append(np.zeros(6), v), nan,
                         np.zeros(problem.uv.shape), 0.0, 0)

    assert (judge.aligned_score(fit(0.05)).agreement
            < judge.aligned_score(fit(0.0)).agreement - 0.05)
    assert "contradict" in judge.veto(fit(0.05), fit(0.0))
    # a baseline whose extrinsic is off agrees less at its own extrinsic than the longer
    # forearm at the true one, but not once each is aligned: still refused
    off = _fit(problem, T_from_rotvec_t(np.zeros(3), np.array([OFF_M, 0.0, 0.0])) @ T_true)
    assert judge.score(fit(0.05)).agreement > judge.score(off).agreement
    assert "aligned to the edges" in judge.veto(fit(0.05), off)
    assert judge.veto(fit(0.0), fit(0.05)) is None
