"""The cable the URDF lacks (`synth.cable`): its curve, its capsules and its render."""

from __future__ import annotations

import numpy as np
import pytest

from dream.errors import InputError
from dream.robot import load_robot
from dream.transforms import R_from_quaternion_xyzw, transform_points
from synth.cable import CableDraw, cable_in_base, cable_points, cable_segments, sample_cable
from synth.config import config_from_dict
from synth.frames import FrameMaker

FIXED = {"width": 320, "height": 240, "fx": 330.0, "fy": 318.0, "cx": 165.2, "cy": 116.8}


def arc_length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


@pytest.mark.parametrize("slack", [1.0, 1.05, 1.2])
def test_a_span_passes_its_clips_and_is_slack_times_their_distance(slack):
    clips = np.array([[0.1, -0.2, 0.3], [0.6, 0.1, 0.9], [0.9, 0.4, 0.5]])
    points = cable_points(clips, slack, samples_per_span=400)
    for clip in clips:                                   # through every clip
        assert np.min(np.linalg.norm(points - clip, axis=1)) < 1e-12
    chord = np.linalg.norm(np.diff(clips, axis=0), axis=1).sum()
    assert arc_length(points) == pytest.approx(slack * chord, rel=0.01)
    assert np.all(points[:, 2] <= np.interp(points[:, 0], clips[:, 0], clips[:, 2]) + 1e-12)


def test_the_capsules_join_end_to_end_along_the_curve():
    rng = np.random.default_rng(3)
    points = cable_points(rng.uniform(0.2, 1.0, (4, 3)), 1.15)
    pieces = cable_segments(points, 17, floor_z=0.0)
    assert len(pieces) == 17
    ends = []
    for centre, quaternion_wxyz, half in pieces:
        axis = R_from_quaternion_xyzw(np.roll(quaternion_wxyz, -1))[:, 2]
        ends.append((centre - half * axis, centre + half * axis))
    assert np.allclose(ends[0][0], points[0]) and np.allclose(ends[-1][1], points[-1])
    for (_, b), (a, _) in zip(ends[:-1], ends[1:], strict=True):
        assert np.allclose(a, b)                          # each begins where the last ends
    halves = [half for _, _, half in pieces]
    spacing = arc_length(points) / 17                    # equal arcs: each chord at most one,
    assert np.all(2 * np.array(halves) <= spacing + 1e-9)
    assert np.mean(2 * np.array(halves) > 0.95 * spacing) >= 0.8   # shorter only across a clip


def test_the_cable_stays_above_the_floor():
    clips = np.array([[0.0, 0.0, 0.01], [1.0, 0.0, 0.01]])
    pieces = cable_segments(cable_points(clips, 1.3), 10, floor_z=0.01)
    assert min(centre[2] for centre, _, _ in pieces) >= 0.01 - 1e-12


def test_bad_cables_are_refused():
    with pytest.raises(InputError, match="at least two"):
        cable_points(np.zeros((1, 3)), 1.1)
    with pytest.raises(InputError, match="slack"):
        cable_points(np.zeros((2, 3)), 0.9)
    with pytest.raises(InputError, match="one \\(3,\\) clip per link"):
        CableDraw(np.zeros(3), ("a", "b"), np.zeros((1, 3)), 0.01, 1.1, np.ones(4))
    with pytest.raises(InputError, match="cable_segments"):
        config_from_dict({"distractors": {"cable_segments": 0}})
    with pytest.raises(InputError, match="cable_slack"):
        config_from_dict({"distractors": {"cable_slack": [0.8, 1.1]}})


def test_a_drawn_cable_runs_from_the_floor_along_moving_links():
    links = ("base", "l1", "l2", "l3", "l4", "l5")
    for seed in range(20):
        cable = sample_cable(np.random.default_rng(seed), links, (0.005, 0.01), (1.05, 1.1),
                             (0.03, 0.08), (0.1, 0.3))
        assert cable.links[0] == "l1" and len(cable.links) >= 2     # never the base
        assert cable.start_m[2] == cable.radius_m
        assert 0.1 <= np.hypot(*cable.start_m[:2]) <= 0.3
        offsets = np.linalg.norm(cable.clips_m, axis=1)
        assert np.all((offsets >= 0.03) & (offsets <= 0.08))


def test_the_rendered_cable_moves_with_the_arm_and_is_not_the_robot():
    """With `cable_prob` 1 its capsules sit at the clips carried by the links in every frame,
    the image shows them, and the robot mask does not hold them."""
    config = config_from_dict({"distractors": {"count": [0, 0], "cable_prob": 1.0,
                                               "cable_radius_m": [0.015, 0.015]},
                               "camera": {"radius_m": [1.2, 1.4]}, "intrinsics": FIXED})
    robot = load_robot("panda")
    maker = FrameMaker(robot, config, seed=4)
    try:
        geoms = maker.scene.distractor_geom_ids[-config.distractors.cable_segments:]
        bodies = maker.scene.distractor_body_ids[-config.distractors.cable_segments:]
        seen = 0
        for i in range(4):
            rendered = maker.make(i)
            p = maker.params(i)
            cable = p.scene.cable
            T = robot.link_poses(p.joints, cable.links)
            last_clip = transform_points(T[-1], cable.clips_m[-1])
            pieces = cable_in_base(cable, T, len(bodies))
            assert np.allclose(maker.scene.model.body_pos[bodies[-1]], pieces[-1][0])
            axis = R_from_quaternion_xyzw(np.roll(pieces[-1][1], -1))[:, 2]
            assert np.allclose(pieces[-1][0] + pieces[-1][2] * axis, last_clip)
            ids = maker.renderer.render(rgb=False, segmentation=True).geom_ids
            on_cable = np.isin(ids, geoms)
            seen += on_cable.sum() > 0
            assert not (on_cable & (rendered.link_ids > 0)).any()
        assert seen >= 3
    finally:
        maker.close()
