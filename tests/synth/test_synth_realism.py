"""Randomisation aimed at real photos (synth.realism, held assemblies, boards): the draws."""

import colorsys

import numpy as np
import pytest

from dream.camera import project
from dream.errors import InputError
from dream.robot import load_robot
from dream.transforms import invert_T, transform_points
from synth.config import config_from_dict
from synth.randomize import HELD_PART_OVERLAP, sample_frame
from synth.realism import (
    CLOSEUP_MIN_HEIGHT_M,
    FLOOR_TOLERANCE_M,
    LOOSE_AZIMUTH_SPREAD_RAD,
    METAL_SPECULAR,
    OTHER_ROBOT_AZIMUTH_SPREAD_RAD,
    WHITE_PLASTIC_SATURATION,
    WHITE_PLASTIC_SPECULAR,
    WHITE_PLASTIC_VALUE,
    closeup_pose,
)
from synth.textures import calibration_board

PANDA = load_robot("panda")
UR5 = load_robot("ur5")
# two light parts and two dark ones, as a Panda's white links and black joints
RGBA = np.array([[0.9, 0.9, 0.9, 1.0], [0.1, 0.1, 0.1, 1.0], [0.95, 0.95, 0.9, 1.0],
                 [0.2, 0.2, 0.25, 1.0]])
ALL_ON = {"camera": {"closeup_prob": 0.5}, "intrinsics": {"hfov_rad": [0.9, 1.75]},
          "appearance": {"white_plastic_prob": 0.3, "metal_prob": 0.3, "hide_hand_prob": 0.5},
          "distractors": {"held_prob": 1.0, "held_parts": [1, 3], "held_checker_prob": 0.5,
                          "robot_prob": 0.5, "loose_prob": 0.5}}


def frame(seed, index, values, other=None, robot=PANDA):
    return sample_frame(seed, index, robot, config_from_dict(values), RGBA, 4, 6, 4,
                        other_robot=other)


def test_new_draws_leave_the_others_as_they_were():
    """Each draw has its own random stream: a recipe using them draws the same joints, lights,
    distractors and backgrounds as one without them, and by default nothing new appears."""
    for i in range(20):
        plain, real = frame(5, i, {}), frame(5, i, ALL_ON, PANDA)
        assert not plain.scene.hide_hand and plain.scene.other_robot is None
        assert np.array_equal(plain.joints, real.joints)
        assert plain.scene.background_seed == real.scene.background_seed
        assert [d.position_m.tolist() for d in plain.scene.distractors] == \
            [d.position_m.tolist() for d in real.scene.distractors]
        assert [lt.position_m.tolist() for lt in plain.scene.lights] == \
            [lt.position_m.tolist() for lt in real.scene.lights]


def test_closeup_cameras_aim_at_a_keypoint_from_close():
    values = {"camera": {"closeup_prob": 1.0, "closeup_radius_m": [0.3, 0.5]}}
    for i in range(20):
        f = frame(9, i, values)
        P_cam = transform_points(f.scene.T_cam_base, PANDA.forward_kinematics(f.joints))
        camera = f.scene.camera
        # aimed at: one keypoint projects to the image centre, from 0.3-0.5 m
        centred = np.all(np.abs(project(camera, P_cam) - [camera.cx, camera.cy]) < 1e-6,
                         axis=1) & (P_cam[:, 2] > 0)
        assert centred.any()
        assert np.all((np.linalg.norm(P_cam[centred], axis=1) >= 0.3 - 1e-9)
                      & (np.linalg.norm(P_cam[centred], axis=1) <= 0.5 + 1e-9))
    shares = [frame(9, i, {"camera": {"closeup_prob": 0.3}}).scene.T_cam_base for i in range(200)]
    close = sum(np.linalg.norm(invert_T(T)[:3, 3] - [0, 0, 0.4]) < 0.95 for T in shares)
    assert 35 <= close <= 85


@pytest.mark.parametrize("mode", ["fixed_camera", "trajectory"])
def test_a_sequence_closeup_aimed_at_the_start_sees_the_first_frames_arm(mode):
    """`camera.closeup_aim: start` aims a sequence's one close-up at a keypoint of its first
    frame, wherever the joint ranges' middle is; the default aims at that middle."""
    values = {"camera": {"closeup_prob": 1.0, "closeup_aim": "start"},
              "sequence": {"mode": mode}}
    for seed in range(5):
        first, later = frame(seed, 0, values, None, UR5), frame(seed, 7, values, None, UR5)
        assert np.array_equal(first.scene.T_cam_base, later.scene.T_cam_base)
        camera = first.scene.camera
        P_cam = transform_points(first.scene.T_cam_base, UR5.forward_kinematics(first.joints))
        centred = np.all(np.abs(project(camera, P_cam) - [camera.cx, camera.cy]) < 1e-6, axis=1)
        assert centred.any() and np.all(P_cam[centred, 2] > 0)
        middle = frame(seed, 0, {**values, "camera": {"closeup_prob": 1.0}}, None, UR5)
        P_mid = transform_points(middle.scene.T_cam_base, UR5.forward_kinematics(
            (UR5.joint_lower + UR5.joint_upper) / 2))
        assert np.any(np.all(np.abs(project(camera, P_mid) - [camera.cx, camera.cy]) < 1e-6,
                             axis=1))


