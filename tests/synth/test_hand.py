"""A dexterous hand the URDF lacks (`synth.hand`): its geometry over time, the draw and the
render."""

from __future__ import annotations

import numpy as np
import pytest
from scenes import random_extrinsic

from dream.errors import InputError
from dream.robot import load_robot
from dream.transforms import R_from_quaternion_xyzw
from synth.config import config_from_dict
from synth.frames import FrameMaker
from synth.hand import (
    FINGERS,
    PALM_GAP_M,
    PALM_HALF_M,
    SEGMENTS_M,
    SLOTS,
    HandDraw,
    finger_points,
    hand_shapes,
    sample_hand,
)

FIXED = {"width": 320, "height": 240, "fx": 330.0, "fy": 318.0, "cx": 165.2, "cy": 116.8}


def capsule_ends(size: np.ndarray, centre: np.ndarray, quaternion_wxyz: np.ndarray):
    axis = R_from_quaternion_xyzw(np.roll(quaternion_wxyz, -1))[:, 2]
    return centre - size[1] * axis, centre + size[1] * axis


def hand(period_s: float = 2.0) -> HandDraw:
    return HandDraw("tool0", 1.0, 0.3, 0.5, 0.4, period_s, np.linspace(0.0, 2.0, FINGERS),
                    np.array([0.3, 0.3, 0.3, 1.0]))


def test_a_finger_bends_each_joint_by_the_curl_and_keeps_its_lengths():
    rng = np.random.default_rng(0)
    for _ in range(20):
        along = rng.normal(size=3)
        along /= np.linalg.norm(along)
        towards = np.cross(along, rng.normal(size=3))
        towards /= np.linalg.norm(towards)
        curl = rng.uniform(0.0, 1.2)
        pts = finger_points(rng.normal(size=3), along, towards, curl, SEGMENTS_M)
        steps = np.diff(pts, axis=0)
        lengths = np.linalg.norm(steps, axis=1)
        assert np.allclose(lengths, SEGMENTS_M)
        units = steps / lengths[:, None]
        assert np.allclose(np.arccos(np.clip(units[0] @ along, -1, 1)), curl)
        assert np.allclose(np.arccos(np.clip(np.sum(units[1:] * units[:-1], axis=1), -1, 1)),
                           curl)
        assert units[0] @ towards >= -1e-12            # it bends towards the palm's face


def test_the_hand_sits_on_the_flange_and_moves_with_it():
    draw = hand()
    local = hand_shapes(draw, np.eye(4), 0.3)
    assert len(local) == SLOTS and [s[0] for s in local] == ["box"] + ["capsule"] * (SLOTS - 1)
    # the palm along the link's z axis, its near edge PALM_GAP_M from the origin
    assert np.allclose(local[0][2], [0.0, 0.0, PALM_GAP_M + PALM_HALF_M[2]])
    for seed in range(5):
        T = random_extrinsic(np.random.default_rng(seed))
        moved = hand_shapes(draw, T, 0.3)
        for (_, size_a, centre_a, q_a, _), (_, size_b, centre_b, q_b, _) in zip(
                local, moved, strict=True):
            assert np.allclose(size_a, size_b)
            assert np.allclose(T[:3, :3] @ centre_a + T[:3, 3], centre_b)
            R_a = R_from_quaternion_xyzw(np.roll(q_a, -1))
            R_b = R_from_quaternion_xyzw(np.roll(q_b, -1))
            assert np.allclose(T[:3, :3] @ R_a[:, 2], R_b[:, 2])


def test_the_fingers_are_joined_and_open_and_close_with_time():
    draw = hand(period_s=2.0)
    tips = []
    for t in (0.0, 0.5, 2.0):
        shapes = hand_shapes(draw, np.eye(4), t)
        ends = [capsule_ends(*s[1:3], s[3]) for s in shapes[1:]]
        for finger in range(FINGERS):
            segments = ends[3 * finger:3 * finger + 3]
            for (_, b), (a, _) in zip(segments[:-1], segments[1:], strict=True):
                assert np.allclose(b, a)               # the segments are joined
        tips.append(np.array([ends[3 * f + 2][1] for f in range(FINGERS)]))
    assert np.min(np.linalg.norm(tips[1] - tips[0], axis=1)) > 0.005   # the fingers moved
    assert np.allclose(tips[2], tips[0])                                 # one period later


def test_drawn_hands_stay_in_their_ranges_and_bad_ones_are_refused():
    for seed in range(20):
        draw = sample_hand(np.random.default_rng(seed), "tool0")
        assert draw.link == "tool0" and draw.scale > 0 and draw.period_s > 0
        assert draw.phases_rad.shape == (FINGERS,) and np.all((0 <= draw.rgba) & (draw.rgba <= 1))
    with pytest.raises(InputError, match="phases"):
        HandDraw("tool0", 1.0, 0.0, 0.5, 0.4, 2.0, np.zeros(3), np.ones(4))
    with pytest.raises(InputError, match="positive"):
        HandDraw("tool0", 1.0, 0.0, 0.5, 0.4, 0.0, np.zeros(FINGERS), np.ones(4))
    with pytest.raises(InputError, match="hand_prob"):
        config_from_dict({"distractors": {"hand_prob": 2.0}})


def test_the_rendered_hand_moves_with_the_flange_and_is_not_the_robot():
    """With `hand_prob` 1 in a fixed-camera sequence the same hand is drawn in every frame, its
    palm carried by the last keypoint link, its fingers in another shape in each frame, and
    neither the robot mask nor the labels change."""
    values = {"distractors": {"count": [0, 0], "hand_prob": 1.0},
              "camera": {"radius_m": [1.4, 1.6]}, "intrinsics": FIXED,
              "sequence": {"mode": "fixed_camera"}}
    robot = load_robot("ur5")
    maker = FrameMaker(robot, config_from_dict(values), seed=3)
    plain = FrameMaker(robot, config_from_dict({**values, "distractors": {"count": [0, 0]}}),
                       seed=3)
    try:
        geoms = maker.scene.distractor_geom_ids[-SLOTS:]
        bodies = maker.scene.distractor_body_ids[-SLOTS:]
        draws, seen, tips = set(), 0, []
        for i in range(4):
            rendered, without = maker.make(i), plain.make(i)
            p = maker.params(i)
            draws.add((p.scene.hand.scale, p.scene.hand.roll_rad))
            T = robot.link_poses(p.joints, p.scene.hand.link)[0]
            expected = hand_shapes(p.scene.hand, T, p.timestamp)
            assert np.allclose(maker.scene.model.body_pos[bodies[0]], expected[0][2])
            tips.append(T[:3, :3].T @ (maker.scene.model.body_pos[bodies[3]] - T[:3, 3]))
            ids = maker.renderer.render(rgb=False, segmentation=True).geom_ids
            on_hand = np.isin(ids, geoms)
            seen += on_hand.sum() > 0
            assert not (on_hand & (rendered.link_ids > 0)).any()
            assert np.allclose(rendered.uv, without.uv, equal_nan=True)
        assert seen >= 2 and len(draws) == 1
        assert len({tuple(np.round(t, 6)) for t in tips}) == 4
    finally:
        maker.close()
        plain.close()
