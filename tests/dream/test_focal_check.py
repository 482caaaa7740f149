"""The keypoint path's focal-length check: a focal length 10 % off moved the camera 96 mm and
was called `good`; the right one passes without a word."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dream.cli import main
from dream.coarse.focal import with_focal_scale
from dream.focal_check import fit_focal_scale, keypoint_focal, keypoint_focal_finding
from dream.inject import InjectionSettings, make_injected_sequence
from dream.io import write_dream
from dream.pipeline import calibrate, observations_from_labels, robot_for


def _scene(scale: float):
    seq = make_injected_sequence(InjectionSettings(num_frames=40, seed=11))
    return seq.with_fixed_camera(with_focal_scale(seq.camera, scale))


@pytest.mark.parametrize("scale", [1.0, 1.1, 0.9])
def test_the_keypoints_ask_for_the_focal_length_they_were_seen_with(scale):
    seq = _scene(scale)
    robot = robot_for(seq, None)
    obs = observations_from_labels(seq, robot)
    result = calibrate(seq, obs, "all")
    focal = keypoint_focal(result, obs, seq.camera)
    assert focal.scale == pytest.approx(1 / scale, rel=0.02)
    assert focal.sigma_jackknife is not None and focal.sigma >= focal.sigma_fit
    finding = keypoint_focal_finding(focal, seq.camera)
    assert (finding is None) == (scale == 1.0)


def test_the_joint_fit_needs_points_in_front():
    P = np.array([[0.0, 0.0, -1.0]] * 10)
    scale, sigma, _ = fit_focal_scale(P, np.zeros((10, 2)), _scene(1.0).camera, np.eye(4))
    assert np.isnan(scale) and sigma == np.inf


def test_calibrate_says_the_focal_length_is_off(tmp_path, capsys):
    for name, scale in (("right", 1.0), ("wrong", 1.1)):
        write_dream(_scene(scale), tmp_path / name)
        out = tmp_path / f"{name}.json"
        assert main(["calibrate", "--data", str(tmp_path / name), "--use-labels", "--refine",
                     "none", "--out", str(out)]) == 0
        printed = capsys.readouterr().out
        doc = json.loads(out.read_text())
        assert doc["keypoint_focal"]["agrees"] == (scale == 1.0)
        if scale == 1.0:
            assert "focal length" not in printed
        else:
            assert doc["quality"]["verdict"] == "check"
            assert "keypoints fit best with a focal length x0.9" in printed


def test_require_makes_a_verdict_below_it_a_failed_exit_with_the_result_written(tmp_path,
                                                                                 capsys):
    """A script asks for `good`: the scene with fx, fy 10 % off (verdict `check`) exits 3 and
    says why on stderr, its RESULT.json written all the same; `--require check` lets it
    pass, and the right scene passes `--require good`."""
    for name, scale in (("right", 1.0), ("wrong", 1.1)):
        write_dream(_scene(scale), tmp_path / name)
    runs = (("right", "good", 0), ("wrong", "good", 3), ("wrong", "check", 0))
    for name, required, expected in runs:
        out = tmp_path / f"{name}_{required}.json"
        code = main(["calibrate", "--data", str(tmp_path / name), "--use-labels", "--refine",
                     "none", "--out", str(out), "--require", required])
        err = capsys.readouterr().err
        assert code == expected, err
        assert json.loads(out.read_text())["quality"]["verdict"] == ("good" if name == "right"
                                                                     else "check")
        assert ("the verdict is check, below --require good" in err) == (expected == 3)
    with pytest.raises(SystemExit):                 # unreliable is nothing to require
        main(["calibrate", "--data", str(tmp_path / "right"), "--use-labels", "--out",
              str(tmp_path / "x.json"), "--require", "unreliable"])
    assert "invalid choice" in capsys.readouterr().err
