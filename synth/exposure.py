"""Motion blur: a frame as a camera exposes it while the arm moves.

A real shutter stays open for `sensor.exposure_s`; what moves in that time is smeared along its
path. In the `trajectory` sequence mode (joints a function of time) a frame at time t is the
mean, in linear light, of `sensor.exposure_samples` renders at times evenly spread over
[t - exposure_s / 2, t + exposure_s / 2]: the frame's timestamp is the middle of its exposure,
and its labels and segmentation are those at that middle.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dream.errors import InputError

SRGB_GAMMA = 2.2    # 8-bit levels to linear light and back (the display gamma, close to sRGB's)
LEVELS = 255.0


def exposure_times(timestamp: float, exposure_s: float, samples: int) -> np.ndarray:
    """(samples,) times, s, spread evenly over the exposure centred on `timestamp` (the middle
    one at `timestamp` where `samples` is odd).

    >>> exposure_times(1.0, 0.02, 3).round(3).tolist()
    [0.99, 1.0, 1.01]
    >>> exposure_times(1.0, 0.0, 1).tolist()
    [1.0]
    """
    if samples < 1 or exposure_s < 0:
        raise InputError(f"an exposure needs samples >= 1 and exposure_s >= 0, got {samples} "
                         f"and {exposure_s}", fix="set sensor.exposure_samples and "
                         "sensor.exposure_s")
    if samples == 1:
        return np.array([float(timestamp)])
    return float(timestamp) + exposure_s * (np.linspace(0.0, 1.0, samples) - 0.5)


def mean_exposure(images: Sequence[np.ndarray]) -> np.ndarray:
    """The (H, W, 3) uint8 mean of 8-bit images in linear light, as a sensor integrates light
    over its exposure.

    >>> black, white = np.zeros((1, 1, 3), np.uint8), np.full((1, 1, 3), 255, np.uint8)
    >>> int(mean_exposure([black, white])[0, 0, 0])  # half the light: brighter than level 127
    186
    >>> bool(np.all(mean_exposure([white, white]) == white))
    True
    """
    if not images:
        raise InputError("an exposure needs at least one image")
    shape = images[0].shape
    if any(image.shape != shape or image.dtype != np.uint8 for image in images):
        raise InputError("the exposure's images must be uint8 of one shape")
    linear = np.mean([(image.astype(np.float32) / LEVELS) ** SRGB_GAMMA for image in images],
                     axis=0)
    return np.clip(np.rint(LEVELS * linear ** (1.0 / SRGB_GAMMA)), 0, LEVELS).astype(np.uint8)
