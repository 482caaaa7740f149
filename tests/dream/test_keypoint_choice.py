"""Keypoint links suggested for a URDF, and the warnings for origins that coincide or stay on
one line (`dream.robot.keypoint_choice`)."""

from __future__ import annotations

import contextlib
import io
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dream.cli import main
from dream.errors import RobotError
from dream.robot import builtin_robot, load_robot, parse_urdf, robot_data_dir
from dream.robot.keypoint_choice import (
    COLLINEAR_TOL_M,
    LinkOrigins,
    analyse_keypoints,
    arm_chain,
    coincident_groups,
    collinear_sets,
    logged_joint_links,
    perpendicular_spread,
    sample_link_origins,
    stays_collinear,
)

KINOVA = "robots/kinova_description/robots/kinova.urdf"
Z1 = "robots/z1_description/urdf/z1.urdf"
TIAGO = "robots/tiago_description/robots/tiago.urdf"
TIAGO_DUAL = "robots/tiago_description/robots/tiago_dual.urdf"
B1_Z1 = "robots/b1_description/urdf/b1-z1.urdf"

# A 7-axis arm in the shape of a KUKA LBR Med 7: A1 turns about the base's vertical axis and
# A2's origin lies on it, so lbr_link_0, lbr_link_1 and lbr_link_2 stay on that axis for every
# joint value; lbr_link_2 -> 3 -> 4 (A3 rolls along the upper arm) stay on a line that moves.
LBR_JOINTS = (  # name, parent, child, xyz, rpy
    ("A1", "lbr_link_0", "lbr_link_1", "0 0 0.1475", "0 0 0"),
    ("A2", "lbr_link_1", "lbr_link_2", "0 0 0.2025", "1.5708 0 3.14159"),
    ("A3", "lbr_link_2", "lbr_link_3", "0 0.2045 0", "1.5708 0 3.14159"),
    ("A4", "lbr_link_3", "lbr_link_4", "0 0 0.2155", "1.5708 0 0"),
    ("A5", "lbr_link_4", "lbr_link_5", "0 0.1845 0", "-1.5708 3.14159 0"),
    ("A6", "lbr_link_5", "lbr_link_6", "0 0 0.2155", "1.5708 0 0"),
    ("A7", "lbr_link_6", "lbr_link_7", "0 0.081 0", "-1.5708 3.14159 0"),
)


def lbr_urdf(folder: Path) -> Path:
    """The LBR-shaped URDF, with a flange (fixed, 4.5 cm out) and a camera mount on link 3."""
    links = [f"lbr_link_{i}" for i in range(8)] + ["lbr_link_ee", "camera_mount"]
    joints = [f"""<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/>
      <origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="0 0 1"/>
      <limit lower="-2.09" upper="2.09" effort="1" velocity="1"/></joint>"""
              for n, p, c, xyz, rpy in LBR_JOINTS]
    joints += ["""<joint name="flange" type="fixed"><parent link="lbr_link_7"/>
      <child link="lbr_link_ee"/><origin xyz="0 0 0.045"/></joint>""",
               """<joint name="mount" type="fixed"><parent link="lbr_link_3"/>
      <child link="camera_mount"/><origin xyz="0.05 0 0.1"/></joint>"""]
    path = folder / "med7.urdf"
    path.write_text('<?xml version="1.0"?>\n<robot name="med7">\n'
                    + "".join(f'  <link name="{n}"/>\n' for n in links)
                    + "\n".join(joints) + "\n</robot>\n")
    return path


@pytest.mark.parametrize("name", ["panda", "ur5", "xarm7"])
def test_builtin_keypoints_are_suggested(name: str) -> None:
    """The rules reproduce every built-in set, DREAM's Panda set included."""
    entry = builtin_robot(name)
    advice = analyse_keypoints(parse_urdf(entry.urdf_path), entry.base_link)
    assert advice.suggested == entry.keypoints
    assert advice.suggested_collinear == ()


