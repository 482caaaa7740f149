"""Joint logs that update slower than the images: found, interpolated in time, and the
calibration better for it."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from dream.cli import main
from dream.errors import InputError
from dream.inject import InjectionSettings, make_injected_sequence
from dream.io import write_dream
from dream.metrics import pose_errors
from dream.readings import (
    HeldReadingsSettings,
    after_last_update,
    clock_phase_range,
    held_log,
    interpolated_joints,
    reading_updates,
    stamp_jitter,
    update_times,
    with_interpolated_readings,
    without_frames_after_last_update,
)

FRAME_PERIOD_S = 1.0 / 30.0
HOLD_FRAMES = 6  # a 5 Hz joint log beside a 30 Hz camera


def test_a_held_log_is_found_and_a_streaming_one_is_not():
    t = np.arange(60) * FRAME_PERIOD_S
    q = np.sin(t)[:, None] * [1.0, 0.5]
    streaming = reading_updates(t, q)
    assert not streaming.held and streaming.repeat_fraction == 0.0
    held = reading_updates(t, q[(np.arange(60) // HOLD_FRAMES) * HOLD_FRAMES])
    assert held.held and len(held.update_index) == 10
    assert held.period_s == pytest.approx(HOLD_FRAMES * FRAME_PERIOD_S)
    assert held.repeat_fraction == pytest.approx(50 / 59)
    static = reading_updates(t, np.ones((60, 2)))  # an arm at rest: its readings are the truth
    assert not static.held
    parked = q.copy()
    parked[:40] = q[0]        # at rest for 40 frames, then streaming: the repeats are the truth
    rested = reading_updates(t, parked)
    assert rested.repeat_fraction == pytest.approx(39 / 59) and len(rested.update_index) == 21
    assert not rested.held
    parked[40:] = q[40 + (np.arange(20) // HOLD_FRAMES) * HOLD_FRAMES]
    assert reading_updates(t, parked).held     # at rest, then a 5 Hz log: held


def test_linear_motion_sampled_between_frames_is_recovered_exactly():
    t = np.arange(30) * FRAME_PERIOD_S
    speed = np.array([0.8, -0.3])
    starts = np.arange(0, 30, HOLD_FRAMES)
    t_sample = t[starts] - FRAME_PERIOD_S / 2   # a regular log: frame 0's reading too
    q_logged = (t_sample[:, None] * speed)[np.arange(30) // HOLD_FRAMES]
    q = interpolated_joints(t, q_logged, reading_updates(t, q_logged))
    before_last = t <= t_sample[-1]
    np.testing.assert_allclose(q[before_last], (t[:, None] * speed)[before_last], atol=1e-12)
    np.testing.assert_array_equal(q[~before_last], q_logged[~before_last])  # the last is held
    late = after_last_update(t, reading_updates(t, q_logged))
    np.testing.assert_array_equal(late, ~before_last)   # exactly the frames it cannot know
    assert late.sum() == HOLD_FRAMES


def test_nothing_is_late_in_a_log_that_is_not_held():
    t = np.arange(30) * FRAME_PERIOD_S
    q = np.sin(t)[:, None]
    assert not after_last_update(t, reading_updates(t, q)).any()
    seq = make_injected_sequence(InjectionSettings(num_frames=12, frame_period_s=FRAME_PERIOD_S,
                                                   seed=1))
    assert without_frames_after_last_update(seq, None) == (seq, ())


def test_a_frame_subset_keeps_the_chosen_frames_in_order():
    seq = make_injected_sequence(InjectionSettings(num_frames=6, frame_period_s=FRAME_PERIOD_S,
                                                   seed=1))
    keep = np.array([True, False, True, True, False, False])
    part = seq.subset(keep)
    assert [f.name for f in part.frames] == [seq.frames[i].name for i in (0, 2, 3)]
    assert part.camera == seq.camera and part.keypoint_names == seq.keypoint_names
    with pytest.raises(InputError, match=r"must be \(6,\) bool"):
        seq.subset(np.ones(5, bool))
    with pytest.raises(InputError, match="bool"):
        seq.subset(np.array([1, 0, 1, 1, 0, 0]))


def _clock_log(period_s: float, phase_s: float, frames: int, skip: int, seed: int):
    """Frame times, the frames where a log sampled every `period_s` shows a new reading (`skip`
    updates left out: the arm stood still) and the true sample times of those updates."""
    t = np.arange(frames) * FRAME_PERIOD_S
    sampled = phase_s + np.arange(0.0, t[-1], period_s)
    sampled = sampled[sampled <= t[-1]]
    index, first = np.unique(np.searchsorted(t, sampled), return_index=True)
    keep = np.ones(len(index), bool)
    keep[np.random.default_rng(seed).choice(np.arange(2, len(index)), skip, replace=False)] = False
    return t, index[keep], sampled[first][keep]


@pytest.mark.parametrize("period_s,phase_s", [(0.17, 0.013), (0.23, 0.004), (0.11, 0.03)])
def test_a_regular_log_clock_places_its_updates_within_a_fraction_of_a_frame(period_s, phase_s):
    t, index, sampled = _clock_log(period_s, phase_s, 450, skip=5, seed=1)
    found = update_times(t, index)
    later = index > 0
    midpoint = 0.5 * (t[index - 1] + t[index])[later]
    assert np.all((found[later] > t[index - 1][later]) & (found[later] <= t[index][later]))
    error = np.sqrt(np.mean((found[later] - sampled[later]) ** 2))
    assert error < 0.25 * np.sqrt(np.mean((midpoint - sampled[later]) ** 2)), error
    assert error < 0.1 * FRAME_PERIOD_S
    np.testing.assert_allclose(update_times(t, index, use_clock=False)[later], midpoint)


def test_a_long_pause_in_a_regular_log_keeps_its_clock():
    """A 7 Hz log whose arm stands still for 1.3 s (9 updates change nothing): counted with the
    first, frame-rounded period the pause would break the clock."""
    t, index, sampled = _clock_log(1 / 7, 0.01, 450, skip=0, seed=1)
    pause = np.arange(20, 29)
    index, sampled = np.delete(index, pause), np.delete(sampled, pause)
    later = index > 0
    error = np.sqrt(np.mean((update_times(t, index)[later] - sampled[later]) ** 2))
    assert error < 0.1 * FRAME_PERIOD_S, error


def test_clock_placed_updates_stay_in_their_intervals_and_in_order():
    rng = np.random.default_rng(3)
    for _ in range(300):
        t, index, _ = _clock_log(rng.uniform(0.05, 0.35), rng.uniform(0.0, 0.05),
                                 int(rng.integers(60, 200)), skip=0, seed=0)
        found = update_times(t, index)
        later = index > 0
        assert np.all(np.diff(found) > 0)
        assert np.all((found[later] > t[index - 1][later]) & (found[later] <= t[index][later]))
        q = np.sin(t)[:, None][np.searchsorted(index, np.arange(len(t)), side="right") - 1]
        interpolated_joints(t, q, reading_updates(t, q))   # strictly increasing knots


def test_the_phase_range_of_jittered_stamps_still_holds_the_true_placement():
    """Frame stamps that scatter by 1 ms about the instants the frames were taken: the range
    of the mean placement over the clocks through every stamped interval misses the truth in
    many logs; widened by the stamps' own scatter (`tail_probability`) it holds it in all."""
    rng = np.random.default_rng(3)
    missed = {None: 0, 1e-3: 0}   # by tail_probability (None: not widened)
    for _ in range(40):
        t, index, sampled = _clock_log(rng.uniform(0.1, 0.3), rng.uniform(0.0, 0.05), 150,
                                       skip=0, seed=0)
        stamps = t + rng.normal(0.0, 0.001, len(t))
        later = index > 0
        placed = np.mean(update_times(stamps, index)[later] - sampled[later])
        for tail in missed:
            lo, hi = clock_phase_range(stamps, index, tail) or (-np.inf, np.inf)
            missed[tail] += not lo - 1e-9 <= placed <= hi + 1e-9
    assert stamp_jitter(stamps) == pytest.approx(0.001, rel=0.3)
    assert missed[None] >= 5 and missed[1e-3] == 0, missed


