"""The joint log's lag read off the silhouettes (`dream.coarse.timing`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dream.coarse import calibration
from dream.coarse.calibration import (
    DATA_MASKS,
    TIMING,
    CameraGuess,
    MarkStart,
    SearchMasks,
    searched_again,
)
from dream.coarse.focal import FocalSettings
from dream.coarse.mark import Mark, mark_points
from dream.coarse.search import find_winner
from dream.coarse.timing import (
    LagEstimate,
    TimingSettings,
    best_lag,
    lag_applied,
    lag_profile,
    read_lag,
    shifted_joints,
    timing_finding,
    with_lag,
    with_timing,
)
from dream.errors import InputError
from dream.metrics import pose_errors
from dream.sequence import Frame, Sequence
from dream.silhouette import render_silhouette
from dream.transforms import look_at
from tests.dream.test_coarse import SMALL, off_by
from tests.dream.test_edges import CAMERA, TARGET

LAG_S = 0.06          # the readings lag the images by this in the rendered trajectory
FPS = 10.0
FRAMES = 20
GRID = TimingSettings(max_lag_s=0.16, step_s=0.02)


def absorbing(true_lag: float, share: float, growth: float = 0.0):
    """A search whose pose takes up `share` of the lag it is not given (plus `growth` times
    the share of the true lag it was given: more as it nears it): the IoU at a lag peaks
    between the true lag and the lag the pose was found with; returns (iou_at, search_from,
    the lags searched with)."""
    searched = [0.0]

    def iou_at(lag: float) -> float:
        taken = share + growth * searched[-1] / true_lag
        peak = taken * searched[-1] + (1 - taken) * true_lag
        return 0.8 - 60 * (lag - peak) ** 2      # 0.15 lost 50 ms off, as on renders

    return iou_at, searched.append, searched


@pytest.mark.parametrize("growth", [0.0, 0.3])
def test_read_lag_follows_a_lag_the_pose_took_up_in_part(growth: float) -> None:
    """Also where the pose takes up more of the lag the nearer it is given (as on renders),
    so that the lag read lies within the resolution of the one in use 7 ms short of the
    true one."""
    iou_at, search_from, searched = absorbing(0.05, share=0.6, growth=growth)
    estimate = read_lag(iou_at, search_from, GRID, lambda line: None)
    assert estimate.adopted and abs(estimate.seconds - 0.05) < 2 * GRID.resolution_s, estimate
    assert estimate.rounds == len(searched) - 1 >= 2
    assert estimate.iou_at_lag > estimate.iou_as_stamped
    assert estimate.sigma_s >= GRID.sigma_fraction * estimate.seconds > 0


def test_read_lag_adopts_nothing_where_the_stamps_fit() -> None:
    iou_at, search_from, searched = absorbing(0.004, share=0.0)
    estimate = read_lag(iou_at, search_from, GRID, lambda line: None)
    assert not estimate.adopted and estimate.seconds == 0.0 and searched == [0.0]
    assert "+4.0 ms" in estimate.reason and timing_finding(estimate.to_dict()) is None


def test_best_lag_keeps_a_peak_at_the_grids_end_and_settings_are_checked() -> None:
    lags = np.array([0.0, 0.02, 0.04])
    assert best_lag(lags, np.array([0.1, 0.2, 0.3])) == 0.04
    with pytest.raises(InputError, match="step_s"):
        TimingSettings(max_lag_s=0.01, step_s=0.02)
    with pytest.raises(InputError, match="rounds"):
        TimingSettings(rounds=0)


def trajectory(panda, seed: int = 0) -> np.ndarray:
    """(FRAMES, J) every joint swinging back and forth about its middle at FPS (a pose
    cannot take up a lag of motions that reverse)."""
    rng = np.random.default_rng(seed)
    middle = 0.5 * (panda.joint_lower + panda.joint_upper)
    dof = len(middle)
    phase, speed = rng.uniform(0, 2 * np.pi, dof), rng.uniform(3.0, 5.0, dof)
    t = np.arange(FRAMES)[:, None] / FPS
    return middle + 0.3 * np.sin(speed * t + phase)


def test_a_lagging_joint_log_is_read_off_the_silhouettes_and_the_pose_follows(panda, meshes,
                                                                             monkeypatch):
    """Masks of a swinging arm, readings stamped LAG_S late: the lag is found within a
    hundredth of a second, the pose searched again with it lands nearer the truth, and the
    finding names it, also where the first winner fails the found test; the readings on time
    leave the search alone."""
    T_true = look_at(TARGET + np.array([1.3, 0.5, 0.6]), TARGET)
    t = np.arange(FRAMES) / FPS
    q_image = trajectory(panda)
    masks = np.stack([render_silhouette(meshes, q, T_true, CAMERA) for q in q_image])
    # a reading stamped s shows the arm at s - LAG_S
    readings = shifted_joints(q_image, t, -LAG_S)
    frames = tuple(Frame(name=f"{i:06d}", joints=readings[i], timestamp=float(t[i]))
                   for i in range(FRAMES))
    seq = Sequence(robot="panda", camera=CAMERA, joint_names=panda.joint_names,
                   keypoint_names=(), frames=frames)
    start = {"guess": off_by(T_true, 0.02, 0.02, 3)[None]}
    everything = np.arange(FRAMES)

    def again(moved: SearchMasks, last):
        return searched_again(CAMERA, moved, last, last.best.T_cam_base, TIMING, SMALL)

    def found(joints):
        winner = find_winner(meshes, joints, masks, CAMERA, start, SMALL)
        inputs = SearchMasks(meshes, everything, joints, masks, DATA_MASKS, (), everything)
        return winner, with_timing(seq, joints, inputs, winner, SMALL, GRID, again, False)

    first, (winner, inputs) = found(readings)
    assert isinstance(inputs.timing, LagEstimate)
    assert abs(inputs.timing.seconds - LAG_S) < 0.01, inputs.timing
    assert TIMING in winner.hypotheses
    before = pose_errors(first.best.T_cam_base, T_true)[0]
    after = pose_errors(winner.best.T_cam_base, T_true)[0]
    assert after < before, (before, after)
    assert timing_finding(inputs.timing.to_dict())[0] == "check"
    assert np.linalg.norm(inputs.timing.xi_per_second) > 0
    assert np.trace(inputs.timing.pose_covariance) > 0
    shifted = with_lag(seq, inputs.timing.seconds).joints
    assert np.allclose(shifted[2:-2], q_image[2:-2], atol=0.01)   # the arm as the images show
    _, (_, on_time) = found(q_image)
    assert not on_time.timing.adopted and abs(best_lag(on_time.timing.lags_s,
                                                       on_time.timing.ious)) < 0.01
    # a late log can keep the right pose's first winner below the found test: the lag is read
    # there all the same, and the search goes on from the winner with it
    found_iou = 0.5 * (first.best.iou + winner.best.iou)
    searched = searched_below_the_found_test(monkeypatch, seq, panda, first, SearchMasks(
        meshes, everything, readings, masks, DATA_MASKS, (), everything), found_iou)
    outcome, inputs = searched
    assert inputs.timing is not None and inputs.timing.adopted, inputs.timing
    assert TIMING in outcome.hypotheses and outcome.best.iou >= found_iou
    assert pose_errors(outcome.best.T_cam_base, T_true)[0] < before


def searched_below_the_found_test(monkeypatch, seq, robot, first, inputs, found_iou):
    """`coarse_start` whose masks are `inputs` and whose first winner is `first`, with the
    found test at `found_iou` (nothing carried sought, the focal length as given)."""
    calls = []

    def first_then_searched(*args, **kwargs):
        calls.append(args)
        return first if len(calls) == 1 else find_winner(*args, **kwargs)

    monkeypatch.setattr(calibration, "search_masks", lambda *args: inputs)
    monkeypatch.setattr(calibration, "find_winner", first_then_searched)
    guess = CameraGuess(first.best.T_cam_base, 0.05, 0.05, "the first winner")
    settings = replace(SMALL, min_found_iou=found_iou, min_found_iou_held_kept=1.0,
                       find_carried=False)
    return calibration.coarse_start(seq, robot, guess, settings,
                                     focal=FocalSettings(fit=False), timing=GRID)


def test_a_rest_stays_a_rest_and_unordered_stamps_are_not_read() -> None:
    """A repeated reading is the arm at rest: shifted by a millisecond it does not ramp
    towards the next one; stamps that repeat or go back leave the lag unread."""
    t = np.arange(5) / 30
    q = np.array([0.0, 0.0, 0.0, 0.1, 0.2])[:, None]
    assert abs(shifted_joints(q, t, 0.001)[1, 0]) < 1e-12
    assert np.allclose(shifted_joints(q, t, 0.0), q)
    assert np.allclose(shifted_joints(q, t, 0.001, np.array([1, 4])), q[[1, 4]])

    def stamped(*times) -> Sequence:
        return Sequence(robot="panda", camera=CAMERA, joint_names=("j",), keypoint_names=(),
                        frames=tuple(Frame(name=str(i), joints=np.zeros(1), timestamp=s)
                                     for i, s in enumerate(times)))

    for times in ((0.0, 0.1, 0.1), (0.1, 0.0), (0.0, None), (0.0,)):
        assert stamped(*times).increasing_timestamps is None, times
    assert np.array_equal(stamped(0.0, 0.1).increasing_timestamps, [0.0, 0.1])
    assert stamped(0.0, None).timestamps is None
    unordered = stamped(0.1, 0.0)
    assert with_lag(unordered, 0.0) is unordered
    with pytest.raises(InputError, match="timestamps"):
        with_lag(unordered, 0.05)
    with pytest.raises(InputError, match="shape"):
        unordered.with_joints(np.zeros((3, 1)))
    assert np.array_equal(unordered.with_joints([[1.0], [2.0]]).joints, [[1.0], [2.0]])


def test_a_lag_the_last_winner_does_not_fit_better_than_the_stamps_is_not_adopted() -> None:
    """The first winner asks for 50 ms, but once searched with it the stamps fit best (noise,
    a wrong pose): nothing is adopted."""
    searched = [0.0]

    def iou_at(lag: float) -> float:
        peak = 0.05 if len(searched) == 1 else 0.0
        return 0.8 - 60 * (lag - peak) ** 2

    estimate = read_lag(iou_at, searched.append, GRID, lambda line: None)
    assert len(searched) > 1 and not estimate.adopted and estimate.sigma_s == 0.0
    assert "none adopted" in estimate.reason and timing_finding(estimate.to_dict()) is None


def test_an_adopted_lag_shifts_the_readings_and_the_marks_clicked_points(panda) -> None:
    """After a search that adopted a lag, what follows sees the readings shifted by it, and
    the mark's clicked points (checked against the clicks at the pose found) are the mark at
    those readings, not at the readings as stamped; nothing changes where none was adopted."""
    t = np.arange(FRAMES) / FPS
    q = trajectory(panda)
    seq = Sequence(robot="panda", camera=CAMERA, joint_names=panda.joint_names,
                   keypoint_names=(), frames=tuple(
                       Frame(name=f"{i:06d}", joints=q[i], timestamp=float(t[i]))
                       for i in range(FRAMES)))
    mark = Mark("panda_link8", np.array([0.0, 0.0, 0.1]), np.array([3, 9, 14]),
                np.zeros((3, 2)))
    stamped = mark_points(panda, q[mark.frames], mark.link, mark.offset_link_m)
    marked = MarkStart(mark, CameraGuess(None, 0.3, 0.3, "a guess"), None, mark.frames, 3,
                       stamped, {})
    flat = np.zeros(3)
    for none in (None, LagEstimate(0.0, 0.5, 0.5, flat, flat, 0, "none")):
        assert lag_applied(seq, panda, none, marked) == (seq, marked)
    adopted = LagEstimate(LAG_S, 0.5, 0.6, flat, flat, 1, "read", sigma_s=0.01)
    shifted_seq, shifted_mark = lag_applied(seq, panda, adopted, marked)
    q_late = shifted_joints(q, t, LAG_S)
    assert np.allclose(shifted_seq.joints, q_late)
    assert np.allclose(shifted_mark.P_clicked_base,
                       mark_points(panda, q_late[mark.frames], mark.link, mark.offset_link_m))
    assert np.linalg.norm(shifted_mark.P_clicked_base - stamped, axis=1).min() > 1e-3
    assert lag_applied(seq, panda, adopted, None)[1] is None


def test_the_lags_scores_are_read_again_at_each_new_winner(monkeypatch) -> None:
    """`with_timing` scores each lag once per winner: after a search again the new winner's
    IoUs are computed afresh (a pose that took up 60 % of the lag peaks elsewhere than the
    first winner), so the lag read reaches the true one; scores kept from the first winner
    would stop it where the first read lay."""
    from types import SimpleNamespace

    from dream.coarse import search

    t = np.arange(FRAMES) / FPS
    middle = np.arange(5, 15)                     # shifted within the log by up to 0.16 s
    seq = Sequence(robot="panda", camera=CAMERA, joint_names=("j",), keypoint_names=(),
                   frames=tuple(Frame(name=str(i), joints=np.array([t[i]]),
                                      timestamp=float(t[i])) for i in range(FRAMES)))
    calls = []

    def pose_iou(meshes, joints, masks, camera, T_cam_base, settings, held):
        lag = float(np.mean(joints[:, 0] - t[middle]))      # the readings' shift
        searched_with = T_cam_base[0, 3]                    # the lag the pose was found with
        peak = 0.6 * searched_with + 0.4 * LAG_S
        calls.append(lag)
        return 0.8 - 60 * (lag - peak) ** 2

    def winner(lag: float):
        T = np.eye(4)
        T[0, 3] = lag
        return SimpleNamespace(best=SimpleNamespace(T_cam_base=T))

    def again(inputs: SearchMasks, last):
        return winner(float(np.mean(inputs.joints[:, 0] - t[middle])))

    monkeypatch.setattr(search, "pose_iou", pose_iou)
    inputs = SearchMasks(None, middle, t[middle, None], None, DATA_MASKS, (), middle)
    last, found = with_timing(seq, t[:, None], inputs, winner(0.0), SMALL, GRID, again, False)
    assert found.timing.adopted and abs(found.timing.seconds - LAG_S) < 2 * GRID.resolution_s
    assert last.best.T_cam_base[0, 3] == pytest.approx(found.timing.seconds)
    grid = len(lag_profile(lambda lag: 0.0, GRID)[0])
    assert len(calls) <= (found.timing.rounds + 1) * (grid + 2) + 1    # once per winner
