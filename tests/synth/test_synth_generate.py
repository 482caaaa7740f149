"""`dream synth`: labels agree with renders, every robot, kill and resume, sequences."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from test_synth_scene import _write_user_robot

from dream.camera import project
from dream.cli import main
from dream.errors import InputError
from dream.io import is_temporary, read_sequence
from dream.metrics import pose_errors
from dream.robot import load_robot
from dream.transforms import transform_points
from synth.config import config_from_dict
from synth.frames import FrameMaker
from synth.generate import ADDED_CONFIG_KEYS, SynthJob, generate
from synth.render import RenderSettings, SceneRenderer
from synth.scene import SceneSettings, build_scene

MARKER_RADIUS_M = 0.012
MIN_MARKER_PIXELS = 12
CENTROID_TOLERANCE_PX = 0.5
FIXED = {"width": 320, "height": 240, "fx": 330.0, "fy": 318.0, "cx": 165.2, "cy": 116.8}


def quiet(job: SynthJob) -> dict:
    return generate(job, on_progress=lambda n: None)


@pytest.mark.parametrize("distortion", [None, [0.08, -0.04, 0.001, -0.0008, 0.0]])
def test_written_labels_lie_on_rendered_keypoint_markers(tmp_path, distortion):
    intrinsics = dict(FIXED, distortion=distortion)
    config = config_from_dict({"intrinsics": intrinsics, "camera": {"radius_m": [1.3, 1.8]}})
    out = tmp_path / "set"
    quiet(SynthJob("panda", out, 6, config, seed=11))
    seq = read_sequence(out)
    assert seq.camera.distortion == (None if distortion is None else tuple(distortion))
    robot = load_robot("panda")
    scene = build_scene(robot, SceneSettings(keypoint_markers=True,
                                             marker_radius_m=MARKER_RADIUS_M))
    options = RenderSettings(show_robot=False, show_floor=False, show_distractors=False,
                             show_markers=True)
    checked, worst = 0, 0.0
    with SceneRenderer(scene, seq.camera, options) as renderer:
        for frame in seq.frames:
            renderer.set_state(frame.joints, frame.T_cam_base_true)
            ids = renderer.render(rgb=False, segmentation=True).geom_ids
            for k, geom in enumerate(scene.marker_geom_ids):
                v, u = np.nonzero(ids == geom)
                if len(u) < MIN_MARKER_PIXELS or u.min() == 0 or v.min() == 0 or \
                        u.max() == seq.camera.width - 1 or v.max() == seq.camera.height - 1:
                    continue
                error = np.hypot(u.mean() - frame.uv_labels[k, 0], v.mean() - frame.uv_labels[k, 1])
                worst = max(worst, error)
                checked += 1
    assert checked >= 20
    assert worst < CENTROID_TOLERANCE_PX, worst


@pytest.mark.parametrize("robot", ["ur5", "xarm7"])
def test_other_builtin_robots(tmp_path, robot):
    out = tmp_path / robot
    quiet(SynthJob(robot, out, 2, config_from_dict({}), seed=1))
    seq = read_sequence(out)
    assert seq.robot == robot and len(seq) == 2
    assert seq.keypoint_names == load_robot(robot).keypoint_names
    mask = cv2.imread(str(out / "000000.seg.png"), cv2.IMREAD_UNCHANGED)
    assert mask.shape == (240, 320) and mask.max() > 0


def test_user_urdf(tmp_path):
    urdf = _write_user_robot(tmp_path)
    out = tmp_path / "user"
    quiet(SynthJob(str(urdf), out, 2, config_from_dict({}), seed=2, keypoints=("base", "tip")))
    doc = json.loads((out / "000001.json").read_text())
    assert [k["name"] for k in doc["objects"][0]["keypoints"]] == ["base", "tip"]
    assert all({"in_frame", "occlusion", "projected_location"} <= set(k)
               for k in doc["objects"][0]["keypoints"])


def _synth_cmd(out: Path, workers: int) -> list[str]:
    return [sys.executable, "-m", "dream.cli", "synth", "--robot", "panda", "--num", "40",
            "--out", str(out), "--seed", "7", "--workers", str(workers)]


def _same_dataset(a: Path, b: Path) -> None:
    names_a = sorted(p.name for p in a.iterdir())
    assert names_a == sorted(p.name for p in b.iterdir())
    for name in names_a:
        if name.endswith(".json"):
            assert json.loads((a / name).read_text()) == json.loads((b / name).read_text()), name
        else:
            ia = cv2.imread(str(a / name), cv2.IMREAD_UNCHANGED)
            ib = cv2.imread(str(b / name), cv2.IMREAD_UNCHANGED)
            assert np.array_equal(ia, ib), name


@pytest.mark.slow
def test_killed_run_resumes_to_the_uninterrupted_result(tmp_path):
    killed, whole = tmp_path / "killed", tmp_path / "whole"
    proc = subprocess.Popen(_synth_cmd(killed, 2), start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if len(list(killed.glob("*.json"))) >= 10:  # settings + camera + 8 frames
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    frames_before = len(list(killed.glob("[0-9]*.json")))
    assert 1 <= frames_before < 40, frames_before
    subprocess.run(_synth_cmd(killed, 1), check=True, capture_output=True)
    subprocess.run(_synth_cmd(whole, 1), check=True, capture_output=True)
    assert not [p for p in killed.iterdir() if is_temporary(p)]
    _same_dataset(killed, whole)


def test_resume_with_other_settings_is_refused(tmp_path, capsys):
    out = tmp_path / "set"
    quiet(SynthJob("panda", out, 2, config_from_dict({}), seed=1))
    with pytest.raises(InputError, match="other settings"):
        quiet(SynthJob("panda", out, 2, config_from_dict({}), seed=2))
    code = main(["synth", "--robot", "panda", "--num", "2", "--out", str(out), "--seed", "3"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "other settings" in err


def test_rendered_sequence_calibrates_back_to_its_camera(tmp_path, capsys):
    config = config_from_dict({"intrinsics": FIXED, "sequence": {"mode": "trajectory",
                                                                 "fps": 10.0}})
    out = tmp_path / "seq"
    quiet(SynthJob("panda", out, 20, config, seed=5))
    seq = read_sequence(out)
    stamps = [f.timestamp for f in seq.frames]
    assert np.allclose(np.diff(stamps), 0.1)
    truth = seq.frames[0].T_cam_base_true
    assert all(np.array_equal(f.T_cam_base_true, truth) for f in seq.frames)
    assert main(["calibrate", "--data", str(out), "--use-labels", "--out",
                 str(tmp_path / "r.json")]) == 0
    T = np.array(json.loads((tmp_path / "r.json").read_text())["T_cam_base"])
    t_err, r_err = pose_errors(T, truth)
    assert t_err < 1e-6 and r_err < 1e-6


def test_occlusion_flags_agree_with_the_robot_mask(tmp_path):
    config = config_from_dict({"distractors": {"count": [4, 6], "occluder_prob": 0.8}})
    out = tmp_path / "occ"
    quiet(SynthJob("panda", out, 24, config, seed=4))
    seen = {"visible": [], "distractor": []}
    for i in range(24):
        doc = json.loads((out / f"{i:06d}.json").read_text())
        mask = cv2.imread(str(out / f"{i:06d}.seg.png"), cv2.IMREAD_UNCHANGED)
        for kp in doc["objects"][0]["keypoints"]:
            if kp["occlusion"] in seen:
                u, v = np.rint(kp["projected_location"]).astype(int)
                seen[kp["occlusion"]].append(mask[v, u] > 0)
    assert len(seen["distractor"]) >= 5 and len(seen["visible"]) >= 50
    assert not any(seen["distractor"])           # a distractor covers that pixel
    assert np.mean(seen["visible"]) > 0.9        # the robot is there (edges may miss)


def test_held_object_moves_with_the_hand():
    """The held object is drawn where its link is in each frame: at its offset in the link's
    frame, on the image near the projection of that point, and it is labelled as an occluder."""
    config = config_from_dict({"distractors": {"count": [0, 0], "held_prob": 1.0,
                                               "held_size_m": [0.15, 0.2]},
                               "camera": {"radius_m": [1.2, 1.4]}, "intrinsics": FIXED})
    robot = load_robot("panda")
    maker = FrameMaker(robot, config, seed=2)
    try:
        held_body = maker.scene.distractor_body_ids[-1]
        held_geom = maker.scene.distractor_geom_ids[-1]
        seen = 0
        for i in range(6):
            rendered = maker.make(i)
            p = maker.params(i)
            T_base_link = robot.link_poses(p.joints, p.scene.held.link)[0]
            centre = transform_points(T_base_link, p.scene.held.parts[0].position_m)
            assert np.allclose(maker.scene.model.body_pos[held_body], centre, atol=1e-9)
            ids = maker.renderer.render(rgb=False, segmentation=True).geom_ids
            v, u = np.nonzero(ids == held_geom)
            if len(u) < MIN_MARKER_PIXELS:
                continue
            seen += 1
            uv = project(rendered.camera, transform_points(rendered.T_cam_base, centre))
            radius_px = rendered.camera.fx * 0.2 / np.linalg.norm(
                transform_points(rendered.T_cam_base, centre))
            assert np.hypot(u.mean() - uv[0], v.mean() - uv[1]) < radius_px
        assert seen >= 4
    finally:
        maker.close()


def test_folder_of_an_earlier_version_with_a_retired_key_resumes(tmp_path):
    """`appearance.reflectance` (never read by the renderer) was removed from the recipe, and
    keys were added whose defaults render as before; a folder whose _synth.json still names the
    one and lacks the others resumes instead of being refused."""
    out = tmp_path / "old"
    quiet(SynthJob("panda", out, 1, config_from_dict({}), seed=1))
    info = json.loads((out / "_synth.json").read_text())
    info["config"]["appearance"]["reflectance"] = [0.0, 0.0]
    for section, key in ADDED_CONFIG_KEYS:
        del info["config"][section][key]
    (out / "_synth.json").write_text(json.dumps(info))
    first = (out / "000000.rgb.png").read_bytes()
    quiet(SynthJob("panda", out, 2, config_from_dict({}), seed=1))
    assert len(read_sequence(out).frames) == 2
    assert (out / "000000.rgb.png").read_bytes() == first


def test_resume_with_fewer_frames_or_a_negative_seed_is_refused(tmp_path, capsys):
    out = tmp_path / "set"
    quiet(SynthJob("panda", out, 3, config_from_dict({}), seed=1))
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(InputError, match="frames up to 000002, beyond --num 2"):
        quiet(SynthJob("panda", out, 2, config_from_dict({}), seed=1))
    assert sorted(p.name for p in out.iterdir()) == before
    # --overwrite renders the smaller set afresh
    generate(SynthJob("panda", out, 2, config_from_dict({}), seed=1), overwrite=True,
             on_progress=lambda n: None)
    assert len(read_sequence(out).frames) == 2
    code = main(["synth", "--robot", "panda", "--num", "1", "--out", str(tmp_path / "neg"),
                 "--seed", "-1"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--seed must be >= 0" in err
    assert not (tmp_path / "neg").exists()


def test_photo_backgrounds(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for i, colour in enumerate([(0, 0, 255), (0, 255, 0)]):
        cv2.imwrite(str(photos / f"p{i}.png"), np.full((60, 80, 3), colour, np.uint8))
    config = config_from_dict({"background": {"kinds": {"photo": 1.0, "noise": 0.0},
                                              "photos": str(photos), "floor_prob": 0.0},
                               "distractors": {"count": [0, 0]}})
    out = tmp_path / "bg"
    quiet(SynthJob("panda", out, 3, config, seed=0))
    for i in range(3):
        rgb = cv2.imread(str(out / f"{i:06d}.rgb.png"))
        mask = cv2.imread(str(out / f"{i:06d}.seg.png"), cv2.IMREAD_UNCHANGED)
        background = rgb[mask == 0]
        # pure red or pure green photo pixels (BGR), not a procedural pattern
        assert np.all((background == [0, 0, 255]).all(1) | (background == [0, 255, 0]).all(1))
    with pytest.raises(InputError, match="photo folder not found"):
        config = config_from_dict({"background": {"photos": str(tmp_path / "none"),
                                                  "kinds": {"photo": 1.0}}})
        quiet(SynthJob("panda", tmp_path / "x", 1, config))
    assert not (tmp_path / "x").exists()


def test_random_field_of_view_frames_solve_back_with_their_own_camera(tmp_path):
    """Each frame is written with its own focal length, read back, and its labels solve to its
    true pose with that camera."""
    config = config_from_dict({"intrinsics": {"width": 320, "height": 240,
                                              "hfov_rad": [0.8, 1.7]}})
    out = tmp_path / "fov"
    quiet(SynthJob("panda", out, 6, config, seed=9))
    seq = read_sequence(out)
    focals = {seq.frame_camera(i).fx for i in range(len(seq))}
    assert seq.has_frame_cameras and len(focals) == len(seq)
    result, metrics = tmp_path / "r.json", tmp_path / "m.json"
    assert main(["calibrate", "--data", str(out), "--use-labels", "--frames", "each",
                 "--out", str(result)]) == 0
    assert main(["eval", "--data", str(out), "--result", str(result), "--out",
                 str(metrics)]) == 0
    doc = json.loads(metrics.read_text())
    assert doc["translation_error_m"]["median"] < 1e-4
    assert doc["keypoint_l2_px"]["median"] < 1e-3


def _one_line(code: int, err: str) -> str:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def test_recipe_errors_are_found_before_anything_is_written(tmp_path, capsys):
    """A bad fixed camera, an image too large for the renderer and an undecodable background
    photo are one line naming the key or file and the fix; no output folder appears."""
    out = tmp_path / "set"
    camera = ["--set", "intrinsics.fy=300", "--set", "intrinsics.cx=160", "--set",
              "intrinsics.cy=120"]
    photos = tmp_path / "photos"
    photos.mkdir()
    cv2.imwrite(str(photos / "good.png"), np.zeros((8, 8, 3), np.uint8))
    (photos / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(200)))
    cases = [(["--set", "intrinsics.fx=-5", *camera], "intrinsics.fx must be a focal length > 0",
              "Fix: set intrinsics.fx"),
             (["--set", "intrinsics.width=20000"], "intrinsics.width must be a whole number",
              "Fix: set intrinsics.width between 1 and 4096"),
             (["--set", f"background.photos={photos}", "--set", "background.kinds={photo: 1.0}"],
              f"{photos / 'corrupt.png'}: unreadable background photo", "Fix: remove it")]
    for args, problem, fix in cases:
        line = _one_line(main(["synth", "--robot", "panda", "--num", "2", "--out", str(out),
                               *args]), capsys.readouterr().err)
        assert problem in line and fix in line
        assert not out.exists()


def test_output_path_that_is_a_file_or_under_one_is_refused(tmp_path, capsys):
    from synth.demo import render_demo_scene

    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    for out, words in [(afile, "the output path is a file"),
                       (afile / "s", f"the output folder cannot be made: {afile} is a file")]:
        with pytest.raises(InputError, match=words):
            quiet(SynthJob("panda", out, 2, config_from_dict({})))
        line = _one_line(main(["synth", "--robot", "panda", "--num", "2", "--out", str(out)]),
                         capsys.readouterr().err)
        assert line.startswith(f"dream synth: error: {out}: ") and words in line
    with pytest.raises(InputError, match=f"{afile / 'scene'}: the output folder cannot be made"):
        render_demo_scene(afile / "scene", num_frames=1)
    assert afile.read_text() == "not a folder" and list(tmp_path.iterdir()) == [afile]


def test_failed_render_leaves_no_metadata_only_folder(tmp_path, monkeypatch):
    """A run whose first frame fails removes what it wrote and the folders it made; an empty
    folder given to it stays; a resumed folder keeps its frames."""
    config = config_from_dict({})

    def fail(self, index):
        raise InputError(f"frame {index} cannot be rendered")

    resumed = tmp_path / "resumed"
    quiet(SynthJob("panda", resumed, 2, config, seed=1))
    before = sorted(p.name for p in resumed.iterdir())
    monkeypatch.setattr(FrameMaker, "make", fail)
    fresh = tmp_path / "new" / "set"
    with pytest.raises(InputError, match="frame 0 cannot be rendered"):
        quiet(SynthJob("panda", fresh, 2, config, seed=1))
    assert not (tmp_path / "new").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="frame 0 cannot be rendered"):
        quiet(SynthJob("panda", empty, 2, config, seed=1))
    assert list(empty.iterdir()) == []
    with pytest.raises(InputError, match="frame 2 cannot be rendered"):
        quiet(SynthJob("panda", resumed, 3, config, seed=1))
    assert sorted(p.name for p in resumed.iterdir()) == before


def test_progress_is_shown_by_the_command_not_the_library(tmp_path, capsys):
    generate(SynthJob("panda", tmp_path / "lib", 1, config_from_dict({})))
    assert capsys.readouterr().err == ""
    assert main(["synth", "--robot", "panda", "--num", "1", "--out", str(tmp_path / "cli")]) == 0
    assert "synth: 1/1 frames" in capsys.readouterr().err


def test_fixed_camera_sequence_with_a_random_field_of_view_names_its_one_camera(tmp_path):
    """In the sequence modes the field of view is drawn once: `_camera_settings.json` gives that
    camera, and no frame carries other intrinsics."""
    out = tmp_path / "fixed"
    quiet(SynthJob("panda", out, 3, config_from_dict({"sequence": {"mode": "fixed_camera"}}),
                   seed=4))
    seq = read_sequence(out)
    settings = json.loads((out / "_camera_settings.json").read_text())
    fx = settings["camera_settings"][0]["intrinsic_settings"]["fx"]
    assert seq.camera.fx == pytest.approx(fx)
    assert all(f.camera is None or f.camera == seq.camera for f in seq.frames)
    for f in seq.frames:
        uv = project(seq.camera, f.P_cam_labels)
        assert np.allclose(uv, f.uv_labels, atol=1e-6)


def test_workers_are_capped_at_the_frames_and_cores(tmp_path, capsys):
    from synth.generate import worker_count

    assert worker_count(64, 1, cores=2) == 1
    assert worker_count(64, 100, cores=2) == 2
    assert worker_count(3, 100, cores=16) == 3
    code = main(["synth", "--robot", "panda", "--num", "1", "--workers", "64", "--out",
                 str(tmp_path / "one")])
    assert code == 0 and "1 rendering processes instead of --workers 64" in \
        capsys.readouterr().err


def test_a_sensor_s_exposure_and_noise_change_each_frame_alone():
    """`sensor.gain_sigma` and `noise_std`: each frame of a fixed-camera sequence is the frame
    without them as `sensor_effects` writes it, its own gain and noise, and the rest of the
    draw (labels, joints) is unchanged."""
    from synth.realism import sensor_effects

    robot = load_robot("panda")
    plain = config_from_dict({"intrinsics": FIXED, "sequence": {"mode": "fixed_camera"}})
    real = config_from_dict({"intrinsics": FIXED, "sequence": {"mode": "fixed_camera"},
                             "sensor": {"gain_sigma": 0.2, "noise_std": 2.0}})
    frames = {}
    for name, config in (("plain", plain), ("real", real)):
        maker = FrameMaker(robot, config, seed=3)
        try:
            frames[name] = [maker.make(i) for i in range(3)]
        finally:
            maker.close()
    ratios = []
    for i, (a, b) in enumerate(zip(frames["plain"], frames["real"], strict=True)):
        assert np.array_equal(sensor_effects(a.rgb, 3, i, real), b.rgb)
        assert np.array_equal(a.uv, b.uv, equal_nan=True)
        assert np.array_equal(a.joints, b.joints)
        ratios.append(float(np.median(b.rgb[a.rgb > 20] / a.rgb[a.rgb > 20])))
    assert len({round(r, 2) for r in ratios}) == 3          # a gain of its own in each frame
