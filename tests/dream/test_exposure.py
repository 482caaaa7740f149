"""The exposure match (`dream.edges.exposure`) and what it does for the motion masks and the
edge alignment's background model of a camera on automatic exposure; block compression
(`dream.edges.compression`) and the motion masks of a JPEG recording."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dream.edges.background import background_model, matched_frames
from dream.edges.compression import block_step_ratio
from dream.edges.exposure import ExposureSettings, exposure_gain, matched_exposure
from dream.edges.motion import (
    MotionSettings,
    background_rgb,
    motion_masks,
    recording_settings,
)
from dream.edges.settings import EdgeSettings
from dream.errors import InputError

SIZE = (60, 80)
SENSOR_NOISE = 2.0                            # grey levels
ARM = (slice(21, 39), slice(25, 45))         # 360 of the 4800 pixels, its sides off the 8-px grid


def scene(seed: int = 0) -> np.ndarray:
    """(H, W, 3) uint8: a cluttered scene of mid to bright levels (a lit wall and shelves)."""
    rng = np.random.default_rng(seed)
    coarse = rng.uniform(60, 220, (6, 8, 3))
    return np.kron(coarse, np.ones((10, 10, 1))).astype(np.uint8)


def arm_at(shift: int = 0) -> np.ndarray:
    """(H, W) bool: the arm's patch moved `shift` pixels to the right."""
    mask = np.zeros(SIZE, bool)
    mask[ARM[0], ARM[1].start + shift:ARM[1].stop + shift] = True
    return mask


def with_arm(background: np.ndarray, gain: float, shift: int = 0, colour: int = 30
             ) -> np.ndarray:
    """The scene at exposure `gain` with a dark arm at `arm_at(shift)`."""
    frame = np.clip(np.rint(background * gain), 0, 255).astype(np.uint8)
    frame[arm_at(shift)] = colour
    return frame


@pytest.mark.parametrize("gain", [0.7, 0.9, 1.15, 1.3])
def test_a_frame_s_gain_is_found_beside_the_arm(gain):
    background = scene()
    frame = with_arm(background, gain)
    found = exposure_gain(frame / 255.0, background / 255.0)
    assert found == pytest.approx(gain, rel=0.01)
    matched = matched_exposure(frame / 255.0, background / 255.0)
    outside = np.ones(SIZE, bool)
    outside[ARM] = False
    unsaturated = (background * gain < 250).all(axis=2) & outside
    assert np.abs(matched[unsaturated] * 255 - background[unsaturated]).max() < 1.5


def test_a_fixed_exposure_is_left_exactly_as_read():
    background = scene()
    frame = with_arm(background, 1.0)
    assert exposure_gain(frame / 255.0, background / 255.0) == 1.0
    assert exposure_gain(frame / 255.0 * 1.03, background / 255.0) == 1.0     # the dead band
    image = frame / 255.0
    assert np.array_equal(matched_exposure(image, background / 255.0), image.astype(np.float32))


def test_an_arm_filling_most_of_the_view_leaves_the_gain_at_one():
    background = scene()
    rng = np.random.default_rng(1)
    frame = np.clip(np.rint(background * 1.2), 0, 255).astype(np.uint8)
    frame[:, 20:] = rng.integers(40, 250, (SIZE[0], SIZE[1] - 20, 3))   # 75 % arm, any colour
    # the 25 % of the pixels that show the scene cannot outvote an arm of any colour
    assert exposure_gain(frame / 255.0, background / 255.0) == 1.0


def test_images_of_other_shapes_are_refused():
    with pytest.raises(InputError, match="share one shape"):
        exposure_gain(np.zeros((4, 4)), np.zeros((4, 5)))
    with pytest.raises(InputError, match="min_level < max_level"):
        ExposureSettings(min_level=0.5, max_level=0.4)


