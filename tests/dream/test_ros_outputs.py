"""What a user pastes into their robot stack: the URDF joint, the ROS 2 launch file and the
easy_handeye YAML agree with RESULT.json's extrinsic, under the frame names asked for."""

from __future__ import annotations

import ast
import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from dream.cli import main
from dream.errors import InputError
from dream.ros import handeye_text, launch_text, rpy_from_R, urdf_text
from dream.transforms import R_from_rotvec, T_from_quaternion_xyzw_t, invert_T, look_at


def _R_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    return R_from_rotvec([0, 0, yaw]) @ R_from_rotvec([0, pitch, 0]) @ R_from_rotvec([roll, 0, 0])


def test_rpy_rebuilds_the_rotation(rng):
    for _ in range(50):
        R = R_from_rotvec(rng.normal(size=3))
        assert np.allclose(_R_from_rpy(*rpy_from_R(R)), R, atol=1e-9)


def test_snippets_carry_the_pose_and_the_frames():
    T_cam_base = look_at(np.array([1.1, -0.3, 0.9]), np.array([0.0, 0.0, 0.4]), 0.2)
    T_base_cam = invert_T(T_cam_base)
    joint = ET.fromstring(f"<robot>{urdf_text(T_cam_base, 'world', 'cam_optical')}</robot>")
    origin = joint.find("joint/origin")
    assert joint.find("joint/parent").get("link") == "world"
    assert joint.find("joint/child").get("link") == "cam_optical"
    assert np.allclose([float(v) for v in origin.get("xyz").split()], T_base_cam[:3, 3],
                       atol=1e-8)
    rpy = [float(v) for v in origin.get("rpy").split()]
    assert np.allclose(_R_from_rpy(*rpy), T_base_cam[:3, :3], atol=1e-8)

    handeye = yaml.safe_load(handeye_text(T_cam_base, "world", "cam_optical"))
    assert handeye["eye_on_hand"] is False and handeye["robot_base_frame"] == "world"
    t = handeye["transformation"]
    T = T_from_quaternion_xyzw_t([t["qx"], t["qy"], t["qz"], t["qw"]], [t["x"], t["y"], t["z"]])
    assert np.allclose(T, T_base_cam, atol=1e-8)

    tree = ast.parse(launch_text(T_cam_base, "world", "cam_optical"))   # valid Python
    args = [ast.literal_eval(n.value) for n in ast.walk(tree)
            if isinstance(n, ast.keyword) and n.arg == "arguments"][0]
    values = dict(zip(args[::2], args[1::2], strict=True))
    assert values["--frame-id"] == "world" and values["--child-frame-id"] == "cam_optical"
    assert float(values["--x"]) == pytest.approx(T_base_cam[0, 3], abs=1e-8)
    with pytest.raises(InputError, match="tf frame name"):
        urdf_text(T_cam_base, "base link", "cam")
    with pytest.raises(InputError, match="tf frame name"):
        handeye_text(T_cam_base, "base", 'cam"/><evil')


def test_calibrate_writes_the_snippets_with_the_frames_asked_for(tmp_path, capsys):
    data = tmp_path / "data"
    assert main(["sample", "--out", str(data), "--num", "6"]) == 0
    out = tmp_path / "r.json"
    assert main(["calibrate", "--data", str(data), "--use-labels", "--out", str(out),
                 "--base-frame", "base_link", "--camera-frame", "camera_color_optical_frame"]) == 0
    printed = capsys.readouterr().out
    T_base_cam = invert_T(np.array(json.loads(out.read_text())["T_cam_base"]))
    handeye = yaml.safe_load((tmp_path / "r.handeye.yaml").read_text())
    assert handeye["tracking_base_frame"] == "camera_color_optical_frame"
    assert handeye["transformation"]["z"] == pytest.approx(T_base_cam[2, 3], abs=1e-8)
    assert 'parent link="base_link"' in (tmp_path / "r.urdf.xml").read_text()
    assert "'--frame-id', 'base_link'" in (tmp_path / "r.launch.py").read_text()
    ros = (tmp_path / "r.ros.txt").read_text().splitlines()[-1].split()
    assert ros[7:] == ["base_link", "camera_color_optical_frame"]
    assert "r.urdf.xml" in printed and "easy_handeye" in printed


def test_bad_frame_names_are_refused_before_reading(tmp_path, capsys):
    code = main(["calibrate", "--data", str(tmp_path / "missing"), "--use-labels", "--out",
                 str(tmp_path / "r.json"), "--camera-frame", "my camera"])
    err = capsys.readouterr().err
    assert code == 2 and "--camera-frame 'my camera'" in err and "missing" not in err
