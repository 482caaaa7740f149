"""`dream synth --model-extension`: the rendered world is the extended one, the written data the
nominal one; labels stay on the rendered keypoints; refusals; resume checks the extension."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from dream.camera import project
from dream.cli import main
from dream.errors import InputError
from dream.extended import (
    effective_joints,
    extended_camera,
    extended_robot,
    joint_offset_vector,
    keypoint_points,
)
from dream.extension import extension_from_effects, extension_yaml
from dream.io import read_sequence
from dream.robot import load_robot
from dream.transforms import look_at, transform_points
from synth.config import config_from_dict
from synth.generate import SYNTH_INFO, SynthJob, generate
from synth.nominal import nominal_camera
from synth.render import RenderSettings, SceneRenderer
from synth.scene import SceneSettings, build_scene

MARKER_RADIUS_M = 0.012
MIN_MARKER_PIXELS = 12
CENTROID_TOLERANCE_PX = 0.5
MIN_CHECKED_MARKERS = 12
MIN_EFFECT_PX = 3.0        # the injected effects move the labels at least this much (median)
JSON_TOLERANCE = 1e-9
FIXED = {"width": 320, "height": 240, "fx": 330.0, "fy": 318.0, "cx": 165.2, "cy": 116.8}
KINEMATIC_AND_CAMERA = extension_from_effects({
    "joint_offset": {"panda_joint2": 0.04, "panda_joint4": -0.05},
    "link_length": {"panda_joint3": 0.02, "panda_joint5": -0.015},
    "intrinsics_error": {"fx": 343.0, "fy": 309.0, "cx": 168.0, "cy": 114.5},
    "lens_distortion": {"k1": -0.08}}, robot="panda")
TAU_S = 0.1                 # one frame period at FPS
FPS = 10.0
MOVE_FRAME = 3
SEQUENCE_EFFECTS = extension_from_effects({
    "keypoint_bias": {"panda_link4": [0.0, 0.02, -0.01]},
    "time_offset": {"seconds": TAU_S},
    "camera_moved": {"frame": f"{MOVE_FRAME:06d}", "translation_m": [0.01, 0.0, -0.005],
                     "rotation_rad": [0.0, 0.01, 0.0]}}, robot="panda")


def quiet(job: SynthJob) -> dict:
    return generate(job, on_progress=lambda n: None)


def test_labels_lie_on_the_rendered_extended_robot(tmp_path):
    config = config_from_dict({"intrinsics": FIXED, "camera": {"radius_m": [1.3, 1.8]},
                               "distractors": {"count": [0, 0]}})
    nominal_dir, extended_dir = tmp_path / "nominal", tmp_path / "extended"
    quiet(SynthJob("panda", nominal_dir, 5, config, seed=11))
    quiet(SynthJob("panda", extended_dir, 5, config, seed=11, extension=KINEMATIC_AND_CAMERA))
    nominal, seq = read_sequence(nominal_dir), read_sequence(extended_dir)
    assert seq.camera == nominal.camera == nominal_camera(config)    # the believed camera
    np.testing.assert_array_equal(seq.joints, nominal.joints)         # the readings
    assert (extended_dir / "_camera_settings.json").read_bytes() == \
        (nominal_dir / "_camera_settings.json").read_bytes()
    assert "camera_intrinsics" not in json.loads((extended_dir / "000000.json").read_text())
    robot = load_robot("panda")
    true_robot = extended_robot(robot, KINEMATIC_AND_CAMERA)
    camera = extended_camera(seq.camera, KINEMATIC_AND_CAMERA)
    offsets = joint_offset_vector(robot, KINEMATIC_AND_CAMERA.joint_offset_rad)
    shifts = []
    for frame in seq.frames:
        believed = project(seq.camera, transform_points(frame.T_cam_base_true,
                                                        robot.forward_kinematics(frame.joints)))
        shifts.append(np.linalg.norm(frame.uv_labels - believed, axis=-1))
    assert np.nanmedian(shifts) > MIN_EFFECT_PX
    scene = build_scene(true_robot, SceneSettings(keypoint_markers=True,
                                                  marker_radius_m=MARKER_RADIUS_M))
    options = RenderSettings(show_robot=False, show_floor=False, show_distractors=False,
                             show_markers=True)
    checked, worst = 0, 0.0
    with SceneRenderer(scene, camera, options) as renderer:
        for frame in seq.frames:
            renderer.set_state(frame.joints + offsets, frame.T_cam_base_true)
            ids = renderer.render(rgb=False, segmentation=True).geom_ids
            for k, geom in enumerate(scene.marker_geom_ids):
                v, u = np.nonzero(ids == geom)
                if len(u) < MIN_MARKER_PIXELS or u.min() == 0 or v.min() == 0 or \
                        u.max() == camera.width - 1 or v.max() == camera.height - 1:
                    continue
                error = np.hypot(u.mean() - frame.uv_labels[k, 0],
                                 v.mean() - frame.uv_labels[k, 1])
                worst = max(worst, error)
                checked += 1
    assert checked >= MIN_CHECKED_MARKERS
    assert worst < CENTROID_TOLERANCE_PX, worst


def test_time_offset_camera_move_and_keypoint_bias_in_a_trajectory(tmp_path):
    config = config_from_dict({"intrinsics": FIXED, "distractors": {"count": [0, 0]},
                               "sequence": {"mode": "trajectory", "fps": FPS}})
    nominal_dir, extended_dir = tmp_path / "nominal", tmp_path / "extended"
    n = 6
    quiet(SynthJob("panda", nominal_dir, n, config, seed=5))
    quiet(SynthJob("panda", extended_dir, n, config, seed=5, extension=SEQUENCE_EFFECTS))
    nominal, seq = read_sequence(nominal_dir), read_sequence(extended_dir)
    # the readings lag by one frame period; the arm rests at its start before t = 0
    state = nominal.joints                       # the arm's state at the image times
    np.testing.assert_allclose(seq.joints[1:], state[:-1], atol=JSON_TOLERANCE)
    np.testing.assert_allclose(seq.joints[0], state[0], atol=JSON_TOLERANCE)
    times = np.array([f.timestamp for f in seq.frames])
    recovered = effective_joints(seq.joints, times, TAU_S)
    inner = slice(1, -1)   # the resting start repeats a reading; the end is clamped
    np.testing.assert_allclose(recovered[inner], state[inner], atol=JSON_TOLERANCE)
    dT = SEQUENCE_EFFECTS.camera_moved.T_after_before
    robot = load_robot("panda")
    P_base = keypoint_points(robot, state, None, SEQUENCE_EFFECTS.keypoint_bias_m)
    for i, (a, b) in enumerate(zip(nominal.frames, seq.frames, strict=True)):
        moved = i >= MOVE_FRAME
        T = dT @ a.T_cam_base_true if moved else a.T_cam_base_true
        np.testing.assert_allclose(b.T_cam_base_true, T, atol=JSON_TOLERANCE)
        uv = project(seq.camera, transform_points(T, P_base[i]))
        np.testing.assert_allclose(b.uv_labels, uv, atol=1e-6)
        same_image = np.array_equal(cv2.imread(str(nominal_dir / f"{i:06d}.rgb.png")),
                                    cv2.imread(str(extended_dir / f"{i:06d}.rgb.png")))
        assert same_image != moved, i   # time offset and bias leave the image as it was


@pytest.mark.parametrize("mode, effects, match", [
    ("random", {"time_offset": {"seconds": 0.05}}, "dream.inject"),
    ("random", {"camera_moved": {"frame": "000001", "translation_m": [0.01, 0, 0]}},
     "dream.inject"),
    ("fixed_camera", {"camera_moved": {"frame": "000009", "translation_m": [0.01, 0, 0]}},
     "000009"),
    ("fixed_camera", {"camera_moved": {"frame": "move", "translation_m": [0.01, 0, 0]}},
     "frame name"),
    ("random", {"joint_offset": {"panda_joint9": 0.01}}, "panda_joint9"),
    ("random", {"link_length": {"panda_joint2": 0.01}}, "zero origin offset"),
    ("random", {"keypoint_bias": {"panda_link1": [0, 0, 0.01]}}, "panda_link1"),
    ("random", {"lens_distortion": {"k1": -3.0}}, "distortion"),
    ("random", {"intrinsics_error": {"fx": 600, "fy": 600, "cx": 319.5, "cy": 239.5}},
     "model extension's camera on the recipe's"),       # for 640x480 images
    ("random", {"link_geometry": {"panda_hand": "exclude"}}, "cannot be rendered"),
    ("random", {"link_geometry": {"tool0": {"kind": "scale", "scale": 1.1}}}, "tool0"),
])
def test_unrenderable_extensions_are_refused_before_writing(tmp_path, mode, effects, match):
    config = config_from_dict({"intrinsics": FIXED, "sequence": {"mode": mode}})
    out = tmp_path / "out"
    with pytest.raises(InputError, match=match):
        quiet(SynthJob("panda", out, 4, config, extension=extension_from_effects(effects)))
    assert not out.exists()


def test_refusals_about_robot_and_random_intrinsics(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(InputError, match="ur5"):
        quiet(SynthJob("panda", out, 2, config_from_dict({}),
                       extension=extension_from_effects({"time_offset": {"seconds": 0.1}},
                                                        robot="ur5")))
    with pytest.raises(InputError, match="field of view"):
        quiet(SynthJob("panda", out, 2, config_from_dict({}), extension=extension_from_effects(
            {"intrinsics_error": {"fx": 300, "fy": 300, "cx": 160, "cy": 120}})))
    assert not out.exists()


def test_cli_option_and_resume_checks_the_extension(tmp_path, capsys):
    first, other = tmp_path / "a.yaml", tmp_path / "b.yaml"
    first.write_text(extension_yaml(extension_from_effects(
        {"joint_offset": {"panda_joint4": 0.03}}, robot="panda")))
    other.write_text(extension_yaml(extension_from_effects(
        {"joint_offset": {"panda_joint4": -0.03}}, robot="panda")))
    out = tmp_path / "set"
    base = ["synth", "--robot", "panda", "--num", "1", "--out", str(out), "--seed", "2",
            "--set", "distractors.count=[0,0]"]
    assert main(base + ["--model-extension", str(first)]) == 0
    info = json.loads((out / SYNTH_INFO).read_text())
    assert info["model_extension"]["effects"] == {"joint_offset": {"panda_joint4": 0.03}}
    assert main(base + ["--model-extension", str(first)]) == 0         # resumes: same settings
    assert "0 frames rendered, 1 already there" in capsys.readouterr().out
    for extra in (["--model-extension", str(other)], []):
        assert main(base + extra) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "other settings" in err
    assert main(base + ["--model-extension", str(tmp_path / "none.yaml")]) == 2
    assert "not found" in capsys.readouterr().err
    plain = SynthJob("panda", tmp_path / "x", 1, config_from_dict({}),
                     extension=extension_from_effects({}))
    assert plain.extension is None and "model_extension" not in plain.info()


def test_an_added_box_is_rendered_as_part_of_the_robot(tmp_path):
    """A plate at the hand: the same pose rendered with it shows more robot, the plate's pixels
    belong to the hand, and synth writes such frames (labels stay link origins)."""
    robot = load_robot("panda")
    plate = extension_from_effects({"link_geometry": {"panda_hand": {
        "kind": "box", "size_m": [0.3, 0.22, 0.01], "position_m": [0.0, 0.0, 0.14]}}})
    config = config_from_dict({"intrinsics": FIXED, "distractors": {"count": [0, 0]}})
    camera = nominal_camera(config)
    q = robot.rest_joints
    T_cam_base = look_at(np.array([0.9, 0.3, 1.6]), robot.forward_kinematics(q)[-1])
    robot_pixels, hand_geoms = [], None
    for geometry in ((), plate.link_geometry):
        scene = build_scene(robot, SceneSettings(), link_geometry=geometry)
        options = RenderSettings(show_floor=False, show_distractors=False)
        with SceneRenderer(scene, camera, options) as renderer:
            renderer.set_state(q, T_cam_base)
            ids = renderer.render(rgb=False, segmentation=True).geom_ids
        robot_pixels.append(int(np.isin(ids, scene.robot_geom_ids).sum()))
        hand = scene.robot_geom_ids[scene.geom_link_index[scene.robot_geom_ids]
                                    == robot.link_names.index("panda_hand") + 1]
        hand_geoms = int(np.isin(ids, hand).sum())
    gained = robot_pixels[1] - robot_pixels[0]
    assert gained > 0.1 * robot_pixels[0] and hand_geoms > gained
    quiet(SynthJob("panda", tmp_path / "out", 2, config, extension=plate))
    assert len(read_sequence(tmp_path / "out").frames) == 2
