"""`dream plan`: the pose checks, the planner and the command, end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dream.camera import CameraIntrinsics, project
from dream.cli.app import main
from dream.errors import InputError
from dream.transforms import look_at, transform_points
from plan.camera_prior import CameraPrior, prior_from_result
from plan.feasibility import Box, Feasibility, PoseChecker, in_view
from plan.planner import PlanSettings, choose_poses, find_candidates, joint_ranges

CAMERA = CameraIntrinsics(600.0, 600.0, 319.5, 239.5, 640, 480)
POSITION, TARGET = np.array([1.6, 0.0, 0.6]), np.array([0.0, 0.0, 0.4])
T_CAM_BASE = look_at(POSITION, TARGET)
# found by drawing random poses and checked in renders: a valid pose, one that folds the hand
# 9 cm into the upper arm, one where the camera sees a wrist keypoint through another link
VALID = [-2.18, 0.6, 0.85, -1.22, -0.67, 3.74, 2.79]
SELF_COLLISION = [2.88, -1.54, 2.54, -2.97, 0.64, 0.39, 2.71]
HIDDEN = [1.33, -1.14, 2.1, -1.45, -1.16, 1.58, -2.73]
CAMERA_ARGS = ["--camera", "1.6,0,0.6", "--look-at", "0,0,0.4",
               "--intrinsics", "600,600,319.5,239.5,640,480"]


@pytest.fixture(scope="module")
def checker(panda):
    return PoseChecker(panda, Feasibility(), CAMERA, T_CAM_BASE)


def test_checks_name_what_fails(checker):
    assert checker.check(np.array(VALID)).valid
    collision = checker.check(np.array(SELF_COLLISION))
    assert collision.failed == "self-collision" and collision.self_clearance_m < -0.05
    assert checker.check(np.array(HIDDEN)).failed == "keypoint hidden"


def test_the_table_and_keep_out_boxes_are_obstacles(panda):
    q = np.array(VALID)
    hand = panda.forward_kinematics(q)[-1]
    box = Box(tuple(hand - 0.05), tuple(hand + 0.05))
    assert PoseChecker(panda, Feasibility(keep_out=(box,)), CAMERA, T_CAM_BASE).check(q) \
        .failed == "keep-out box"
    ray = (hand - POSITION) / np.linalg.norm(hand - POSITION)
    screen = Box(tuple(POSITION + 0.3 * ray - 0.03), tuple(POSITION + 0.3 * ray + 0.03))
    assert PoseChecker(panda, Feasibility(keep_out=(screen,)), CAMERA, T_CAM_BASE).check(q) \
        .failed == "keypoint hidden"
    far = Box((5.0, 5.0, 0.0), (5.5, 5.5, 0.5))
    assert PoseChecker(panda, Feasibility(keep_out=(far,)), CAMERA, T_CAM_BASE).check(q).valid
    lowest = min(float(p[2]) for p in panda.forward_kinematics(q)[1:])
    raised = Feasibility(table_z_m=lowest)
    assert PoseChecker(panda, raised, CAMERA, T_CAM_BASE).check(q).failed == "table"


def test_in_view_keeps_the_margin():
    P = np.array([[[0.0, 0.0, 0.4]]])
    uv = project(CAMERA, transform_points(T_CAM_BASE, P))[0, 0]
    margin = float(min(uv[0], uv[1], 639 - uv[0], 479 - uv[1]))
    assert in_view(P, CAMERA, T_CAM_BASE, margin - 1)[0]
    assert not in_view(P, CAMERA, T_CAM_BASE, margin + 1)[0]


def test_feasibility_checks_its_values():
    with pytest.raises(InputError, match="lower < upper"):
        Box((0.0, 0.0, 0.0), (1.0, -1.0, 1.0))
    with pytest.raises(InputError, match="max_cut"):
        Feasibility(max_cut=1.5)


def test_joint_ranges_must_lie_inside_the_limits(panda):
    lower, upper = joint_ranges(panda, {"panda_joint1": (-1.0, 1.0)})
    assert (lower[0], upper[0]) == (-1.0, 1.0)
    with pytest.raises(InputError, match="outside the URDF limits.*radians, not degrees"):
        joint_ranges(panda, {"panda_joint1": (-90.0, 90.0)})
    with pytest.raises(InputError, match="no joint 'elbow'"):
        joint_ranges(panda, {"elbow": (-1.0, 1.0)})


def test_planned_poses_are_valid_and_better_than_random(panda, checker):
    prior = CameraPrior(CAMERA, T_CAM_BASE, 0.05, 0.05)
    settings = PlanSettings(num_poses=8, candidates=120, camera_samples=4)
    candidates = find_candidates(panda, prior, Feasibility(), settings, joint_ranges(panda))
    assert len(candidates.joints) == 120
    plan = choose_poses(panda, prior, candidates, settings)
    assert plan.joints.shape == (8, 7)
    assert all(checker.check(q).valid for q in plan.joints)
    assert np.all(plan.joints >= panda.joint_lower) and np.all(plan.joints <= panda.joint_upper)
    assert plan.random_predicted["position_worst_m"] > 1.3 * plan.predicted["position_worst_m"]


def test_dream_plan_writes_the_plan_folder(tmp_path, panda, checker, capsys):
    out = tmp_path / "plan"
    code = main(["plan", "--robot", "panda", *CAMERA_ARGS, "--num", "6", "--candidates",
                 "60", "--out", str(out), "--keep-out", "0.4,0.4,0,0.8,0.8,0.4"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "predicted 1-sigma" in printed and "span about" not in printed
    doc = json.loads((out / "plan.json").read_text())
    joints = np.loadtxt(out / "joints.txt")
    assert joints.shape == (6, 7)
    assert np.allclose(joints, [p["joints_rad"] for p in doc["poses"]], atol=1e-6)
    assert doc["predicted"]["camera_position_worst_mm"] > 0
    assert doc["camera"]["position_base_m"] == pytest.approx(POSITION.tolist())
    assert all(p["keypoint_border_px"] >= 20 for p in doc["poses"])
    boxed = PoseChecker(panda, Feasibility(keep_out=(Box((0.4, 0.4, 0), (0.8, 0.8, 0.4)),)),
                        CAMERA, T_CAM_BASE)
    assert all(boxed.check(q).valid for q in joints)
    assert (out / "contact_sheet.png").stat().st_size > 0


def test_a_camera_far_from_the_robot_is_warned_of(tmp_path, capsys):
    """A camera 8 m away planned without a word (the Panda about 60 px tall)."""
    code = main(["plan", "--robot", "panda", "--camera", "8,0,1.5", "--look-at", "0,0,0.4",
                 "--intrinsics", "600,600,319.5,239.5,640,480", "--num", "3", "--candidates",
                 "30", "--out", str(tmp_path / "plan")])
    assert code == 0
    printed = capsys.readouterr().out
    span = float(printed.split("keypoints span about ")[1].split(" px")[0])
    assert 30 < span < 120 and "place the camera nearer the robot" in printed


def test_a_box_may_hold_the_base_and_moves_are_checked(tmp_path, panda):
    """A keep-out box under the robot (a table given as a box) leaves the base alone; every
    move of the plan is reported with its clearance."""
    out = tmp_path / "plan"
    assert main(["plan", "--robot", "panda", *CAMERA_ARGS, "--keep-out=-1,-1,-0.5,1,1,0",
                 "--num", "5", "--candidates", "40", "--out", str(out)]) == 0
    doc = json.loads((out / "plan.json").read_text())
    assert [(m["from"], m["to"]) for m in doc["moves"]] == [(i, i + 1) for i in range(4)]
    assert doc["start_joints_rad"] is None
    assert ["panda_leftfinger", "panda_rightfinger"] in doc["always_in_contact"]
    assert doc["other_joints"]   # the fingers, at the value the checks used
    checker = PoseChecker(panda, Feasibility(), CAMERA, T_CAM_BASE)
    joints = np.array([p["joints_rad"] for p in doc["poses"]])
    for move, q_from, q_to in zip(doc["moves"], joints[:-1], joints[1:], strict=True):
        clear = checker.motion_clearance(q_from, q_to) >= 0.01
        assert move["clear"] == clear or not clear   # the box only makes moves less clear


def test_an_overhead_camera_and_a_result_of_another_robot(tmp_path):
    from plan.camera_prior import prior_from_look_at

    prior = prior_from_look_at(np.array([0.5, 0.0, 1.5]), np.array([0.5, 0.0, 0.0]), CAMERA)
    assert np.allclose(prior.position_base_m, [0.5, 0.0, 1.5])
    result = tmp_path / "RESULT.json"
    result.write_text(json.dumps({"T_cam_base": T_CAM_BASE.tolist(), "robot": "ur5"}))
    with pytest.raises(InputError, match="calibrated robot 'ur5', not 'panda'"):
        prior_from_result(result, CAMERA, robot_names={"panda"})


def test_a_result_file_states_the_camera(tmp_path):
    result = tmp_path / "RESULT.json"
    result.write_text(json.dumps({
        "T_cam_base": T_CAM_BASE.tolist(), "sigma_camera_position_base_m": [0.01, 0.02, 0.03],
        "sigma_rotation_rad": [0.01, 0.01, 0.02],
        "data": {"camera": {"fx": 600, "fy": 600, "cx": 319.5, "cy": 239.5, "width": 640,
                            "height": 480, "distortion": None}}}))
    prior = prior_from_result(result)
    assert prior.camera == CAMERA
    assert (prior.position_sigma_m, prior.rotation_sigma_rad) == (0.03, 0.02)
    assert np.allclose(prior.T_cam_base, T_CAM_BASE)
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps({"T_cam_base": T_CAM_BASE.tolist()}))
    with pytest.raises(InputError, match="does not record its camera.*--intrinsics"):
        prior_from_result(bare)
    assert prior_from_result(bare, CAMERA).position_sigma_m > 0


def test_dream_plan_from_a_result_with_the_model_keypoints(tmp_path):
    """--camera RESULT.json, --model, --start, --joint-range and --table-z none together."""
    from dream.models import BUNDLED_MODEL

    result = tmp_path / "RESULT.json"
    result.write_text(json.dumps({
        "T_cam_base": T_CAM_BASE.tolist(),
        "data": {"camera": {"fx": 600, "fy": 600, "cx": 319.5, "cy": 239.5, "width": 640,
                            "height": 480}}}))
    start = ",".join(str(v) for v in VALID)
    out = tmp_path / "plan"
    assert main(["plan", "--robot", "panda", "--camera", str(result), "--model",
                 str(BUNDLED_MODEL), f"--start={start}", "--joint-range",
                 "panda_joint1=-2.5:0", "--table-z", "none", "--num", "4", "--candidates", "40",
                 "--out", str(out)]) == 0
    doc = json.loads((out / "plan.json").read_text())
    assert doc["camera"]["source"] == str(result)
    assert doc["start_joints_rad"] == pytest.approx(VALID)
    assert doc["moves"][0]["from"] == "start" and len(doc["moves"]) == 4
    assert doc["feasibility"]["table_z_m"] is None
    joints = np.array([p["joints_rad"] for p in doc["poses"]])
    assert np.all((joints[:, 0] >= -2.5) & (joints[:, 0] <= 0.0))
    from dream.detection import load_keypoint_model

    assert doc["keypoint_names"] == list(load_keypoint_model(BUNDLED_MODEL).keypoint_names)


@pytest.mark.parametrize(("args", "message"), [
    (["--camera=-3,0,0.5", "--look-at=-6,0,0.5",
      "--intrinsics", "600,600,319.5,239.5,640,480"], "in none of"),
    ([*CAMERA_ARGS, "--joint-range", "panda_joint1=-90:90"], "outside the URDF limits"),
    ([*CAMERA_ARGS, "--num", "12", "--max-draws", "20"], "only 3 valid poses were found in 20"),
    ([*CAMERA_ARGS, "--num", "40", "--candidates", "30"], "cannot be chosen from 30"),
    ([*CAMERA_ARGS, "--start=0,-45,0,-135,0,90,45"], "are these degrees?"),
    ([*CAMERA_ARGS, "--joint-range", "panda_joint1=-1:1", "--joint-range",
      "panda_joint1=-2:2"], "names panda_joint1 twice"),
    (["--camera", "1.6 0 0.6"], "neither a RESULT.json file nor a position"),
    (["--camera", "1.6,0,0.6", "--look-at", "0,0,0.4", "--intrinsics", "600,600,319.5,239.5"],
     "must be six numbers"),
    (["--camera", "1.6,0,0.6", "--intrinsics", "600,600,319.5,239.5,640,480"],
     "needs --look-at"),
    ([*CAMERA_ARGS, "--keep-out", "1,2,3"], "must be 6 finite numbers"),
    (["--camera", "1600,0,600", "--look-at", "0,0,400", "--intrinsics",
      "600,600,319.5,239.5,640,480"], "are these millimetres?"),
    (["--camera", "1.6,0,0.6", "--look-at", "0,0,400", "--intrinsics",
      "600,600,319.5,239.5,640,480"], "the point looked at lies"),
    (["--camera", "1.6,0,0.6", "--look-at", "0,0,0.4", "--intrinsics",
      "3.6,3.6,319.5,239.5,640,480"], "is the focal length in millimetres?"),
    (["--camera", "1.4,0.5,-0.5", "--look-at", "0,0,0.4", "--intrinsics",
      "600,600,319.5,239.5,640,480"], "below the table (--table-z 0)"),
    ([*CAMERA_ARGS, "--position-sigma-m", "50"], "give --position-sigma-m in metres"),
])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys, args, message):
    out = tmp_path / "plan"
    assert main(["plan", "--robot", "panda", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err
    assert not out.exists()
