"""The readings check: a base joint's readings negated put the keypoint fit a metre off and it
was called `good`; readings paired with the wrong images were told to record more
configurations. The check names the mistake; right readings pass without a word."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dream.cli import main
from dream.errors import InputError
from dream.inject import InjectionSettings, make_injected_sequence
from dream.io import write_dream
from dream.pipeline import (
    calibrate,
    joints_in_robot_order,
    observations_from_labels,
    robot_for,
    truth_poses,
    with_robot_joints,
)
from dream.quality import GOOD, UNRELIABLE, result_quality
from dream.readings_check import (
    LAGS,
    ReadingsCheck,
    ReadingsCheckSettings,
    check_readings,
    reading_hypotheses,
    readings_finding,
)
from dream.transforms import invert_T


def _scene(motion: str = "trajectory", mistake=None, frames: int = 30):
    seq = make_injected_sequence(InjectionSettings(num_frames=frames, seed=3, motion=motion))
    robot = robot_for(seq, None)
    joints = joints_in_robot_order(seq, robot)
    if mistake is not None:
        joints = mistake(joints.copy())
        seq = with_robot_joints(seq, robot, joints)       # the labels stay those of the truth
    return seq, robot, joints


def _negate_base(joints):
    joints[:, 0] *= -1
    return joints


def _check(seq, robot, joints):
    obs = observations_from_labels(seq, robot)
    result = calibrate(seq, obs, "all")
    return result, obs, check_readings(result, obs, robot, joints, seq.camera)


def test_right_readings_are_not_questioned():
    result, obs, check = _check(*_scene())
    assert check.explained == check.detections and check.tried == ()
    assert readings_finding(check) is None


def test_a_negated_base_joint_is_named_where_the_fit_was_called_good():
    seq, robot, joints = _scene(mistake=_negate_base, frames=20)
    result, obs, check = _check(seq, robot, joints)
    assert check.explained > 0.85 * check.detections    # the fit leaves only a few out
    off_m = np.linalg.norm(invert_T(result.T_cam_base)[:3, 3]
                           - invert_T(truth_poses(seq)[0])[:3, 3])
    assert off_m > 0.5 and result_quality(result, obs).verdict == GOOD   # what it was
    assert check.best.what == "joint 'panda_joint1' negated" and check.resolved > 0.9
    level, text = readings_finding(check)
    assert level == UNRELIABLE and "panda_joint1' negated" in text and "negate its" in text


def test_readings_of_the_previous_frame_are_named():
    seq, robot, joints = _scene("random", lambda q: np.roll(q, 1, axis=0))
    result, obs, check = _check(seq, robot, joints)
    assert check.best.what == LAGS[-1][0]
    level, text = readings_finding(check)
    assert level == UNRELIABLE and "one frame late" in text and "reading after it" in text
    assert "carries the previous frame's readings" in text
    reasons = result_quality(result, obs, leading=[(level, text)]).warnings
    assert reasons[0] == text and len(reasons) > 1     # before the advice it may cause


def test_readings_of_the_next_frame_are_named():
    seq, robot, joints = _scene("random", lambda q: np.roll(q, -1, axis=0))
    _, _, check = _check(seq, robot, joints)
    assert check.best.what == LAGS[1][0] and "next frame's readings" in check.best.what
    assert "reading before it" in readings_finding(check)[1]


def test_the_hypotheses_are_compared_on_at_most_max_frames():
    seq, robot, joints = _scene(mistake=_negate_base, frames=20)
    obs = observations_from_labels(seq, robot)
    result = calibrate(seq, obs, "all")
    check = check_readings(result, obs, robot, joints, seq.camera,
                           ReadingsCheckSettings(max_frames=10))
    assert check.best.what == "joint 'panda_joint1' negated"
    assert check.best_detections == obs.found[::2].sum() < check.detections
    assert readings_finding(check)[0] == UNRELIABLE
    with pytest.raises(InputError):
        ReadingsCheckSettings(max_frames=2)


def test_hypotheses_leave_out_what_changes_nothing():
    joints = np.array([[0.5, 0.5, 0.0], [0.7, 0.7, 0.01]])
    names = [m.what for m in reading_hypotheses(joints, ("a", "b", "c"))]
    assert names == ["joint 'a' negated", "joint 'b' negated", "joints 'b' and 'c' swapped"]
    early = reading_hypotheses(np.arange(8.0).reshape(4, 2), ("a", "b"))[-2]
    assert early.what == LAGS[1][0]
    assert early.frames.tolist() == [False, True, True, True]
    assert early.joints[1:].tolist() == np.arange(6.0).reshape(3, 2).tolist()
    with pytest.raises(InputError, match="joint names"):
        reading_hypotheses(joints, ("a", "b"))


def test_readings_must_be_those_of_the_observations():
    seq, robot, joints = _scene()
    obs = observations_from_labels(seq, robot)
    with pytest.raises(InputError, match="not those"):
        check_readings(calibrate(seq, obs, "all"), obs, robot, -joints, seq.camera)


def test_a_small_gain_is_no_finding():
    mistake = reading_hypotheses(np.array([[0.5, 1.0]] * 3), ("a", "b"))[0]
    assert readings_finding(ReadingsCheck(100, 70, ("x",), mistake, 100, 80, 70, 10.0)) is None
    assert readings_finding(ReadingsCheck(100, 70, ("x",), mistake, 100, 73, 70, 10.0)) is None
    assert readings_finding(ReadingsCheck(100, 90, ("x",), mistake, 100, 96, 90, 10.0))[0] \
        == UNRELIABLE
    assert readings_finding(ReadingsCheck(100, 100, ())) is None


def test_calibrate_names_the_mistake(tmp_path, capsys):
    for name, mistake in (("right", None), ("negated", _negate_base)):
        seq, _, _ = _scene(mistake=mistake)
        write_dream(seq, tmp_path / name)
        out = tmp_path / f"{name}.json"
        assert main(["calibrate", "--data", str(tmp_path / name), "--use-labels", "--refine",
                     "none", "--out", str(out)]) == 0
        printed = capsys.readouterr().out
        doc = json.loads(out.read_text())
        assert doc["readings_check"]["agrees"] == (mistake is None)
        if mistake is None:
            assert "readings check" not in printed
            assert doc["readings_check"]["tried"] == []
        else:
            assert doc["quality"]["verdict"] == UNRELIABLE
            assert doc["readings_check"]["best"] == "joint 'panda_joint1' negated"
            assert "readings check: " in printed and "panda_joint1' negated" in printed
            assert doc["quality"]["warnings"][0].startswith("the joint readings look wrong")


def test_the_benchmark_names_each_mistake_as_the_check_names_its_fix():
    from tests.benchmark_scripts import load_benchmark

    joints = np.array([[0.3, -1.0, 0.2], [0.5, -1.2, 0.4], [0.4, -1.1, 0.9]])
    names = ("a", "b", "c")
    fixes = {fix for _, fix, _ in load_benchmark("readings_check").mistakes(joints, names)}
    assert fixes == {m.what for m in reading_hypotheses(joints, names)}


def test_what_counts_as_explained_scales_with_the_image_width():
    """A network's keypoints err in proportion to the image: 10 px at 320 wide, 20 at 640."""
    import dataclasses

    seq, robot, joints = _scene(mistake=_negate_base, frames=20)
    obs = observations_from_labels(seq, robot)
    result = calibrate(seq, obs, "all")
    narrow = check_readings(result, obs, robot, joints, seq.camera)
    wide_camera = dataclasses.replace(seq.camera, width=2 * seq.camera.width)
    wide = check_readings(result, obs, robot, joints, wide_camera)
    assert narrow.explained_px == pytest.approx(seq.camera.width / 32)
    assert wide.explained_px == pytest.approx(2 * narrow.explained_px)
    assert wide.explained >= narrow.explained
    assert f"{narrow.explained_px:.3g} px of the fit" in readings_finding(narrow)[1]
    assert narrow.to_dict()["explained_within_px"] == narrow.explained_px
