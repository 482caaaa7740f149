"""Plausible-looking mistakes are refused before solving: joints in degrees or beyond their
limits, intrinsics that cannot belong to the images, distortion off by orders of magnitude,
`--intrinsics` that silently replace the data's own."""

from __future__ import annotations

import doctest
import json
import logging
from pathlib import Path

import numpy as np
import pytest

import dream.plausibility
from dream.camera import CameraIntrinsics
from dream.cli import BUNDLED_MODEL, main
from dream.errors import InputError
from dream.plausibility import check_camera, check_joint_readings
from dream.robot import load_robot


def refused(argv: list, capsys) -> str:
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    return err.strip()


@pytest.fixture(scope="module")
def labels(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("plausible") / "data"
    assert main(["sample", "--out", str(out), "--num", "6", "--seed", "5"]) == 0
    return out


def edited(labels: Path, dest: Path, frame_edit=None, camera_edit=None) -> Path:
    dest.mkdir()
    for f in labels.iterdir():
        text = f.read_text()
        if f.name.startswith("0") and frame_edit is not None:
            doc = json.loads(text)
            frame_edit(doc)
            text = json.dumps(doc)
        if f.name == "_camera_settings.json" and camera_edit is not None:
            doc = json.loads(text)
            camera_edit(doc["camera_settings"][0]["intrinsic_settings"])
            text = json.dumps(doc)
        (dest / f.name).write_text(text)
    return dest


def _in_degrees(doc: dict) -> None:
    for joint in doc["sim_state"]["joints"]:
        joint["position"] = float(np.rad2deg(joint["position"]))


def test_joints_in_degrees_are_refused_naming_the_joint(labels, tmp_path, capsys):
    data = edited(labels, tmp_path / "deg", _in_degrees)
    line = refused(["calibrate", "--data", data, "--use-labels", "--out", tmp_path / "r.json"],
                   capsys)
    assert "are these degrees?" in line and "panda_joint" in line and "URDF limits" in line
    assert "radians" in line and not (tmp_path / "r.json").exists()
    line = refused(["diagnose", "--data", data, "--use-labels", "--out", tmp_path / "d"],
                   capsys)
    assert "are these degrees?" in line and not (tmp_path / "d").exists()


def test_a_joint_far_beyond_its_limit_is_refused(labels, tmp_path, capsys):
    def joint4_positive(doc):
        for joint in doc["sim_state"]["joints"]:
            if joint["name"] == "panda_joint4":
                joint["position"] = 1.5

    data = edited(labels, tmp_path / "j4", joint4_positive)
    line = refused(["calibrate", "--data", data, "--use-labels", "--out", tmp_path / "r.json"],
                   capsys)
    assert "panda_joint4 = 1.5" in line and "-0.070" in line


def test_limits_margin_continuous_and_prismatic_joints():
    lower, upper = np.array([-1.0, -np.inf, 0.0]), np.array([1.0, np.inf, 0.04])
    prismatic = np.array([False, False, True])
    names, frames = ("a", "b", "finger"), ("000000", "000001")
    ok = np.array([[1.09, 100.0, 0.045], [-1.09, -50.0, -0.009]])
    check_joint_readings(ok, names, lower, upper, prismatic, frames)  # within the margins
    with pytest.raises(InputError, match="are these millimetres"):
        check_joint_readings(np.array([[0.0, 0.0, 40.0]]), names, lower, upper, prismatic,
                             frames)
    with pytest.raises(InputError, match=r"frame 000001: joint a = 1\.2.*1 of 2 frames"):
        check_joint_readings(np.array([[0.0, 0, 0], [1.2, 0, 0]]), names, lower, upper,
                             prismatic, frames)


def test_readings_no_unit_explains_are_asked_about_the_column_order():
    """A swapped column (Panda joint4 only bends one way) is not "degrees": no unit puts the
    readings inside the limits; a reading that could be either is asked about both."""
    lower, upper = np.array([-2.9, -3.07]), np.array([2.9, -0.07])
    names, frames, revolute = ("j1", "j4"), ("000000", "000001"), np.array([False, False])
    swapped = np.array([[-2.2, 0.4], [-2.0, 2.5]])     # j1's column and j4's exchanged
    with pytest.raises(InputError) as info:
        check_joint_readings(swapped, names, lower, upper, revolute, frames)
    assert "not in degrees either: is it another joint's column" in str(info.value)
    assert "radians" not in str(info.value) and "joint order (j1, j4)" in str(info.value)
    small = np.array([[0.0, -2.0], [0.0, 0.5]])        # 0.5: radians of another joint, or degrees
    with pytest.raises(InputError) as info:
        check_joint_readings(small, names, lower, upper, revolute, frames)
    assert "are these degrees (0.5 deg = 0.009 rad), or another joint's column" in str(info.value)
    degrees = np.array([[0.0, -120.0], [10.0, -30.0]])
    with pytest.raises(InputError) as info:
        check_joint_readings(degrees, names, lower, upper, revolute, frames)
    assert "are these degrees? (-120 deg = -2.094 rad)" in str(info.value)


def test_clean_inputs_pass(labels, tmp_path):
    robot = load_robot("panda")
    q = np.stack([robot.joint_lower, robot.joint_upper, robot.rest_joints])
    check_joint_readings(q, robot.joint_names, robot.joint_lower, robot.joint_upper,
                         np.zeros(robot.num_joints, bool), ("0", "1", "2"))
    for camera in (CameraIntrinsics(151.1, 151.1, 160.1, 120.7, 320, 240),
                   CameraIntrinsics(615.0, 615.0, 319.5, 239.5, 640, 480,
                                    (0.1, -0.25, 0.001, 0.001, 0.1)),
                   CameraIntrinsics(1400.0, 1400.0, 960.0, 540.0, 1920, 1080)):
        check_camera(camera)
    assert main(["calibrate", "--data", str(labels), "--use-labels", "--out",
                 str(tmp_path / "r.json")]) == 0


@pytest.mark.parametrize("camera, words", [
    (CameraIntrinsics(600.0, 600.0, 3313.0, 240.0, 640, 480), "cx = 3313 px lies outside"),
    (CameraIntrinsics(600.0, 600.0, 320.0, -80.0, 640, 480), "cy = -80 px lies outside"),
    (CameraIntrinsics(600.0, 600.0, 0.5, 0.5, 640, 480), "cx = 0.5 px lies far from the "
     "centre.*normalised"),
    (CameraIntrinsics(300.0, 300.0, 319.5, 120.0, 320, 240), "another resolution"),
    (CameraIntrinsics(300.0, 300.0, 119.5, 159.5, 320, 240), "are cx and cy .* swapped"),
    (CameraIntrinsics(4.0, 4.0, 319.5, 239.5, 640, 480), "millimetres"),
    (CameraIntrinsics(40000.0, 40000.0, 319.5, 239.5, 640, 480), "larger image"),
    (CameraIntrinsics(600.0, 200.0, 319.5, 239.5, 640, 480), "differ by a factor 3.00"),
    (CameraIntrinsics(600.0, 600.0, 319.5, 239.5, 640, 480, (50.0, 0, 0, 0, 0)),
     "scales radii by"),
    (CameraIntrinsics(600.0, 600.0, 319.5, 239.5, 640, 480, (-3.0, 0, 0, 0, 0)), "folds"),
])
def test_implausible_cameras_are_refused(camera, words):
    with pytest.raises(InputError, match=words):
        check_camera(camera)


def test_implausible_data_camera_is_refused_on_reading(labels, tmp_path, capsys):
    data = edited(labels, tmp_path / "cx", camera_edit=lambda k: k.update(cx=3313.0))
    line = refused(["info", data], capsys)
    assert "cx = 3313" in line and str(data) in line
    data = edited(labels, tmp_path / "mm", camera_edit=lambda k: k.update(fx=3.6, fy=3.6))
    line = refused(["calibrate", "--data", data, "--use-labels", "--out", tmp_path / "r.json"],
                   capsys)
    assert "millimetres" in line


def test_intrinsics_that_differ_from_the_datas_own_need_the_override(labels, tmp_path, capsys):
    settings = json.loads((labels / "_camera_settings.json").read_text())
    k = settings["camera_settings"][0]["intrinsic_settings"]
    mine = f"{k['fx'] * 1.3},{k['fy'] * 1.3},{k['cx']},{k['cy']}"
    out = tmp_path / "r.json"
    line = refused(["calibrate", "--data", labels, "--use-labels", "--intrinsics", mine,
                    "--out", out], capsys)
    assert "differs from the data's own" in line and "--override-intrinsics" in line
    assert not out.exists()
    same = f"{k['fx']},{k['fy']},{k['cx']},{k['cy']}"
    assert main(["calibrate", "--data", str(labels), "--use-labels", "--intrinsics", same,
                 "--out", str(out)]) == 0
    assert main(["calibrate", "--data", str(labels), "--use-labels", "--intrinsics", mine,
                 "--override-intrinsics", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["data"]["camera"]["fx"] == pytest.approx(k["fx"] * 1.3)
    assert doc["settings"]["override_intrinsics"] and doc["settings"]["intrinsics"] == mine


def test_empty_data_path_is_refused(tmp_path, capsys):
    line = refused(["calibrate", "--data", "", "--use-labels", "--out", tmp_path / "r.json"],
                   capsys)
    assert "--data is empty" in line


def test_docstring_example():
    assert doctest.testmod(dream.plausibility, optionflags=doctest.ELLIPSIS).failed == 0


def test_eval_refuses_a_result_of_other_data(labels, tmp_path, capsys):
    result, metrics = tmp_path / "r.json", tmp_path / "m.json"
    assert main(["calibrate", "--data", str(labels), "--use-labels", "--out", str(result)]) == 0
    doc = json.loads(result.read_text())
    assert doc["data"]["path"] == str(labels.resolve()) and doc["data"]["num_frames"] == 6
    assert len(doc["data"]["content_sha256"]) == 64 and doc["settings"]["frames"] == "all"
    assert main(["eval", "--data", str(labels), "--result", str(result), "--out",
                 str(metrics)]) == 0
    line = refused(["eval", "--data", labels, "--result", result, "--out", result], capsys)
    assert "is the --result it scores" in line and json.loads(result.read_text()) == doc
    other = tmp_path / "other"
    assert main(["sample", "--out", str(other), "--num", "6", "--seed", "6"]) == 0
    line = refused(["eval", "--data", other, "--result", result, "--out", tmp_path / "m2.json"],
                   capsys)
    assert "other data" in line and str(labels.resolve()) in line
    assert not (tmp_path / "m2.json").exists()
    # a result written before the record existed is still scored
    del doc["data"]
    result.write_text(json.dumps(doc))
    assert main(["eval", "--data", str(other), "--result", str(result), "--out",
                 str(metrics)]) == 0


def test_diagnose_of_too_few_frames_says_so(tmp_path, capsys):
    one = tmp_path / "one"
    assert main(["sample", "--out", str(one), "--num", "1"]) == 0
    line = refused(["diagnose", "--data", one, "--use-labels", "--out", tmp_path / "d"], capsys)
    assert "too few to diagnose" in line and "more than 5 frames" in line
    assert not (tmp_path / "d").exists()


def test_franka_offline_in_degrees_names_the_unit_not_collinear_keypoints(realdata, tmp_path,
                                                                          capsys):
    source = realdata / "franka_offline"
    data = tmp_path / "deg"
    data.mkdir()
    for entry in source.iterdir():
        if entry.name != "qpos":
            (data / entry.name).symlink_to(entry)
    (data / "qpos").mkdir()
    for path in (source / "qpos").iterdir():
        values = np.loadtxt(path)
        np.savetxt(data / "qpos" / path.name, np.rad2deg(values))
    line = refused(["calibrate", "--data", data, "--model", BUNDLED_MODEL, "--out",
                    tmp_path / "r.json"], capsys)
    assert "are these degrees?" in line and "collinear" not in line


def test_timestamps_that_cannot_be_seconds_are_refused_in_any_layout(labels, tmp_path, capsys):
    """A DREAM folder whose frames were stamped in nanoseconds: one line, before any work."""
    def in_nanoseconds(doc: dict) -> None:
        doc["timestamp"] = doc["timestamp"] * 1e9

    data = edited(labels, tmp_path / "ns", frame_edit=in_nanoseconds)
    line = refused(["calibrate", "--data", data, "--use-labels", "--out", tmp_path / "r.json"],
                   capsys)
    assert "they are not seconds" in line and "divided by 1e9" in line
    assert not (tmp_path / "r.json").exists()



def test_a_steady_frame_interval_in_milliseconds_is_warned_of(caplog) -> None:
    """Stamps of a 30 frames/s video in milliseconds from 0 can be seconds (a frame every
    33 s): warned of, not refused; irregular stamps of a sparse capture and seconds pass
    quietly."""
    from dream.plausibility import check_seconds

    with caplog.at_level(logging.WARNING, logger="dream.plausibility"):
        check_seconds(np.arange(30) * 1000 / 30, Path("joints.csv"))
    assert "milliseconds" in caplog.text and "joints.csv" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="dream.plausibility"):
        check_seconds(np.arange(30) / 30, Path("joints.csv"))
        check_seconds(np.cumsum(np.random.default_rng(0).uniform(5, 60, 30)), None)
    assert not caplog.text
