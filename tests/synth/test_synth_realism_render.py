"""Randomisation aimed at real photos, rendered: a hidden hand, another robot, contact sheets."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dream.cli import main
from dream.robot import load_robot
from synth.config import config_from_dict
from synth.contact_sheet import SHEET_COLUMNS, TILE_WIDTH_PX
from synth.frames import FrameMaker, hand_geoms
from synth.other_robot import PARKED_Z_M

FIXED = {"width": 320, "height": 240, "fx": 300.0, "fy": 300.0, "cx": 159.5, "cy": 119.5}
PLAIN = {"intrinsics": FIXED, "camera": {"radius_m": [1.2, 1.4]},
         "distractors": {"count": [0, 0]}, "background": {"floor_prob": 0.0}}
MIN_PIXELS = 20


def _render(values: dict, frames: int = 4, seed: int = 3):
    robot = load_robot("panda")
    maker = FrameMaker(robot, config_from_dict({**PLAIN, **values}), seed)
    try:
        out = []
        for i in range(frames):
            rendered = maker.make(i)
            ids = maker.renderer.render(rgb=False, segmentation=True).geom_ids
            out.append((rendered, ids, maker.params(i), maker.scene.model.body_pos.copy()))
        return maker, out
    finally:
        maker.close()


def _shown_unlabelled(rendered, ids: np.ndarray, geom_ids: np.ndarray) -> bool:
    """Whether more than MIN_PIXELS of `geom_ids` are drawn; none of them labelled as the
    robot."""
    pixels = np.isin(ids, geom_ids)
    assert not rendered.link_ids[pixels].any()
    return bool(pixels.sum() > MIN_PIXELS)


def test_hidden_hand_leaves_the_mask_and_keeps_its_label():
    robot = load_robot("panda")
    hand = [robot.link_names.index(k) + 1 for k in
            ("panda_hand", "panda_leftfinger", "panda_rightfinger")]
    _, shown = _render({})
    maker, hidden = _render({"appearance": {"hide_hand_prob": 1.0}})
    assert len(hand_geoms(maker.scene)) > 0
    seen = 0
    for (a, *_), (b, *_) in zip(shown, hidden, strict=True):
        assert np.array_equal(a.uv, b.uv) and np.array_equal(a.joints, b.joints)
        assert not np.isin(b.link_ids, hand).any()
        seen += np.isin(a.link_ids, hand).sum() > MIN_PIXELS
        # the other links are drawn as before (a hand in front may have hidden some)
        others = (a.link_ids > 0) & ~np.isin(a.link_ids, hand)
        assert np.all(b.link_ids[others] == a.link_ids[others])
    assert seen >= 3


def test_other_robot_is_drawn_unlabelled_where_its_links_are():
    maker, frames = _render({"distractors": {"count": [0, 0], "robot_prob": 1.0,
                                             "robot_distance_m": [1.0, 1.2]}}, frames=6)
    other = maker.other_geoms
    seen = 0
    for rendered, ids, p, body_pos in frames:
        draw = p.scene.other_robot
        T_base_link = draw.T_base_other @ other.robot.link_poses(draw.joints, other.links)
        assert np.allclose(body_pos[other.body_ids], T_base_link[:, :3, 3], atol=1e-9)
        seen += _shown_unlabelled(rendered, ids, other.geom_ids)
    assert seen >= 3


def test_loose_parts_are_drawn_unlabelled_and_the_rest_of_the_robot_parked():
    maker, frames = _render({"distractors": {"count": [0, 0], "loose_prob": 1.0,
                                             "loose_distance_m": [0.4, 0.6]}}, frames=6)
    other = maker.other_geoms
    seen = 0
    for rendered, ids, p, body_pos in frames:
        drawn = np.isin(other.links, p.scene.other_robot.links)
        assert drawn.any() and not drawn.all()
        assert np.all(body_pos[other.body_ids[~drawn], 2] == PARKED_Z_M)
        assert np.all(body_pos[other.body_ids[drawn], 2] > PARKED_Z_M)
        seen += _shown_unlabelled(rendered, ids, other.geom_ids)
    assert seen >= 3


def test_contact_sheet_shows_the_first_frames(tmp_path):
    out, sheet = tmp_path / "set", tmp_path / "sheet.png"
    code = main(["synth", "--robot", "panda", "--num", "5", "--out", str(out),
                 "--config", "configs/synth/real_world.yaml", "--contact-sheet", str(sheet)])
    assert code == 0
    image = cv2.imread(str(sheet))
    assert image.shape == (2 * 240, SHEET_COLUMNS * TILE_WIDTH_PX, 3)
    assert image[240:, 320:].max() == 0                  # the empty tiles of the last row


def test_contact_sheet_name_is_checked_before_rendering(tmp_path, capsys):
    out = tmp_path / "set"
    code = main(["synth", "--robot", "panda", "--num", "1", "--out", str(out),
                 "--contact-sheet", str(tmp_path / "sheet.jpg")])
    assert code == 2 and ".png" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("name", ["ur5", None])
def test_other_robot_of_another_model_or_the_same(name):
    values = {"distractors": {"robot_prob": 1.0, "robot_name": name}}
    maker, frames = _render(values, frames=1)
    assert maker.other_robot.name == (name or "panda")


def test_unknown_other_robot_is_refused_before_writing(tmp_path, capsys):
    out = tmp_path / "set"
    code = main(["synth", "--robot", "panda", "--num", "1", "--out", str(out),
                 "--set", "distractors.robot_prob=0.5", "--set", "distractors.robot_name=kuka"])
    err = capsys.readouterr().err
    assert code == 2 and "unknown robot 'kuka'" in err and err.count("\n") == 1
    assert not out.exists()


def test_shadows_darken_the_floor_beside_the_robot_and_change_nothing_else():
    """With `lights.shadow_prob` 1 the first light casts the robot's shadow on the floor: some
    floor pixels darken, none brighten, the robot's pixels and labels stay; the draws (joints,
    camera) are those of the same seed without shadows."""
    floor = {"background": {"floor_prob": 1.0}, "lights": {"count": [1, 1], "ambient": [0.1, 0.1],
                                                          "elevation_rad": [1.0, 1.2]}}
    _, plain = _render(floor, frames=2)
    shaded_values = {**floor, "lights": {**floor["lights"], "shadow_prob": 1.0}}
    maker, shaded = _render(shaded_values, frames=2)
    assert all(maker.params(i).scene.shadows for i in range(2))
    for (a, *_), (b, *_) in zip(plain, shaded, strict=True):
        assert np.array_equal(a.uv, b.uv) and np.array_equal(a.joints, b.joints)
        assert np.array_equal(a.link_ids, b.link_ids)
        background = a.link_ids == 0
        change = b.rgb.astype(int).sum(axis=2) - a.rgb.astype(int).sum(axis=2)
        assert (change[background] < -30).sum() > MIN_PIXELS      # a shadow on the floor
        assert (change[background] > 3).sum() == 0                # nothing lit more
