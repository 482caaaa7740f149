"""A person guiding the arm by hand (`synth.person`): the arm's geometry, the draw and the
render."""

from __future__ import annotations

import numpy as np
import pytest

from dream.errors import InputError
from dream.robot import load_robot
from dream.transforms import R_from_quaternion_xyzw, transform_points
from synth.config import config_from_dict
from synth.frames import FrameMaker
from synth.person import (
    CAMERA_CLEAR_RAD,
    MIN_SHOULDER_HEIGHT_M,
    REACH_FRACTION,
    SLOTS,
    PersonDraw,
    elbow_position,
    person_shapes,
    sample_person,
    shoulder_position,
)

FIXED = {"width": 320, "height": 240, "fx": 330.0, "fy": 318.0, "cx": 165.2, "cy": 116.8}


def capsule_ends(size: np.ndarray, centre: np.ndarray, quaternion_wxyz: np.ndarray):
    axis = R_from_quaternion_xyzw(np.roll(quaternion_wxyz, -1))[:, 2]
    return centre - size[1] * axis, centre + size[1] * axis


def test_the_elbow_joins_segments_of_their_lengths_below_the_line():
    rng = np.random.default_rng(0)
    for _ in range(50):
        shoulder = rng.uniform(-1, 1, 3)
        hand = shoulder + rng.normal(size=3) * 0.2
        upper, fore = rng.uniform(0.25, 0.35, 2)
        if not abs(upper - fore) < np.linalg.norm(hand - shoulder) < upper + fore:
            continue
        elbow = elbow_position(shoulder, hand, upper, fore, 0.0)
        assert np.linalg.norm(elbow - shoulder) == pytest.approx(upper)
        assert np.linalg.norm(hand - elbow) == pytest.approx(fore)
        t = (elbow - shoulder) @ (hand - shoulder) / np.sum((hand - shoulder) ** 2)
        assert elbow[2] <= (shoulder + t * (hand - shoulder))[2] + 1e-12   # it hangs
        turned = elbow_position(shoulder, hand, upper, fore, 0.5)
        assert np.linalg.norm(turned - shoulder) == pytest.approx(upper)
        assert np.linalg.norm(turned - elbow) > 0


def test_a_hand_out_of_reach_straightens_the_arm_towards_it():
    shoulder, hand = np.zeros(3), np.array([2.0, 0.0, 0.0])
    elbow = elbow_position(shoulder, hand, 0.3, 0.27, 0.0)
    assert np.allclose(elbow, [0.3, 0.0, 0.0])


def test_the_shoulder_rests_at_the_anchor_or_leans_to_the_hand():
    anchor = np.array([0.8, 0.0, 1.3])
    near = np.array([0.5, 0.0, 1.0])
    assert np.array_equal(shoulder_position(anchor, near, 0.57), anchor)
    far = np.array([0.0, 0.0, 0.4])
    leaned = shoulder_position(anchor, far, 0.57)
    assert np.linalg.norm(leaned - far) == pytest.approx(REACH_FRACTION * 0.57)
    direction = (anchor - far) / np.linalg.norm(anchor - far)
    assert np.allclose((leaned - far) / np.linalg.norm(leaned - far), direction)


def person(anchor=(0.8, 0.0, 1.35)) -> PersonDraw:
    return PersonDraw("hand", np.array([0.0, 0.03, 0.02]), np.array(anchor), 1.0, 0.2,
                      np.array([0.2, 0.3, 0.8, 1.0]), np.array([0.9, 0.7, 0.6, 1.0]))


def test_the_hand_grips_the_link_and_moves_with_it():
    draw = person()
    for z in (0.3, 0.7, 1.1):
        T = np.eye(4)
        T[:3, :3] = R_from_quaternion_xyzw(np.array([0.1, 0.3, -0.2, 0.9]) / np.linalg.norm(
            [0.1, 0.3, -0.2, 0.9]))
        T[:3, 3] = [0.4, 0.1, z]
        shapes = person_shapes(draw, T)
        assert len(shapes) == SLOTS
        kinds = [s[0] for s in shapes]
        assert kinds == ["capsule"] * 5 + ["sphere"]
        hand = transform_points(T, draw.grip_m)
        assert np.allclose(shapes[2][2], hand)             # the hand's centre at the grip
        upper_a, upper_b = capsule_ends(*shapes[0][1:3], shapes[0][3])
        fore_a, _ = capsule_ends(*shapes[1][1:3], shapes[1][3])
        assert np.allclose(upper_b, fore_a)                # the arm is joined at the elbow
        assert upper_a[2] >= MIN_SHOULDER_HEIGHT_M - 1e-12  # it bends no lower
        legs_a, _ = capsule_ends(*shapes[4][1:3], shapes[4][3])
        assert legs_a[2] == pytest.approx(shapes[4][1][0])  # the legs stand on the floor