def test_closeups_stay_above_the_floor_and_aim_at_keypoints_above_it():
    """A close-up never aims at a keypoint under the floor, nor stands under it: over many
    draws with one keypoint at the floor, one above and one through it, every camera is at
    least `CLOSEUP_MIN_HEIGHT_M` high and aimed at one of the first two, the low elevations
    drawn again; with every keypoint under the floor, no close-up."""
    config = config_from_dict({"camera": {"closeup_prob": 1.0, "closeup_radius_m": [0.3, 0.8],
                                          "elevation_rad": [-0.5, 1.1]}})
    P = np.array([[0.4, 0.0, 0.0], [0.0, 0.5, 0.3], [0.2, 0.2, -0.2]])
    heights, aimed = [], set()
    for i in range(300):
        T = closeup_pose(np.random.default_rng(i), config, P)
        heights.append(invert_T(T)[2, 3])
        P_cam = transform_points(T, P)
        aimed.add(int(np.argmin(np.linalg.norm(P_cam[:, :2] / P_cam[:, 2:], axis=1))))
    assert min(heights) >= CLOSEUP_MIN_HEIGHT_M - 1e-9 and aimed == {0, 1}
    assert sum(h < 0.1 for h in heights) > 0      # as low as allowed, not pushed far up
    assert closeup_pose(np.random.default_rng(0), config, P[2:]) is None


def test_joints_above_the_floor_are_drawn_again_only_where_a_keypoint_is_under_it():
    """`joints.above_floor`: a UR5, whose full joint ranges reach under its base in about half
    the draws, keeps every keypoint above the floor (within `FLOOR_TOLERANCE_M`) in every
    frame of a fixed-camera sequence and at every waypoint of a trajectory; frames whose first
    draw was above it keep that draw."""
    plain = {"sequence": {"mode": "fixed_camera"}}
    above = {"sequence": {"mode": "fixed_camera"}, "joints": {"above_floor": True}}
    lows, kept = [], 0
    for i in range(60):
        q0, q1 = frame(3, i, plain, None, UR5).joints, frame(3, i, above, None, UR5).joints
        low0, low1 = UR5.forward_kinematics(q0)[:, 2].min(), UR5.forward_kinematics(q1)[:, 2].min()
        lows.append(low0)
        assert low1 >= -FLOOR_TOLERANCE_M
        if low0 >= -FLOOR_TOLERANCE_M:
            assert np.array_equal(q0, q1)
            kept += 1
    assert min(lows) < -0.1 and 10 < kept < 50
    waypoint_s = 1.5
    trajectory = {"sequence": {"mode": "trajectory", "fps": 2.0, "waypoint_period_s": waypoint_s},
                  "joints": {"above_floor": True}}
    for k in range(8):   # frame 3k is waypoint k
        q = frame(4, 3 * k, trajectory, None, UR5).joints
        assert UR5.forward_kinematics(q)[:, 2].min() >= -FLOOR_TOLERANCE_M


def test_an_unknown_closeup_aim_is_refused():
    with pytest.raises(InputError, match="camera.closeup_aim 'end' must be one of middle, start"):
        config_from_dict({"camera": {"closeup_aim": "end"}})


def test_white_plastic_keeps_dark_parts_and_metal_greys_every_part():
    white = frame(2, 0, {"appearance": {"white_plastic_prob": 1.0}}).scene
    assert WHITE_PLASTIC_SPECULAR[0] <= white.robot_specular <= WHITE_PLASTIC_SPECULAR[1]
    for part, real in zip(white.robot_rgba, RGBA, strict=True):
        h, s, v = colorsys.rgb_to_hsv(*part[:3])
        if colorsys.rgb_to_hsv(*real[:3])[2] > 0.5:
            assert v >= WHITE_PLASTIC_VALUE[0] and s <= WHITE_PLASTIC_SATURATION[1]
        else:
            assert np.array_equal(part, real)
    metal = frame(2, 0, {"appearance": {"metal_prob": 1.0}}).scene
    assert METAL_SPECULAR[0] <= metal.robot_specular <= METAL_SPECULAR[1]
    assert np.allclose(metal.robot_rgba, metal.robot_rgba[0])


