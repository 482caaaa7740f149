"""The background model of a fixed camera: what the scene looks like without the moving arm.

The arm moves between the frames and the scene does not, so the per-pixel median of many frames
(evenly spaced, `background_frames`) shows the scene behind the arm wherever the arm stays out
of a pixel in more than half of them. Links that never move (the base) stay in it: their
outline has no background on either side, so the edge alignment passes over it. Where the arm
rests in one pose for most of a recording (parked before and after a motion, waiting at home),
each pose counts once (`background_indices`), so the median does not hold the arm there.

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
MEDIAN_SHARE = 0.5    # a per-pixel median holds what fills a pixel in more than half its frames
# Two frames show the same pose when no joint differs by more than this (rad, or m for a
# prismatic joint): 5 mm at a 1 m reach, as `MotionSettings.static_link_m`.
SAME_POSE = 0.005


def pose_groups(joints: np.ndarray, tolerance: float = SAME_POSE) -> np.ndarray:
    """(F,) for each frame of joints (F, J) the first frame of its pose: frames are taken in
    time order, and one whose joints differ by more than `tolerance` in some joint from every
    pose so far starts a pose of its own; the others join the first pose they match.

    >>> q = np.array([[0.0, 0.0], [0.0, 0.001], [0.3, 0.0], [0.0, 0.0], [0.3, 0.2]])
    >>> pose_groups(q).tolist()
    [0, 0, 2, 0, 4]
    """
    q = np.asarray(joints, dtype=float)
    if q.ndim != 2:
        raise InputError(f"joints have shape {q.shape}, expected (F, J)")
    if not tolerance > 0:
        raise InputError(f"the same-pose tolerance must be positive, got {tolerance}")
    firsts: list[int] = []
    groups = np.zeros(len(q), dtype=int)
    for i in range(len(q)):
        same = np.flatnonzero(np.all(np.abs(q[firsts] - q[i]) <= tolerance, axis=1))
        if len(same):
            groups[i] = firsts[same[0]]
        else:
            firsts.append(i)
            groups[i] = i
    return groups


def median_frames(joints: np.ndarray, tolerance: float = SAME_POSE) -> np.ndarray:
    """The frames (joints (F, J)) a per-pixel median of the recording draws on: all of them,
    or, where the arm rests in one pose (`pose_groups`) in more than `MEDIAN_SHARE` of them
    (parked before or after a motion: the median would hold the arm there), the first frame
    of each pose. Frames at rest in fewer are kept: they are evidence like the others (on a
    real recording the sharpest, without motion blur).

    >>> q = np.zeros((5, 2)); q[3:, 0] = [0.3, 0.6]
    >>> median_frames(q).tolist()        # at rest in 3 of 5 frames
    [0, 3, 4]
    >>> median_frames(q[2:]).tolist()    # in 1 of 3
    [0, 1, 2]
    """
    groups = pose_groups(joints, tolerance)
    if not len(groups) or np.bincount(groups).max() <= MEDIAN_SHARE * len(groups):
        return np.arange(len(groups))
    return np.unique(groups)


def background_indices(sequence: Sequence, count: int) -> np.ndarray:
    """Up to `count` frames of `sequence` for its background model, evenly spaced among its
    `median_frames` (module doc)."""
    if not len(sequence):
        return np.zeros(0, int)
    joints = np.stack([np.asarray(f.joints, float) for f in sequence.frames])
    return evenly_spaced(median_frames(joints), count)


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
    background model (None when it has fewer than `min_background_frames` frames, counted as
    `background_indices` counts them); each image is read once."""
    background_idx = background_indices(sequence, settings.background_frames)
    if len(background_idx) < settings.min_background_frames:
        background_idx = np.zeros(0, int)
    needed = np.union1d(chosen, background_idx)
    images = load_grey(sequence, needed, camera)
    frames = images[np.searchsorted(needed, chosen)]
    if not len(background_idx):
        return frames, None
    background = background_model(images[np.searchsorted(needed, background_idx)], settings)
    return matched_frames(frames, background, settings.exposure), background