def test_panda_coincident_origins_and_hand() -> None:
    entry = builtin_robot("panda")
    tree = parse_urdf(entry.urdf_path)
    advice = analyse_keypoints(tree, entry.base_link)
    assert advice.coincident == (("panda_link1", "panda_link2"), ("panda_link5", "panda_link6"),
                                 ("panda_link8", "panda_hand"))
    # the fingers branch off the hand: the arm ends there, its tcp (between them) is not taken
    assert arm_chain(tree, "panda_link0")[-1] == "panda_hand"


def test_kinova_and_z1_from_example_robot_data() -> None:
    kinova = analyse_keypoints(parse_urdf(robot_data_dir() / KINOVA))
    assert kinova.suggested == ("base",) + tuple(f"j2s6s200_link_{i}" for i in range(1, 7)) + (
        "j2s6s200_end_effector",)                   # the named tool link, not the fingers
    assert kinova.coincident == (("base", "j2s6s200_link_base"),)
    z1 = analyse_keypoints(parse_urdf(robot_data_dir() / Z1))
    assert z1.suggested == ("world", "link01", "link02", "link03", "link04", "link05", "link06",
                            "gripperStator", "gripperMover")
    # link01 and link02 lie on the base's vertical axis for every joint value
    assert z1.suggested_collinear[0].links == ("world", "link01", "link02")
    assert z1.suggested_collinear[0].fixed_line


def test_a_mobile_manipulators_arm_is_followed_past_its_wheels_legs_and_head() -> None:
    """Where the chain branches, a branch with far more moving joints than every other is the
    arm (TIAGo's torso beside its wheels and casters, then its arm beside its head; a Z1 on a
    B1 quadruped's legs); branches alike (two arms, a hand's fingers) end the chain."""
    tiago = analyse_keypoints(parse_urdf(robot_data_dir() / TIAGO)).suggested
    assert tiago[:4] == ("base_footprint", "base_link", "torso_fixed_link", "torso_lift_link")
    assert tiago[4:7] == ("arm_1_link", "arm_2_link", "arm_3_link")
    assert tiago[-1] == "hand_palm_link" and not any("head" in n for n in tiago)
    b1_z1 = analyse_keypoints(parse_urdf(robot_data_dir() / B1_Z1)).suggested
    assert b1_z1[0] == "base" and b1_z1[-3:] == ("link06", "gripperStator", "gripperMover")
    assert not any(n.startswith(("FL_", "FR_", "RL_", "RR_")) for n in b1_z1)
    dual = analyse_keypoints(parse_urdf(robot_data_dir() / TIAGO_DUAL))
    assert dual.suggested[-1] == "torso_lift_link"      # two arms alike: the user names one
    assert dual.branches == ("arm_left_1_link", "arm_right_1_link")
    assert analyse_keypoints(parse_urdf(robot_data_dir() / TIAGO)).branches == ()
    panda = builtin_robot("panda")                      # a hand's fingers are not arms
    assert analyse_keypoints(parse_urdf(panda.urdf_path), panda.base_link).branches == ()
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["robots", "--urdf", str(robot_data_dir() / TIAGO_DUAL)]) == 0
    assert "branches at torso_lift_link" in out.getvalue()
    assert "arm_left_1_link, arm_right_1_link" in " ".join(out.getvalue().split())
    # each arm's suggestion, ready to use: the torso's links, then that arm's
    left, right = dual.branch_keypoints
    assert left[:len(dual.suggested)] == dual.suggested and "arm_left_7_link" in left
    assert not any("right" in n for n in left) and "arm_right_7_link" in right
    assert f"along arm_left_1_link: --keypoints {','.join(left)}" in out.getvalue()
    assert f"--keypoints {','.join(left)} (one arm: see below)" in out.getvalue()   # use: line
    arm = load_robot(str(robot_data_dir() / TIAGO_DUAL), left)
    assert arm.joint_names == ("torso_lift_joint", *(f"arm_left_{i}_joint" for i in range(1, 8)))