def test_a_log_without_a_regular_clock_keeps_the_midpoints():
    t, index, _ = _clock_log(0.17, 0.013, 450, skip=5, seed=1)
    rng = np.random.default_rng(2)
    jittered = np.unique(np.clip(index + rng.integers(-2, 3, len(index)), 1, len(t) - 1))
    np.testing.assert_allclose(update_times(t, jittered),
                               0.5 * (t[jittered - 1] + t[jittered]))
    few = index[:3]   # too few updates to fit a clock
    np.testing.assert_allclose(update_times(t, few)[few > 0],
                               0.5 * (t[few - 1] + t[few])[few > 0])


def test_sequences_without_timestamps_or_in_disorder_are_left_alone():
    seq = make_injected_sequence(InjectionSettings(num_frames=12, motion="random", seed=1))
    unstamped = dataclasses.replace(seq, frames=tuple(dataclasses.replace(f, timestamp=None)
                                                      for f in seq.frames))
    assert with_interpolated_readings(unstamped) == (unstamped, None)
    reversed_times = dataclasses.replace(seq, frames=tuple(
        dataclasses.replace(f, timestamp=-f.timestamp) for f in seq.frames))
    assert with_interpolated_readings(reversed_times)[1] is None


def test_a_simulated_held_log_holds_each_reading_for_its_frames():
    seq = make_injected_sequence(InjectionSettings(num_frames=20, frame_period_s=FRAME_PERIOD_S,
                                                   seed=2))
    held = held_log(seq, HOLD_FRAMES, np.random.default_rng(0))
    updates = reading_updates(np.array([f.timestamp for f in held.frames]), held.joints)
    assert updates.update_index.tolist() == [0, 6, 12, 18]
    np.testing.assert_array_equal(held.joints[0], seq.joints[0])  # the first is the first frame's


