"""Renders of the robot in the user's own scene: the plate is the scene behind the robot, the
renders come from the calibrated camera with that plate behind them, and a recipe that cannot
be honoured (a camera that is not rigid, a close-up of a fixed camera, a floor over the plate,
a plate of another size) stops before anything is written."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dream.errors import InputError
from dream.io import read_sequence
from dream.recipe import merge
from synth.config import config_from_dict
from synth.generate import SynthJob, generate
from tests.dream.test_edges import edge_scene, image_dataset
from train.scene_mix import (
    recording_plate,
    render_scene_mix,
    robot_coverage,
    scene_plate,
    scene_recipe,
)

GREY_TOLERANCE = 1          # the images were written as uint8 from floats in [0, 1]


def test_the_plate_is_the_background_wherever_a_frame_leaves_it_free(panda, meshes, tmp_path):
    T_true, joints, images, background = edge_scene(panda, meshes)
    image_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    frames = np.arange(len(seq))
    plate = recording_plate(seq, panda, T_true, frames)
    expected = (background * 255).astype(np.uint8)
    covered = robot_coverage(seq, panda, T_true, frames)     # the silhouettes, widened
    assert np.all(covered >= (images != background))
    free = ~np.all(covered, axis=0)                           # free in some frame
    assert free.mean() > 0.9
    assert np.abs(plate[..., 0].astype(int) - expected)[free].max() <= GREY_TOLERANCE
    # the median of all frames, a robot in most of them, would not be the background
    median = np.median(images, axis=0)
    assert np.abs(median - background).max() > 0.1


def test_scene_plate_checks_its_shapes():
    with pytest.raises(InputError, match=r"\(F, H, W, 3\) uint8 and \(F, H, W\)"):
        scene_plate(np.zeros((2, 4, 5, 3), np.uint8), np.zeros((2, 4, 4), bool))
    with pytest.raises(InputError, match="covers every pixel in every frame"):
        scene_plate(np.zeros((2, 4, 5, 3), np.uint8), np.ones((2, 4, 5), bool))


def test_pixels_no_frame_saw_free_are_inpainted_from_around_them():
    images = np.full((3, 20, 20, 3), 90, np.uint8)
    images[:, 8:12, 8:12] = 250                       # the robot, there in every frame
    covered = np.zeros((3, 20, 20), bool)
    covered[:, 8:12, 8:12] = True
    plate = scene_plate(images, covered)
    assert np.abs(plate.astype(int) - 90).max() <= 2


def test_renders_come_from_the_calibrated_camera_with_the_plate_behind(panda, meshes, tmp_path):
    T_true = image_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    out = render_scene_mix(seq, panda, "panda", T_true, np.arange(len(seq)), 3,
                           tmp_path / "scene", seed=4)
    plate = cv2.imread(str(tmp_path / "scene_plate.png"))
    rendered = read_sequence(out)
    assert rendered.camera == seq.camera and len(rendered) == 3
    for frame in rendered.frames:
        np.testing.assert_allclose(frame.T_cam_base_true, T_true, atol=1e-9)
    joints = np.stack([f.joints for f in rendered.frames])
    assert np.ptp(joints, axis=0).max() > 0.5                    # random configurations
    # with no occluders, each pixel the robot leaves free shows the plate as it is
    recipe = merge(scene_recipe(seq, T_true, tmp_path / "scene_plate.png"),
                   {"distractors": {"count": [0, 0]}})
    bare = tmp_path / "bare"
    generate(SynthJob("panda", bare, 2, config_from_dict(recipe), seed=4),
             on_progress=lambda done: None)
    for i in range(2):
        image = cv2.imread(str(bare / f"{i:06d}.rgb.png"))
        robot = cv2.imread(str(bare / f"{i:06d}.seg.png"), cv2.IMREAD_UNCHANGED) > 0
        assert 0.01 < robot.mean() < 0.9
        assert np.array_equal(image[~robot], plate[~robot])


def _recipe(tmp_path, **changes):
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 1.5]
    plate = tmp_path / "plate.png"
    cv2.imwrite(str(plate), np.zeros((240, 320, 3), np.uint8))
    recipe = {"camera": {"T_cam_base": T.tolist()},
              "intrinsics": {"width": 320, "height": 240},
              "background": {"plate": str(plate), "floor_prob": 0.0}}
    return merge(recipe, changes)


@pytest.mark.parametrize(("changes", "message"), [
    ({"camera": {"T_cam_base": (2 * np.eye(4)).tolist()}}, "not a rigid transform"),
    ({"camera": {"T_cam_base": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}}, "finite 4x4 matrix"),
    ({"camera": {"closeup_prob": 0.2}}, "cannot move it to a close-up"),
    ({"background": {"floor_prob": 0.5}}, "would draw another over it"),
])
def test_a_recipe_the_renders_cannot_honour_is_refused(tmp_path, changes, message):
    with pytest.raises(InputError, match=message):
        config_from_dict(_recipe(tmp_path, **changes))


def test_a_plate_of_another_size_stops_before_anything_is_written(tmp_path):
    config = config_from_dict(_recipe(tmp_path, intrinsics={"width": 160, "height": 120}))
    with pytest.raises(InputError, match="plate is 320x240 pixels, the images 160x120"):
        generate(SynthJob("panda", tmp_path / "out", 1, config), on_progress=lambda n: None)
    assert not (tmp_path / "out").exists()


def test_docstring_examples_run():
    import doctest

    import train.scene_mix

    assert doctest.testmod(train.scene_mix).failed == 0
