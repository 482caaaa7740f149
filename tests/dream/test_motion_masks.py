"""Motion masks (`dream.edges.motion`), `dream masks` and `dream calibrate --polish
--motion-masks`, on images of the project's own silhouettes over a cluttered scene
(`tests/dream/test_edges.py`'s scenes)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from dream.camera import project
from dream.cli import main
from dream.edges.background import background_indices
from dream.edges.motion import (
    MotionSettings,
    background_rgb,
    check_motion,
    motion_masks,
    sequence_motion_model,
)
from dream.edges.shadow import ShadowSettings
from dream.errors import InputError
from dream.io import write_dream
from dream.metrics import pose_errors
from dream.sequence import Frame, Sequence
from dream.silhouette import render_silhouette, static_links, without_links
from dream.transforms import transform_points
from tests.dream.test_edges import CAMERA, edge_scene, image_dataset, ordered_sequence

NOISE_GREY = 6          # sensor noise of the synthetic frames, grey levels of 255


def test_motion_masks_find_the_moving_robot_and_drop_speckle(panda, meshes):
    T_true, joints, images, _ = edge_scene(panda, meshes)
    rng = np.random.default_rng(0)
    rgb = np.repeat((images * 255).astype(np.int16)[..., None], 3, axis=3)
    rgb = np.clip(rgb + rng.integers(-NOISE_GREY, NOISE_GREY + 1, rgb.shape), 0, 255)
    rgb = rgb.astype(np.uint8)
    settings = MotionSettings()
    masks = motion_masks(rgb, background_rgb(rgb, settings), settings)
    moving = without_links(meshes, static_links(meshes, joints, settings.static_link_m))
    iou, outside = [], []
    for q, mask in zip(joints, masks, strict=True):
        truth = render_silhouette(moving, q, T_true, CAMERA)
        iou.append((truth & mask).sum() / (truth | mask).sum())
        outside.append((mask & ~render_silhouette(meshes, q, T_true, CAMERA)).sum() / mask.sum())
    # the moving links, less where they stand over robot pixels of the median of 10 frames;
    # and little else (where the median holds the robot and the frame does not)
    assert np.median(iou) > 0.6 and min(iou) > 0.5
    assert np.median(outside) < 0.12


def test_a_faint_part_joins_the_mask_only_where_it_touches_a_clear_one():
    background = np.full((60, 80, 3), 100, np.uint8)
    frame = background.copy()
    frame[10:30, 10:30] = 160        # differs clearly (0.24)
    frame[30:50, 10:30] = 115        # faintly (0.06), touching the clear part: an arm's link
    frame[10:50, 55:75] = 115        # faintly, alone: a soft shadow, a change of light
    settings = MotionSettings()
    mask = motion_masks(frame[None], background, settings)[0]
    assert mask[10:50, 10:30].all() and not mask[:, 45:].any()
    without = motion_masks(frame[None], background, MotionSettings(weak_threshold=0.1))[0]
    assert without[10:30, 10:30].all() and not without[31:, :].any()


@pytest.mark.parametrize("blur_px", [0.5, 0.7, 0.9])
def test_a_blurred_edge_s_outline_lies_where_the_edge_is_not_where_its_ramp_ends(blur_px):
    """A lens's blur spreads a bright part's edge over a ramp: a fixed threshold puts the
    outline a pixel outside all round; half the local contrast puts it on the edge, and a
    sharp edge keeps the mask it had."""
    background = np.full((240, 320, 3), 60, np.uint8)
    sharp = background.copy()
    sharp[80:160, 100:220] = 220
    truth = np.zeros((240, 320), bool)
    truth[80:160, 100:220] = True
    blurred = cv2.GaussianBlur(sharp, (0, 0), blur_px)
    plain = motion_masks(blurred[None], background, MotionSettings(edge_px=0))[0]
    trimmed = motion_masks(blurred[None], background, MotionSettings())[0]
    assert np.count_nonzero(plain & ~truth) == 2 * (80 + 120)       # one pixel all round
    assert np.array_equal(trimmed, truth)
    as_it_was = motion_masks(sharp[None], background, MotionSettings(edge_px=0))[0]
    assert np.array_equal(motion_masks(sharp[None], background, MotionSettings())[0], as_it_was)


def test_background_needs_frames_and_a_moving_arm():
    settings = MotionSettings()
    with pytest.raises(InputError, match="too few for a background model"):
        background_rgb(np.zeros((3, 8, 8, 3), np.uint8), settings)
    with pytest.raises(InputError, match="hardly moves"):
        check_motion(np.zeros(10), settings, "data")
    check_motion(np.full(10, 0.1), settings, "data")
    check_motion(np.r_[np.full(5, 0.1), np.zeros(20)], settings, "data")   # 5 in view: enough
    with pytest.raises(InputError, match="only 4 of 25 frames"):
        check_motion(np.r_[np.full(4, 0.1), np.zeros(21)], settings, "data")
    with pytest.raises(InputError, match="threshold"):
        MotionSettings(threshold=0.0)
    with pytest.raises(InputError, match="weak_threshold 0.2 must not exceed"):
        MotionSettings(weak_threshold=0.2)


def test_dream_masks_writes_one_mask_per_frame(panda, meshes, tmp_path, capsys):
    image_dataset(panda, meshes, tmp_path)
    out = tmp_path / "masks"
    code = main(["masks", "--data", str(tmp_path / "data"), "--out", str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "wrote 10 motion masks" in printed
    names = sorted(p.name for p in out.iterdir())
    assert names == [f"{i:06d}.motion.png" for i in range(10)] + ["background.png"]
    mask = cv2.imread(str(out / "000000.motion.png"), cv2.IMREAD_UNCHANGED)
    assert mask.shape == (CAMERA.height, CAMERA.width) and set(np.unique(mask)) <= {0, 255}


def still_dataset(panda, meshes, folder, frames: int):
    """A DREAM-layout folder of `frames` identical images of an arm that does not move."""
    T_true, joints, images, _ = edge_scene(panda, meshes, frames=1)
    uv = project(CAMERA, transform_points(T_true, panda.forward_kinematics(joints[0])))
    rng = np.random.default_rng(1)
    src = folder / "images"
    src.mkdir(parents=True)
    out = []
    for i in range(frames):
        path = src / f"{i}.png"
        cv2.imwrite(str(path), np.repeat((images[0] * 255).astype(np.uint8)[..., None], 3, 2))
        out.append(Frame(name=f"{i:06d}", joints=joints[0], image_path=path,
                         uv_labels=uv + rng.normal(0.0, 1.0, uv.shape)))
    write_dream(Sequence(robot="panda", camera=CAMERA, joint_names=panda.joint_names,
                         keypoint_names=panda.keypoint_names, frames=tuple(out)),
                folder / "data")


@pytest.mark.parametrize("frames, message", [(12, "hardly moves"), (4, "too few")])
def test_dream_masks_refuses_a_still_or_short_recording(panda, meshes, tmp_path,
                                                        capsys, frames, message):
    still_dataset(panda, meshes, tmp_path, frames)
    out = tmp_path / "masks"
    code = main(["masks", "--data", str(tmp_path / "data"), "--out", str(out)])
    _, err = capsys.readouterr()
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_edges_of_a_still_arm_are_matched_without_a_background(panda, meshes,
                                                                tmp_path, capsys):
    """A still arm stays in the background model, so the edge alignment (the default) goes on
    without one, and --motion-masks is refused with the fix."""
    still_dataset(panda, meshes, tmp_path, 12)
    out = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--out",
                 str(out)])
    _, err = capsys.readouterr()
    assert code == 0, err
    assert json.loads(out.read_text())["edges"]["background_model"] is False
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--polish",
                 "--motion-masks", "--out", str(tmp_path / "m.json")])
    _, err = capsys.readouterr()
    assert code == 2 and "hardly moves" in err and not (tmp_path / "m.json").exists()


def test_calibrate_polishes_with_motion_masks(panda, meshes, tmp_path, capsys):
    T_true = image_dataset(panda, meshes, tmp_path)
    out = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--polish",
                 "--motion-masks", "--out", str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "motion masks" in printed and "panda_link0" in printed
    doc = json.loads(out.read_text())
    assert doc["polish"]["kept"], doc["polish"]["reason"]
    t_keypoints = pose_errors(np.array(doc["polish"]["T_cam_base_keypoints"]), T_true)[0]
    t_polished = pose_errors(np.array(doc["T_cam_base"]), T_true)[0]
    assert t_polished < 0.003 and t_polished < t_keypoints
    check = doc["silhouette_check"]            # the motion masks' own search checks the polish
    assert check["ran"] and check["evidence"] == "motion masks", check
    assert check["distance_m"] < 0.005 and "cue_disagreement_xi" in doc["uncertainty"]


@pytest.mark.parametrize("extra, message", [
    (["--motion-masks"], "--polish was not given"),
    (["--polish", "--motion-masks", "--frames", "each"], "use --frames all"),
])
def test_motion_mask_misuse_is_one_clear_error(tmp_path, capsys, extra, message):
    out = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path), "--use-labels", "--out", str(out),
                 *extra])
    _, err = capsys.readouterr()
    assert code == 2 and message in err and not out.exists()


def test_an_arm_at_rest_for_most_frames_stays_out_of_the_background(panda, meshes, tmp_path):
    """Parked in one pose for 15 of 24 frames, the arm counts once among the background model's
    frames (`background_indices`), so the model shows the scene behind it and the parked frames'
    masks show the arm; a median of all the frames would hold it."""
    T_true, joints, images, scene = edge_scene(panda, meshes, frames=10)
    order = [0] * 15 + list(range(1, 10))
    rgb = np.repeat((images * 255).astype(np.uint8)[..., None], 3, axis=3)
    seq = ordered_sequence(panda, images, joints, order, tmp_path)
    assert background_indices(seq, 60).tolist() == [0] + list(range(15, 24))
    settings = MotionSettings()
    background, settings = sequence_motion_model(seq, settings)
    parked = render_silhouette(without_links(meshes, static_links(
        meshes, joints, settings.static_link_m)), joints[0], T_true, CAMERA)
    scene_rgb = np.round(scene * 255)
    covered = np.mean([render_silhouette(meshes, q, T_true, CAMERA) for q in joints], axis=0)
    free = parked & (covered < 0.5)     # where the ten poses leave the scene in most frames
    assert free.sum() > 0.3 * parked.sum()
    assert (np.abs(background[free, 0] - scene_rgb[free]) < NOISE_GREY).mean() > 0.95
    mask = motion_masks(rgb[0][None], background, settings)[0]
    assert (mask & free).sum() / free.sum() > 0.95
    held = background_rgb(rgb[order], settings)          # every frame: the arm stays in it
    assert (motion_masks(rgb[0][None], held, settings)[0] & free).sum() < 0.05 * free.sum()


def test_a_recording_at_rest_in_fewer_poses_than_a_background_needs_is_refused(panda, meshes,
                                                                                 tmp_path):
    """At rest for 10 of 12 frames, moved to two other poses between: three poses."""
    _, joints, images, _ = edge_scene(panda, meshes, frames=3)
    seq = ordered_sequence(panda, images, joints, [0] * 5 + [1, 2] + [0] * 5, tmp_path)
    with pytest.raises(InputError, match="3 distinct poses in 12 frames"):
        sequence_motion_model(seq, MotionSettings())


def test_a_cast_shadow_is_left_out_of_the_mask_and_the_arm_beside_it_kept():
    """The scene darkened by 0.5 in every channel beside a grey link: without the shadow test
    (the default) the mask holds both, with it the link alone."""
    y, x = np.mgrid[0:60, 0:80] / 80.0
    background = np.stack([80 + 100 * x, 150 - 60 * y, 60 + 40 * (x + y)], axis=2)
    background = np.round(background).astype(np.uint8)             # a smooth coloured floor
    frame = background.copy()
    frame[10:50, 20:35] = (235, 235, 240)                         # the (white) link
    frame[30:50, 35:70] = np.round(background[30:50, 35:70] * 0.5).astype(np.uint8)
    link = np.zeros((60, 80), bool)
    link[10:50, 20:35] = True
    shadow = np.zeros((60, 80), bool)
    shadow[30:50, 35:70] = True
    kept = motion_masks(frame[None], background, MotionSettings())[0]
    assert kept[shadow].mean() > 0.95 and kept[link].mean() > 0.95
    tested = MotionSettings(shadow=ShadowSettings())
    mask = motion_masks(frame[None], background, tested)[0]
    assert mask[shadow].mean() < 0.05 and mask[link].mean() > 0.95
    grey = [np.repeat(cv2.cvtColor(a, cv2.COLOR_RGB2GRAY)[..., None], 3, 2)
            for a in (frame, background)]           # a monochrome camera: no shadow told apart
    assert motion_masks(grey[0][None], grey[1], tested)[0][shadow].mean() > 0.95
    with pytest.raises(InputError, match="min_ratio < max_ratio"):
        ShadowSettings(min_ratio=0.9, max_ratio=0.5)