def test_logged_joints_off_the_keypoints_chain_name_the_links_that_move_them() -> None:
    """A second arm, a head and a gripper the data logs are moved by adding the link after each
    branch's last logged joint; joints already driven, mimics and unknown names add nothing."""
    dual = parse_urdf(robot_data_dir() / TIAGO_DUAL)
    arm = ("base_footprint", "torso_lift_link", "arm_left_7_link")
    logged = ["torso_lift_joint", *(f"arm_{side}_{i}_joint" for side in ("left", "right")
                                    for i in range(1, 8)), "head_1_joint", "head_2_joint",
              "no_such_joint"]
    assert logged_joint_links(dual, "base_footprint", logged, arm) == (
        "arm_right_7_link", "head_2_link")
    assert logged_joint_links(dual, "base_footprint", logged[:8], arm) == ()
    # a joint the data lacks ends its branch before it: no robot may need a missing column
    gap = [n for n in logged if n not in ("arm_right_4_joint", "head_1_joint")]
    assert logged_joint_links(dual, "base_footprint", gap, arm) == ("arm_right_3_link",)
    assert logged_joint_links(dual, "base_footprint", logged, arm + ("head_2_link",)) == (
        "arm_right_7_link",)                              # a link already driven is not added
    panda = builtin_robot("panda")
    tree = parse_urdf(panda.urdf_path)
    assert logged_joint_links(tree, panda.base_link, ["panda_finger_joint1",
                                                      "panda_finger_joint2"],
                              panda.keypoints) == ("panda_leftfinger",)   # joint2 mimics joint1