def test_motion_masks_of_a_camera_on_automatic_exposure_are_those_of_a_fixed_one():
    background = scene()
    gains = [1.0, 1.25, 0.8, 1.1, 0.9, 1.0, 1.2, 0.85, 1.0]
    shifts = [7 * k - 21 for k in range(len(gains))]
    fixed = np.stack([with_arm(background, 1.0, s) for s in shifts])
    auto = np.stack([with_arm(background, g, s) for g, s in zip(gains, shifts, strict=True)])
    settings = MotionSettings()
    expected = motion_masks(fixed, background_rgb(fixed, settings), settings)
    masks = motion_masks(auto, background_rgb(auto, settings), settings)
    assert expected.sum(axis=(1, 2)).min() >= 300             # the arm, 360 pixels
    assert (masks != expected).sum(axis=(1, 2)).max() <= 20
    unmatched = MotionSettings(exposure=None)
    flooded = motion_masks(auto, background_rgb(auto, unmatched), unmatched)
    assert flooded[1].sum() > 3 * expected[1].sum()           # what the match prevents


def test_grey_frames_are_matched_to_the_edge_background_model():
    grey = (scene()[..., 0] / 255.0).astype(np.float32)
    gains = [1.0, 1.3, 0.8, 1.25, 1.2, 0.9, 1.3]
    frames = np.stack([grey * g for g in gains]).astype(np.float32)
    arm = np.stack([arm_at(7 * k - 21) for k in range(len(frames))])
    frames[arm] = 0.1
    model = background_model(frames, EdgeSettings())       # the scene at the median exposure
    matched = matched_frames(frames, model, ExposureSettings())
    differs = np.abs(matched - model[None]) >= EdgeSettings().motion_threshold
    assert (differs & ~arm).sum() <= 0.01 * (~arm).sum()
    assert (np.abs(frames - model[None]) >= 0.05)[1][~arm[1]].mean() > 0.5   # unmatched
    assert matched_frames(frames, model, None) is frames


def jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
    ok, data = cv2.imencode(".jpg", rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1]


def wall() -> np.ndarray:
    """(H, W, 3) uint8: a smoothly lit wall, as much of a real scene is."""
    y, x = np.mgrid[0:SIZE[0], 0:SIZE[1]]
    level = 90 + 1.2 * x + 0.8 * y
    return np.clip(np.stack([level, 0.9 * level, 0.8 * level], axis=2), 0, 255).astype(np.uint8)


def test_a_block_compressed_recording_is_told_from_a_lossless_one():
    background = wall()
    shifts = [6 * k - 24 for k in range(9)]
    rng = np.random.default_rng(4)                  # a sensor's noise: no two frames code alike
    lossless = np.stack([np.clip(with_arm(background, 1.0, s, colour=200)
                                 + rng.normal(0, SENSOR_NOISE, (*SIZE, 3)), 0, 255)
                         .astype(np.uint8) for s in shifts])
    compressed = np.stack([jpeg(f, 60) for f in lossless])
    settings = MotionSettings()
    for frames, expect_weak in ((lossless, settings.weak_threshold),
                                (compressed, settings.threshold)):
        model = background_rgb(frames, settings)
        ratios = [block_step_ratio(cv2.cvtColor(f, cv2.COLOR_RGB2GRAY).astype(float)
                                   - cv2.cvtColor(model, cv2.COLOR_RGB2GRAY)) for f in frames]
        chosen = recording_settings(frames, model, settings)
        assert chosen.weak_threshold == expect_weak, np.median(ratios)
    # the hysteresis off, the compressed masks lie nearer the arm
    model = background_rgb(compressed, settings)
    arm = np.stack([arm_at(s) for s in shifts])
    with_weak = motion_masks(compressed, model, settings)
    without = motion_masks(compressed, model, recording_settings(compressed, model, settings))
    assert (without & ~arm).sum() < (with_weak & ~arm).sum()
    assert (without & arm).sum() >= 0.9 * arm.sum()


def test_block_steps_need_an_image_of_two_blocks():
    with pytest.raises(InputError, match="at least 16 pixels"):
        block_step_ratio(np.zeros((8, 40)))


def test_frames_smaller_than_two_blocks_keep_the_hysteresis():
    frames = np.zeros((5, 10, 12, 3), np.uint8)
    frames[0, 2:5, 2:5] = 200
    settings = MotionSettings()
    assert recording_settings(frames, background_rgb(frames, settings), settings) == settings
