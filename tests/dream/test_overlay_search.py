"""Overlays of a pose found without keypoints: the box around something the URDF lacks, and a
summary legend that speaks of silhouettes, not of a keypoint fit."""

import numpy as np
import pytest

from dream.errors import InputError
from dream.overlay import (
    AWAY_RGB,
    BOX_EDGES,
    CARRIED_RGB,
    blank_image,
    carried_corners,
    draw_box,
    tint,
)
from dream.overlay_search import search_legend
from dream.robot.link_geometry import BOX_KIND, LinkGeometry
from dream.sample import random_joints
from dream.transforms import transform_points

BOX = {"kind": BOX_KIND, "size_m": [0.12, 0.14, 0.06], "position_m": [0.02, 0.01, 0.09],
       "rotation_rad": [0.0, 0.3, 0.0]}


def square_box_uv(lo: float, hi: float) -> np.ndarray:
    """A box seen along its z axis: corner 4x + 2y + z at (lo or hi, lo or hi)."""
    return np.array([[(lo, hi)[x], (lo, hi)[y]] for x in (0, 1) for y in (0, 1)
                     for _ in (0, 1)], dtype=float)


def magenta(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels drawn in the box's colour (anti-aliased: at least half of it)."""
    return np.all(np.abs(image.astype(int) - CARRIED_RGB) < 128, axis=-1)


def test_a_box_has_twelve_edges_each_between_corners_one_side_apart():
    assert len(BOX_EDGES) == 12 and len(set(BOX_EDGES)) == 12
    for i, j in BOX_EDGES:
        assert bin(i ^ j).count("1") == 1


def test_the_box_is_drawn_along_its_edges_and_skips_corners_not_projected():
    image = blank_image(100, 100, gray=0)
    out = draw_box(image, square_box_uv(20.0, 80.0))
    is_box = magenta(out)
    assert is_box[20, 50] and is_box[80, 50] and is_box[50, 20] and is_box[50, 80]
    assert not out[30:70, 30:70].any()          # nothing inside the square
    assert not image.any()                       # the input is left as it was
    uv = square_box_uv(20.0, 80.0)
    uv[[0, 1]] = np.nan                          # the corners at (20, 20) behind the camera
    out = draw_box(image, uv)
    assert not magenta(out)[20, 40:60].any()   # their edges skipped
    assert magenta(out)[80, 50]
    with pytest.raises(InputError, match="8 corners"):
        draw_box(image, uv[:4])


def test_the_carried_box_moves_with_its_link(panda):
    joints = random_joints(np.random.default_rng(0), panda, 3)
    corners = carried_corners(panda, joints, {"named": "panda_hand", "box_around_hull": BOX})
    assert corners.shape == (3, 8, 3)
    in_link, _ = LinkGeometry("panda_hand", **BOX).box_mesh()
    T_base_hand = panda.link_poses(joints, ("panda_hand",))[:, 0]
    for f in range(3):
        assert np.allclose(corners[f], transform_points(T_base_hand[f], in_link))
    assert carried_corners(panda, joints, {}) is None
    assert carried_corners(panda, joints, {"named": None, "box_around_hull": None}) is None
    assert carried_corners(panda, joints, {"named": "no_such_link",
                                            "box_around_hull": BOX}) is None


def test_the_legend_of_a_search_result_names_its_evidence_not_a_keypoint_fit():
    doc = {"start": {"evidence": "motion masks", "iou": 0.4356}, "quality": {"verdict": "check"}}
    lines = [text for text, _ in search_legend(doc, None, 34, None)]
    assert "motion masks" in lines[0] and "IoU 0.44" in lines[0] and "check" in lines[0]
    assert "the silhouette search" in lines[1] and "34 frames" in lines[2]
    assert not any("keypoint" in line and "no keypoints" not in line for line in lines)
    carried = {"named": "panda_hand", "left_out_of_search": True}
    lines = [text for text, _ in search_legend(doc, "the edge alignment", 34, carried)]
    assert "the edge alignment" in lines[1]
    assert "panda_hand, left out of the search" in lines[-1]
    doc["start"]["away"] = {"share": 0.234}
    lines = search_legend(doc, None, 34, None, away=True)
    assert lines[-1] == ("orange: moving pixels away from the robot (23 % of them), not counted "
                         "as robot", AWAY_RGB)


def test_the_tint_blends_only_the_pixels_asked_for():
    image = np.full((4, 5, 3), 100, np.uint8)
    where = np.zeros((4, 5), bool)
    where[1:3, 2] = True
    out = tint(image, where)
    assert np.array_equal(out[~where], image[~where]) and not np.array_equal(out[where],
                                                                             image[where])
    assert np.all(np.abs(out[where].astype(int) - AWAY_RGB)
                  < np.abs(image[where].astype(int) - AWAY_RGB))   # nearer the tint
    assert np.array_equal(image, np.full((4, 5, 3), 100, np.uint8))  # the input untouched
    with pytest.raises(InputError, match="tint needs"):
        tint(image, where[:3])


def test_dream_overlay_draws_the_box_a_result_named(realdata, tmp_path, capsys):
    import json

    import cv2

    from dream.cli import main
    from dream.io import read_sequence

    data = realdata / "panda_teleop"
    T_ref = read_sequence(data).T_cam_base_reference
    drawn = {}
    for name, start in (("plain", None), ("box", {"carried": {"named": "panda_hand",
                                                                "box_around_hull": BOX}})):
        result = tmp_path / f"{name}.json"
        result.write_text(json.dumps({"T_cam_base": T_ref.tolist(), "per_frame": [],
                                      "start": start}))
        assert main(["overlay", str(data), "--extrinsic", str(result), "--out",
                     str(tmp_path / name), "--limit", "2"]) == 0
        image = cv2.imread(str(tmp_path / name / "000000.overlay.png"))
        drawn[name] = int(magenta(cv2.cvtColor(image, cv2.COLOR_BGR2RGB)).sum())
        printed = capsys.readouterr().out
        assert ("magenta box: something the URDF lacks moving with panda_hand" in printed) \
            == (start is not None)
    assert drawn["box"] > drawn["plain"] + 30


def test_dream_overlay_draws_a_result_at_the_joints_it_was_solved_with(realdata, tmp_path):
    """`panda_teleop` logs its joints at 5 Hz beside 30 Hz images: a result solved with the
    readings interpolated in time is drawn with them too, not with the held ones."""
    import json

    import cv2

    from dream.cli import main
    from dream.io import read_sequence

    data = realdata / "panda_teleop"
    T_ref = read_sequence(data).T_cam_base_reference
    drawn = {}
    for name, readings in (("held", None), ("interpolated", {"interpolated": True})):
        result = tmp_path / f"{name}.json"
        result.write_text(json.dumps({"T_cam_base": T_ref.tolist(), "per_frame": [],
                                      "joint_readings": readings}))
        assert main(["overlay", str(data), "--extrinsic", str(result), "--out",
                     str(tmp_path / name), "--limit", "70"]) == 0
        drawn[name] = [cv2.imread(str(tmp_path / name / f"{i:06d}.overlay.png"))
                       for i in (0, 69)]
    # frame 0: the arm at rest, the same joints either way; frame 69: 0.04 rad apart
    assert np.array_equal(drawn["held"][0], drawn["interpolated"][0])
    assert not np.array_equal(drawn["held"][1], drawn["interpolated"][1])