def test_the_robots_command_names_the_joints_a_recording_logs() -> None:
    """`dream robots --urdf` lists the joints the suggested keypoints need (the recording's
    columns) and the moving joints the model holds at rest."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["robots", "--urdf", str(robot_data_dir() / TIAGO)]) == 0
    text = " ".join(out.getvalue().split())
    logged = text.split("joints a recording logs for them")[1].split("move no keypoint")[0]
    assert "torso_lift_joint, arm_1_joint" in logged and "arm_7_joint" in logged
    held = text.split("move no keypoint")[1]
    assert "head_1_joint" in held and "wheel_left_joint" in held and "arm_1_joint" not in held


def test_the_robots_command_describes_a_urdf_without_joints(tmp_path: Path) -> None:
    rigid = tmp_path / "rigid.urdf"
    rigid.write_text("<robot name='box'><link name='body'/></robot>")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["robots", "--urdf", str(rigid)]) == 0
    assert "joints (0):" in out.getvalue() and "nothing for a recording" in out.getvalue()
    assert "suggested keypoints" not in out.getvalue()


def test_links_on_the_base_axis_are_useless_alone(tmp_path: Path) -> None:
    tree = parse_urdf(lbr_urdf(tmp_path))
    advice = analyse_keypoints(tree, given=("lbr_link_0", "lbr_link_1", "lbr_link_2"))
    assert advice.given_line is not None and advice.given_line.fixed_line
    assert advice.suggested == tuple(f"lbr_link_{i}" for i in range(8)) + ("lbr_link_ee",)
    first = advice.suggested_collinear[0]
    assert first.links == ("lbr_link_0", "lbr_link_1", "lbr_link_2") and first.fixed_line
    # the upper arm's three origins share a line that moves with the joints
    moving = [s for s in advice.suggested_collinear if not s.fixed_line]
    assert ("lbr_link_2", "lbr_link_3", "lbr_link_4") in [s.links for s in moving]
    spread = analyse_keypoints(tree, given=("lbr_link_0", "lbr_link_2", "lbr_link_3",
                                            "camera_mount"))
    assert spread.given_line is None and spread.given_collinear == ()


def test_coincident_given_keypoints_count_once(tmp_path: Path) -> None:
    entry = builtin_robot("panda")
    tree = parse_urdf(entry.urdf_path)
    advice = analyse_keypoints(tree, "panda_link0", ("panda_link0", "panda_link1", "panda_link2",
                                                     "panda_link4"))
    assert advice.given_coincident == (("panda_link1", "panda_link2"),)
    assert advice.given_line is None     # three distinct origins, not on one line
    with pytest.raises(RobotError, match="unknown keypoint link 'gripper'"):
        analyse_keypoints(tree, "panda_link0", ("gripper",))


def test_perpendicular_spread_measures_the_distance_off_the_line() -> None:
    line = np.array([[0.0, 0, 0], [0, 0, 1], [0, 0, 2]])
    assert perpendicular_spread(line) < 1e-12
    bent = line + np.array([[0, 0, 0], [0.03, 0, 0], [0, 0, 0]])
    # best-fit line through the three points: the middle one 2/3 of 3 cm off it
    assert perpendicular_spread(bent) == pytest.approx(0.02, rel=1e-3)
    batch = np.stack([line, bent])
    np.testing.assert_allclose(perpendicular_spread(batch), [0.0, 0.02], atol=1e-4)
    assert stays_collinear(line[None]) and not stays_collinear(batch)
    assert stays_collinear(bent[None], tol_m=0.03) and COLLINEAR_TOL_M < 0.02
    with pytest.raises(RobotError, match="shape"):
        perpendicular_spread(np.zeros((4, 2)))


def test_sampling_is_seeded_and_shapes_are_checked() -> None:
    tree = parse_urdf(builtin_robot("xarm7").urdf_path)
    a = sample_link_origins(tree, "link_base", num_samples=8, seed=3)
    b = sample_link_origins(tree, "link_base", num_samples=8, seed=3)
    assert a.points.shape == (8, len(a.links), 3) and "world" not in a.links
    np.testing.assert_array_equal(a.points, b.points)
    assert coincident_groups(a, ["link1", "link2", "link3"]) == (("link1", "link2"),)
    assert collinear_sets(a, ["link_base", "link1", "link2"]) == ()   # two distinct origins
    with pytest.raises(RobotError, match="shape"):
        LinkOrigins(("a", "b"), np.zeros((3, 1, 3)))
    with pytest.raises(RobotError, match="no sampled origin"):
        a.of(["world"])


def test_the_search_robot_moves_both_arms_the_data_logs(caplog) -> None:
    """A dual-arm URDF without keypoints: the suggestion stops at the torso, but the search's
    robot drives every logged joint (before: none, and the search found no motion)."""
    from types import SimpleNamespace

    from dream.camera import CameraIntrinsics
    from dream.cli.search_robot import robot_for_search
    from dream.sequence import Frame, Sequence

    names = tuple(f"{side}_{j}" for side in ("right", "left")
                  for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2"))
    camera = CameraIntrinsics(300.0, 300.0, 159.5, 119.5, 320, 240)
    urdf = str(robot_data_dir() / "robots/baxter_description/urdf/baxter.urdf")
    seq = Sequence(robot=urdf, camera=camera, joint_names=names, keypoint_names=(),
                   frames=(Frame(name="000000", joints=np.full(len(names), 0.1)),))
    request = SimpleNamespace(robot=None, keypoint_links=None)
    robot = robot_for_search(seq, request)
    assert sorted(robot.joint_names) == sorted(names)
    assert robot.keypoint_names == ("base", "right_wrist", "left_wrist")
    panda = Sequence(robot="panda", camera=camera,
                     joint_names=tuple(f"panda_joint{i}" for i in range(1, 8)), keypoint_names=(),
                     frames=(Frame(name="000000", joints=np.zeros(7)),))
    assert robot_for_search(panda, request).keypoint_names == builtin_robot("panda").keypoints
    # a branch whose readings lie beyond its limits (a gripper's width for a finger's travel)
    # is drawn at rest, with a warning, instead of refusing the recording
    fingers = Sequence(robot="panda", camera=camera,
                       joint_names=panda.joint_names + ("panda_finger_joint1",),
                       keypoint_names=(),
                       frames=(Frame(name="000000", joints=np.r_[np.zeros(7), 0.08]),))
    with caplog.at_level(logging.WARNING, logger="dream.outline_robot"):
        robot = robot_for_search(fingers, request)
    assert robot.keypoint_names == builtin_robot("panda").keypoints
    assert "panda_leftfinger are drawn at rest" in caplog.text
    inside = replace(fingers, frames=(Frame(name="000000", joints=np.r_[np.zeros(7), 0.03]),))
    assert robot_for_search(inside, request).keypoint_names[-1] == "panda_leftfinger"
    # the overlays' outline is that of the same robot, whichever robot drew the keypoints
    from dream.overlay import _Outliner

    keypoint_robot = load_robot("panda")
    assert _Outliner(inside, keypoint_robot).robot.keypoint_names[-1] == "panda_leftfinger"
