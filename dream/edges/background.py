"""The background model of a fixed camera: what the scene looks like without the moving arm.

The arm moves between the frames and the scene does not, so the per-pixel median of many frames
(evenly spaced, `background_frames`) shows the scene behind the arm wherever the arm stays out
of a pixel in more than half of them. Links that never move (the base) stay in it: their
outline has no background on either side, so the edge alignment passes over it.

    >>> import numpy as np
    >>> frames = np.zeros((9, 4, 4)); frames[:3, 0, 0] = 1.0   # something at (0, 0) in 3 of 9
    >>> float(background_model(frames, EdgeSettings())[0, 0])
    0.0
"""

from __future__ import annotations

import cv2
import numpy as np

from dream.camera import CameraIntrinsics
from dream.edges.exposure import ExposureSettings, exposure_gain
from dream.edges.settings import EdgeSettings
from dream.errors import InputError
from dream.polish.objective import evenly_spaced
from dream.sequence import Sequence

GREY_LEVELS = 255.0   # 8-bit images are read as grey levels in [0, 1]


def grey(rgb: np.ndarray) -> np.ndarray:
    """An (H, W, 3) uint8 RGB image as (H, W) float32 grey levels in [0, 1]."""
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise InputError(f"image has shape {rgb.shape}, expected (H, W, 3)")
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / GREY_LEVELS


def load_grey(sequence: Sequence, indices: np.ndarray,
              camera: CameraIntrinsics | None = None) -> np.ndarray:
    """The grey images (n, H, W) of the frames `indices` of `sequence`."""
    from dream.io import load_image

    camera = camera or sequence.camera
    return np.stack([grey(load_image(sequence.frames[int(i)], camera)) for i in indices])


def background_model(frames: np.ndarray, settings: EdgeSettings) -> np.ndarray:
    """The per-pixel median (H, W) of grey frames (F, H, W) (module doc).

    Raises:
        InputError: fewer than `min_background_frames` frames.
    """
    frames = np.asarray(frames, dtype=np.float32)
    if frames.ndim != 3:
        raise InputError(f"frames have shape {frames.shape}, expected (F, H, W)")
    if len(frames) < settings.min_background_frames:
        raise InputError(f"{len(frames)} frames are too few for a background model (at least "
                         f"{settings.min_background_frames})")
    background = np.median(frames, axis=0)
    if settings.exposure is None:
        return background
    matched = matched_frames(frames, background, settings.exposure)
    return background if matched is frames else np.median(matched, axis=0)


def matched_frames(frames: np.ndarray, background: np.ndarray,
                   settings: ExposureSettings | None) -> np.ndarray:
    """Grey frames (F, H, W) each divided by its exposure gain over `background` (H, W)
    (`dream.edges.exposure`), float32; the same array where every gain is one (or `settings`
    is None).

    >>> frames = np.full((2, 4, 4), 0.5, np.float32); frames[1] *= 1.2
    >>> matched_frames(frames, frames[0], ExposureSettings())[1, 0, 0].round(4).item()
    0.5
    """
    if settings is None:
        return frames
    gains = np.array([exposure_gain(f, background, settings) for f in frames])
    if np.all(gains == 1.0):
        return frames
    return (np.asarray(frames, np.float32) / gains.astype(np.float32)[:, None, None])


def frames_and_background(sequence: Sequence, chosen: np.ndarray, settings: EdgeSettings,
                          camera: CameraIntrinsics | None = None
                          ) -> tuple[np.ndarray, np.ndarray | None]:
    """The grey images (n, H, W) of the frames `chosen` of a fixed-camera sequence, and its
    background model (None when it has fewer than `min_background_frames` frames); each image
    is read once."""
    background_idx = (evenly_spaced(np.arange(len(sequence)), settings.background_frames)
                      if len(sequence) >= settings.min_background_frames else np.zeros(0, int))
    needed = np.union1d(chosen, background_idx)
    images = load_grey(sequence, needed, camera)
    frames = images[np.searchsorted(needed, chosen)]
    if not len(background_idx):
        return frames, None
    background = background_model(images[np.searchsorted(needed, background_idx)], settings)
    return matched_frames(frames, background, settings.exposure), background
