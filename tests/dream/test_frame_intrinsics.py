"""Frames with their own intrinsics (`camera_intrinsics` in a DREAM frame file, written by
`dream synth` when the field of view is randomised): read, written, solved per frame, evaluated
with each frame's camera, refused for a fixed-camera solve."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from dream.camera import project
from dream.cli import main
from dream.errors import InputError
from dream.io import read_sequence, write_dream
from dream.sample import SampleSettings, make_sample

FOCALS = (300.0, 450.0, 600.0, 800.0, 1000.0, 520.0)


def frames_with_own_focal(out: Path) -> Path:
    """A keypoint-only set (exact labels) whose frames were seen with different focal lengths:
    each frame's labels are its keypoints projected with its own camera."""
    seq = make_sample(SampleSettings(num_frames=len(FOCALS), pixel_noise_px=0.0, seed=3))
    frames = []
    for frame, f in zip(seq.frames, FOCALS, strict=True):
        cam = replace(seq.camera, fx=f, fy=f)
        frames.append(replace(frame, camera=cam, uv_labels=project(cam, frame.P_cam_labels)))
    return write_dream(replace(seq, frames=tuple(frames), T_cam_base_reference=None), out)


@pytest.fixture(scope="module")
def own_focal(tmp_path_factory) -> Path:
    return frames_with_own_focal(tmp_path_factory.mktemp("own_focal") / "data")


def test_frame_intrinsics_round_trip(own_focal):
    doc = json.loads((own_focal / "000001.json").read_text())
    assert doc["camera_intrinsics"]["fx"] == FOCALS[1]
    seq = read_sequence(own_focal)
    assert seq.has_frame_cameras
    assert [seq.frame_camera(i).fx for i in range(len(seq))] == list(FOCALS)
    assert seq.frame_camera(0).width == seq.camera.width
    # --intrinsics replaces every frame's camera
    plain = read_sequence(own_focal, intrinsics=(500.0, 500.0, 319.5, 239.5))
    assert not plain.has_frame_cameras and plain.frame_camera(2).fx == 500.0


def test_each_frame_is_solved_and_evaluated_with_its_own_camera(own_focal, tmp_path, capsys):
    result, metrics = tmp_path / "r.json", tmp_path / "m.json"
    assert main(["calibrate", "--data", str(own_focal), "--use-labels", "--frames", "each",
                 "--out", str(result)]) == 0
    assert main(["eval", "--data", str(own_focal), "--result", str(result),
                 "--out", str(metrics)]) == 0
    doc = json.loads(metrics.read_text())
    assert doc["add_m"]["median"] < 1e-6 and doc["keypoint_l2_px"]["median"] < 1e-6
    assert doc["add_auc"] > 0.99
    capsys.readouterr()
    assert main(["info", str(own_focal)]) == 0
    assert "own intrinsics: fx 300.00 to 1000.00" in capsys.readouterr().out


def test_a_fixed_camera_solve_is_refused(own_focal, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["calibrate", "--data", str(own_focal), "--use-labels", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "own intrinsics" in err and "--frames each" in err and not out.exists()


@pytest.mark.parametrize(("value", "words"), [
    ({"fx": 500.0, "fy": 500.0, "cx": 319.5}, ["camera_intrinsics.cy"]),
    ({"fx": -5.0, "fy": 500.0, "cx": 319.5, "cy": 239.5}, ["camera_intrinsics", "positive"]),
    ("500", ["camera_intrinsics"]),
])
def test_bad_frame_intrinsics_name_the_file(own_focal, tmp_path, value, words):
    bad = tmp_path / "bad"
    bad.mkdir()
    for path in own_focal.iterdir():
        (bad / path.name).write_bytes(path.read_bytes())
    doc = json.loads((bad / "000002.json").read_text())
    doc["camera_intrinsics"] = value
    (bad / "000002.json").write_text(json.dumps(doc))
    with pytest.raises(InputError) as info:
        read_sequence(bad)
    message = str(info.value)
    assert "000002.json" in message and "\n" not in message
    for word in words:
        assert word in message


def test_frames_with_their_own_camera_keep_the_image_size():
    seq = make_sample(SampleSettings(num_frames=2, pixel_noise_px=0.0))
    small = replace(seq.camera, width=320, height=240)
    with pytest.raises(InputError, match="one image size"):
        replace(seq, frames=(replace(seq.frames[0], camera=small), seq.frames[1]))



def test_diagnosis_refuses_frames_with_their_own_camera(own_focal, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["diagnose", "--data", str(own_focal), "--use-labels", "--out", str(out)]) == 2
    assert "one fixed camera" in capsys.readouterr().err and not out.exists()