def test_bad_arguments_are_input_errors():
    with pytest.raises(InputError, match="strictly increasing frame indices"):
        update_times(np.arange(5.0), np.array([0, 3, 2]))
    with pytest.raises(InputError, match="timestamps must be finite and in increasing order"):
        update_times(np.array([0.0, np.nan, 1.0]), np.array([0, 1]))
    with pytest.raises(InputError, match="min_repeat_fraction"):
        HeldReadingsSettings(min_repeat_fraction=1.5)
    with pytest.raises(InputError, match="min_update_spacing"):
        HeldReadingsSettings(min_update_spacing=1)
    with pytest.raises(InputError, match="increasing"):
        reading_updates(np.array([0.0, 2.0, 1.0]), np.zeros((3, 2)))
    with pytest.raises(InputError, match="expected"):
        reading_updates(np.zeros(3), np.zeros((4, 2)))


def test_calibrating_a_held_log_interpolates_it_and_says_so(tmp_path, capsys):
    """120 frames at 30 Hz, a 5 Hz log, labels with 1 px noise (seeds 0-3: the logged readings
    give 10-48 mm, interpolated 1.6-4.3 mm, the true joints 0.4-1.2 mm); seed 3: 18 -> 1.6 mm."""
    seq = make_injected_sequence(InjectionSettings(num_frames=120, frame_period_s=FRAME_PERIOD_S,
                                                   pixel_noise_px=1.0, seed=3))
    write_dream(held_log(seq, HOLD_FRAMES, np.random.default_rng(3)), tmp_path / "data")
    errors = {}
    for mode in ("as-logged", "interpolate"):
        out = tmp_path / f"{mode}.json"
        assert main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels",
                     "--joint-readings", mode, "--out", str(out)]) == 0
        doc = json.loads(out.read_text())
        expected = {"held": True, "interpolated": mode == "interpolate", "updates": 20,
                    "repeat_fraction": pytest.approx(100 / 119),
                    "update_period_s": pytest.approx(0.2)}
        if mode == "interpolate":   # the last update shows at frame 114: 114-119 are stale
            expected["frames_left_out"] = [f"{i:06d}" for i in range(114, 120)]
            assert len(doc["per_frame"]) == 114
        assert doc["joint_readings"] == expected
        t_err, _ = pose_errors(np.array(doc["T_cam_base"])[None],
                               seq.frames[0].T_cam_base_true[None])
        errors[mode] = t_err[0]
    printed = capsys.readouterr().out
    assert "joint readings: 20 updates in 120 frames, one every 0.200 s" in printed
    assert "interpolated in time" in printed and "kept as logged" in printed
    assert "6 frames after the log's last update left out" in printed
    assert errors["interpolate"] < 0.3 * errors["as-logged"]
    assert errors["interpolate"] < 0.005
    metrics = tmp_path / "metrics.json"
    assert main(["eval", "--data", str(tmp_path / "data"), "--result",
                 str(tmp_path / "interpolate.json"), "--out", str(metrics)]) == 0
    assert json.loads(metrics.read_text())["translation_error_m"]["median"] == pytest.approx(
        errors["interpolate"], abs=1e-9)


def test_a_recording_without_a_held_log_reports_it_unchanged(tmp_path):
    seq = make_injected_sequence(InjectionSettings(num_frames=40, frame_period_s=FRAME_PERIOD_S,
                                                   pixel_noise_px=1.0, seed=5))
    write_dream(seq, tmp_path / "data")
    out = tmp_path / "r.json"
    assert main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels",
                 "--out", str(out)]) == 0
    readings = json.loads(out.read_text())["joint_readings"]
    assert readings["held"] is False and readings["interpolated"] is False