def test_held_assemblies_and_boards():
    values = {"distractors": {"held_prob": 1.0, "held_parts": [3, 3], "held_checker_prob": 1.0,
                              "held_size_m": [0.1, 0.2]}}
    for i in range(10):
        held = frame(4, i, values).scene.held
        assert len(held.parts) == 3 and held.checkerboard
        assert held.parts[0].texture >= 0 and np.array_equal(held.parts[0].rgba, [1, 1, 1, 1])
        for a, b in zip(held.parts, held.parts[1:], strict=False):
            reach = (a.size_m.max() + b.size_m.max()) * HELD_PART_OVERLAP
            assert np.linalg.norm(b.position_m - a.position_m) == pytest.approx(reach)
    # one part, as before the assemblies existed
    assert len(frame(4, 0, {"distractors": {"held_prob": 1.0}}).scene.held.parts) == 1


def test_calibration_board_is_black_and_white_with_a_white_margin():
    board = calibration_board(np.random.default_rng(0), 64, 64)
    assert set(np.unique(board).tolist()) == {0, 255}
    assert np.all(board[0] == 255) and np.all(board[:, 0] == 255)
    assert 0.2 < np.mean(board == 0) < 0.5


def test_other_robot_stands_beyond_the_arm_in_its_own_joints():
    values = {"distractors": {"robot_prob": 1.0, "robot_distance_m": [1.0, 1.5]}}
    for i in range(20):
        f = frame(6, i, values, UR5)
        other = f.scene.other_robot
        xy = other.T_base_other[:2, 3]
        assert 1.0 - 1e-9 <= np.linalg.norm(xy) <= 1.5 + 1e-9
        camera = invert_T(f.scene.T_cam_base)[:2, 3]
        angle = np.arccos(np.dot(xy, -camera) / np.linalg.norm(xy) / np.linalg.norm(camera))
        assert angle <= OTHER_ROBOT_AZIMUTH_SPREAD_RAD + 1e-9
        assert other.T_base_other[2, 3] == 0.0 and other.joints.shape == (UR5.num_joints,)
        assert np.all(other.joints >= UR5.joint_lower) and np.all(other.joints <= UR5.joint_upper)
    sequence = {**values, "sequence": {"mode": "fixed_camera"}}
    a, b = frame(6, 0, sequence, UR5), frame(6, 5, sequence, UR5)
    assert np.array_equal(a.scene.other_robot.joints, b.scene.other_robot.joints)
    moving = {"distractors": {**values["distractors"], "robot_moves": True},
              "sequence": {"mode": "fixed_camera"}}
    c, d = frame(6, 0, moving, UR5), frame(6, 5, moving, UR5)
    assert np.array_equal(c.scene.other_robot.T_base_other, a.scene.other_robot.T_base_other)
    assert np.array_equal(c.scene.other_robot.T_base_other, d.scene.other_robot.T_base_other)
    assert not np.array_equal(c.scene.other_robot.joints, d.scene.other_robot.joints)
    assert np.all(d.scene.other_robot.joints >= UR5.joint_lower)
    assert np.all(d.scene.other_robot.joints <= UR5.joint_upper)


def test_loose_parts_are_the_end_of_the_chain_beside_the_arm_on_the_camera_side():
    values = {"distractors": {"loose_prob": 1.0, "loose_keypoints": 2,
                              "loose_distance_m": [0.5, 0.7], "loose_height_m": [0.1, 0.3]}}
    starts = set()
    for i in range(30):
        f = frame(8, i, values, PANDA)
        loose = f.scene.other_robot
        start = loose.links[0]
        starts.add(start)
        assert start in ("panda_link7", "panda_hand")
        assert loose.links == tuple(k for k in PANDA.link_names
                                    if PANDA.tree.is_ancestor(start, k))
        T_base_link = loose.T_base_other @ PANDA.link_poses(loose.joints, loose.links)
        centre = T_base_link[:, :3, 3].mean(axis=0)
        assert 0.5 - 1e-9 <= np.linalg.norm(centre[:2]) <= 0.7 + 1e-9
        assert 0.1 - 1e-9 <= centre[2] <= 0.3 + 1e-9
        camera = invert_T(f.scene.T_cam_base)[:2, 3]
        angle = np.arccos(np.dot(centre[:2], camera) / np.linalg.norm(centre[:2]) /
                          np.linalg.norm(camera))
        assert angle <= LOOSE_AZIMUTH_SPREAD_RAD + 1e-9
        assert np.allclose(loose.T_base_other[:3, :3] @ loose.T_base_other[:3, :3].T, np.eye(3))
    assert starts == {"panda_link7", "panda_hand"}


def test_loose_parts_only_where_the_whole_robot_is_not_drawn():
    both = {"distractors": {"robot_prob": 0.5, "loose_prob": 1.0}}
    draws = [frame(10, i, both, PANDA).scene.other_robot for i in range(40)]
    whole = [d for d in draws if d.links is None]
    assert 8 <= len(whole) <= 32 and all(d is not None for d in draws)
    alone = {"distractors": {"robot_prob": 0.5}}
    assert [frame(10, i, alone, PANDA).scene.other_robot is None for i in range(40)] == \
        [d.links is not None for d in draws]