def test_a_drawn_person_stands_off_the_cameras_side():
    camera = np.array([1.5, 0.5, 1.0])
    bearing = np.arctan2(camera[1], camera[0])
    for seed in range(40):
        draw = sample_person(np.random.default_rng(seed), "hand", camera, (0.6, 1.0),
                             (1.2, 1.5))
        off = np.angle(np.exp(1j * (np.arctan2(draw.anchor_m[1], draw.anchor_m[0]) - bearing)))
        assert abs(off) >= CAMERA_CLEAR_RAD - 1e-9
        assert 0.6 <= np.hypot(*draw.anchor_m[:2]) <= 1.0 and 1.2 <= draw.anchor_m[2] <= 1.5
        assert draw.link == "hand" and np.all((0 <= draw.skin_rgba) & (draw.skin_rgba <= 1))


def test_bad_persons_are_refused():
    with pytest.raises(InputError, match="\\(3,\\) grip"):
        PersonDraw("hand", np.zeros(2), np.zeros(3), 1.0, 0.0, np.ones(4), np.ones(4))
    with pytest.raises(InputError, match="scale"):
        PersonDraw("hand", np.zeros(3), np.zeros(3), 0.0, 0.0, np.ones(4), np.ones(4))
    with pytest.raises(InputError, match="person_prob"):
        config_from_dict({"distractors": {"person_prob": 1.5}})
    with pytest.raises(InputError, match="person_distance_m"):
        config_from_dict({"distractors": {"person_distance_m": [-0.5, 1.0]}})


def test_the_rendered_person_grips_the_moving_hand_and_is_not_the_robot():
    """With `person_prob` 1 in a fixed-camera sequence the person stands at one anchor, the
    hand's shape sits at the grip carried by the last keypoint link in every frame, the image
    shows the person, and neither the robot mask nor the labels change."""
    values = {"distractors": {"count": [0, 0], "person_prob": 1.0},
              "camera": {"radius_m": [2.0, 2.2]}, "intrinsics": FIXED,
              "sequence": {"mode": "fixed_camera"}}
    robot = load_robot("panda")
    maker = FrameMaker(robot, config_from_dict(values), seed=4)
    plain = FrameMaker(robot, config_from_dict({**values, "distractors": {"count": [0, 0]}}),
                       seed=4)
    try:
        geoms = maker.scene.distractor_geom_ids[-SLOTS:]
        bodies = maker.scene.distractor_body_ids[-SLOTS:]
        anchors, seen = set(), 0
        for i in range(4):
            rendered, without = maker.make(i), plain.make(i)
            p = maker.params(i)
            anchors.add(tuple(p.scene.person.anchor_m))
            T = robot.link_poses(p.joints, p.scene.person.link)[0]
            assert np.allclose(maker.scene.model.body_pos[bodies[2]],
                               transform_points(T, p.scene.person.grip_m))
            ids = maker.renderer.render(rgb=False, segmentation=True).geom_ids
            on_person = np.isin(ids, geoms)
            seen += on_person.sum() > 0
            assert not (on_person & (rendered.link_ids > 0)).any()
            assert np.allclose(rendered.uv, without.uv, equal_nan=True)
            assert np.array_equal(rendered.T_cam_base, without.T_cam_base)
        assert seen >= 3 and len(anchors) == 1
    finally:
        maker.close()
        plain.close()


def test_drawing_the_person_leaves_its_draw_as_it_was():
    draw = person(anchor=(0.5, 0.0, 0.5))                # a low anchor the shoulder is lifted from
    before = draw.anchor_m.copy()
    T = np.eye(4)
    T[:3, 3] = [0.4, 0.0, 0.4]                           # the hand within reach
    shapes = person_shapes(draw, T)
    assert np.array_equal(draw.anchor_m, before)
    assert capsule_ends(*shapes[0][1:3], shapes[0][3])[0][2] == pytest.approx(
        MIN_SHOULDER_HEIGHT_M)
