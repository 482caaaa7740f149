"""A fixed camera that moved while it recorded (`dream.steadiness`): found against an arm moving
over a textured scene, split at the move, not confused with the arm or a change of light; and
`dream calibrate` saying so, with `--frame-range` to calibrate one still stretch."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from dream.cli import main
from dream.errors import InputError
from dream.quality import CHECK, UNRELIABLE
from dream.steadiness import (
    CameraMotion,
    SteadinessSettings,
    camera_motion,
    steadiness_finding,
)

WIDTH, HEIGHT = 320, 240
FRAMES, KNOCK = 12, 6          # frames of a scene; the first frame after the camera moved
ARM_PX = (60, 140)             # the moving block standing in for the arm (width, height)


def scene(seed: int = 0, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """(FRAMES, H, W) grey frames: a textured still scene and a bright block moving over it."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.random((height, width)).astype(np.float32), (0, 0), 1.5)
    texture = 0.2 + 0.6 * (texture - texture.min()) / np.ptp(texture)
    frames = np.repeat(texture[None], FRAMES, axis=0)
    for i, x in enumerate(np.linspace(0, width - ARM_PX[0] * width // WIDTH, FRAMES)):
        frames[i, height // 4:height // 4 + ARM_PX[1] * height // HEIGHT,
               int(x):int(x) + ARM_PX[0] * width // WIDTH] = 0.9
    return frames


def knocked(frames: np.ndarray, M: np.ndarray) -> np.ndarray:
    """The frames from `KNOCK` on seen through the image move M (2, 3)."""
    out = frames.copy()
    size = frames.shape[2], frames.shape[1]
    out[KNOCK:] = [cv2.warpAffine(f, M, size, borderMode=cv2.BORDER_REPLICATE)
                   for f in frames[KNOCK:]]
    return out


def shift(dx: float, dy: float) -> np.ndarray:
    return np.float32([[1, 0, dx], [0, 1, dy]])


def test_a_steady_camera_with_an_arm_moving_is_not_called_moved():
    motion = camera_motion(scene(), np.arange(FRAMES))
    assert not motion.moved.any() and motion.judged.all()
    assert motion.stretches() == [(0, FRAMES - 1)] and motion.largest_px == 0.0
    assert steadiness_finding(motion, [f"{i:06d}" for i in range(FRAMES)]) is None


@pytest.mark.parametrize("M, corner_px", [
    (shift(1.6, -1.2), 2.0),                                             # turned a little
    (cv2.getRotationMatrix2D((WIDTH / 2, HEIGHT / 2), 1.0, 1.0), 3.5),   # rolled 1 deg
    (cv2.getRotationMatrix2D((WIDTH / 2, HEIGHT / 2), 0.0, 1.01), 2.0),  # pushed forward
])
def test_a_knocked_camera_is_found_and_split_where_it_moved(M, corner_px):
    motion = camera_motion(knocked(scene(), M), np.arange(FRAMES))
    assert motion.moved.tolist() == [i >= KNOCK for i in range(FRAMES)]
    assert motion.stretches() == [(0, KNOCK - 1), (KNOCK, FRAMES - 1)]
    assert motion.largest_px == pytest.approx(corner_px, rel=0.15)


def test_the_move_is_told_in_pixels_of_the_recordings_own_width():
    """Frames wider than `width_px` are compared shrunk; the move is reported at full size."""
    frames = knocked(scene(width=2 * WIDTH, height=2 * HEIGHT), shift(4.0, 0.0))
    motion = camera_motion(frames, np.arange(FRAMES))
    assert motion.largest_px == pytest.approx(4.0, rel=0.1)
    assert motion.move_px == pytest.approx(2.0) and motion.unreliable_px == pytest.approx(4.0)


def test_a_change_of_light_or_a_move_below_the_limit_is_not_a_move():
    darker = scene()
    darker[KNOCK:] *= 0.7
    assert not camera_motion(darker, np.arange(FRAMES)).moved.any()
    assert not camera_motion(knocked(scene(), shift(0.5, 0.0)), np.arange(FRAMES)).moved.any()


def test_the_verdict_names_the_move_the_frames_and_the_ranges_to_calibrate():
    names = [f"f{i}" for i in range(FRAMES)]
    small = camera_motion(knocked(scene(), shift(1.5, 0.0)), np.arange(FRAMES))
    level, text = steadiness_finding(small, names)
    assert level == CHECK
    assert "between frames f5 and f6" in text
    assert f"--frame-range 0:{KNOCK}, --frame-range {KNOCK}:{FRAMES}" in text
    large = camera_motion(knocked(scene(), shift(3.0, 0.0)), np.arange(FRAMES))
    assert steadiness_finding(large, names)[0] == UNRELIABLE


def test_a_camera_that_drifted_is_told_to_be_fixed_not_split():
    steps = np.linspace(0.0, 3.0, 7)[:, None, None] * np.ones((7, 4, 2))
    motion = CameraMotion(np.arange(7), steps, steps[:, 0, 0] > 0, np.ones(7, bool), 1.0, 2.0)
    assert motion.stretches() == [(0, 6)]
    level, text = steadiness_finding(motion, [str(i) for i in range(7)])
    assert level == UNRELIABLE and "drifted" in text and "--frame-range" not in text


def test_a_shaking_mount_is_told_to_be_fixed_and_its_longest_stretch_named():
    """A camera that jumps between many places: not a list of one-frame ranges, but the
    advice to fix the mount and the longest still stretch."""
    rng = np.random.default_rng(3)
    frames = scene()
    places = [0, 0, 0, 0, 0, 1, 2, 3, 4, 4, 5, 6]     # five frames still, then it shakes
    offsets = {k: rng.uniform(2.0, 4.0) * np.array([np.cos(a), np.sin(a)])
               for k, a in zip(range(1, 7), rng.uniform(0, 2 * np.pi, 6), strict=True)}
    shaken = np.stack([f if p == 0 else cv2.warpAffine(f, shift(*offsets[p]), (WIDTH, HEIGHT),
                                                       borderMode=cv2.BORDER_REPLICATE)
                       for f, p in zip(frames, places, strict=True)])
    motion = camera_motion(shaken, np.arange(FRAMES))
    level, text = steadiness_finding(motion, [str(i) for i in range(FRAMES)])
    assert level == UNRELIABLE and "shaking" in text
    assert text.count("--frame-range") == 1 and "--frame-range 0:5" in text


def test_bad_settings_and_shapes_are_refused():
    with pytest.raises(InputError, match="min_match"):
        SteadinessSettings(min_match=0.0)
    with pytest.raises(InputError, match="textured_quantile"):
        SteadinessSettings(textured_quantile=1.0)
    with pytest.raises(InputError, match="unreliable_px"):
        SteadinessSettings(move_px=3.0, unreliable_px=2.0)
    with pytest.raises(InputError, match="frames"):
        camera_motion(np.zeros((3, 8)), np.arange(3))
    assert SteadinessSettings(max_frames=5).compared(500).tolist() == [
        0, 125, 250, 374, 499]


def knocked_dataset(panda, meshes, folder, frames: int, dx_px: float):
    """`tests/dream/test_edges.py`'s image dataset with its images from the middle on shifted
    by `dx_px` (the camera turned); returns (T_true, the first shifted frame)."""
    from tests.dream.test_edges import image_dataset

    T_true = image_dataset(panda, meshes, folder, frames=frames)
    half = frames // 2
    for path in sorted((folder / "data").glob("*.rgb.png"))[half:]:
        image = cv2.imread(str(path))
        cv2.imwrite(str(path), cv2.warpAffine(image, shift(dx_px, 0.0), image.shape[1::-1],
                                              borderMode=cv2.BORDER_REPLICATE))
    return T_true, half


def test_calibrate_says_the_camera_moved_and_calibrates_one_stretch(panda, meshes, tmp_path,
                                                                     capsys):
    _, half = knocked_dataset(panda, meshes, tmp_path, 10, 3.0)
    data, out = str(tmp_path / "data"), tmp_path / "r.json"
    assert main(["calibrate", "--data", data, "--use-labels", "--refine", "none",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "steadiness: the camera moved" in printed
    doc = json.loads(out.read_text())
    assert doc["quality"]["verdict"] == UNRELIABLE
    assert any("the camera moved while it recorded" in w for w in doc["quality"]["warnings"])
    assert doc["steadiness"]["stretches"] == [["000000", f"{half - 1:06d}"],
                                              [f"{half:06d}", "000009"]]
    assert main(["calibrate", "--data", data, "--use-labels", "--refine", "none",
                 "--frame-range", f"0:{half}", "--out", str(out)]) == 0
    assert "steadiness" not in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["steadiness"]["moved"] == 0 and doc["data"]["num_frames"] == half
    assert not any("camera moved" in w for w in doc["quality"]["warnings"])


def test_a_frame_range_outside_the_recording_is_one_line_and_exit_2(panda, meshes, tmp_path,
                                                                      capsys):
    knocked_dataset(panda, meshes, tmp_path, 6, 0.0)
    for bad in ("4:2", "0:7", "a:b"):
        code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels",
                     "--frame-range", bad, "--out", str(tmp_path / "r.json")])
        err = capsys.readouterr().err
        assert code == 2 and "--frame-range" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r.json").exists()


def test_the_search_without_keypoints_says_the_camera_moved(panda, meshes, tmp_path, capsys):
    from tests.dream.test_coarse import calibrated_from_a_guess

    T_true, _ = knocked_dataset(panda, meshes, tmp_path, 8, 4.0)
    doc = calibrated_from_a_guess(T_true, tmp_path, capsys)
    assert doc["steadiness"]["moved"] > 0
    assert doc["quality"]["verdict"] == UNRELIABLE
    assert any("the camera moved while it recorded" in w for w in doc["quality"]["warnings"])
