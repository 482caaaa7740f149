"""Cast shadows in a fixed camera's frames: the pixels where the scene behind the arm is only
darker, by about one factor in every colour channel.

The arm's shadow moves with it, so against a background model it differs like the arm does
and joins the motion masks (`dream.edges.motion`): on the floor beside the base, on the table
under the hand. A surface in shadow keeps its colour and loses light: each channel of the frame
is the background's times one factor below one (the light the shadow leaves: ambient and the
other lights). The arm in front of the scene is another surface with its own colour, so its
channels' factors differ, unless it is a darker grey over a grey scene. A pixel is a shadow
where its factors lie in [`min_ratio`, `max_ratio`] and differ by at most `max_spread` of the
largest; where the background is too dark to read a factor (`min_background_level`), or too
grey to tell a shadow from a grey link (`min_background_chroma`), it is not.
A recording without colour (a monochrome camera: `colourless`) tells no shadow from a darker
link, so there none is.

    >>> background = np.zeros((1, 3, 3), np.uint8) + np.array([200, 150, 100], np.uint8)
    >>> frame = background.copy()
    >>> frame[0, 0] = (120, 90, 60)              # darker by 0.6 in every channel: a shadow
    >>> frame[0, 1] = (150, 150, 150)            # another colour: a grey link
    >>> shadow_pixels(frame, background, 1.0, ShadowSettings()).tolist()
    [[True, False, False]]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.errors import InputError
from dream.settings_checks import check_fields

COLOUR_LEVELS = 255.0     # 8-bit colour channels
GREY_SPREAD_LEVELS = 2    # a grey pixel's channels lie within this many levels (compression)
GREY_SHARE = 0.99         # a colourless image: at least this share of its pixels grey


@dataclass(frozen=True)
class ShadowSettings:
    """When a darker pixel is a shadow (module doc); set on rendered fixed-camera scenes with
    cast shadows (`lights.shadow_prob`).

    Attributes:
        min_ratio, max_ratio: the channels' factors (frame over background) of a shadow lie in
            this range: a shadow keeps some light, and takes some.
        max_spread: and differ by at most this share of the largest.
        min_background_level: a background darker than this in some channel ([0, 1]) gives no
            factor to read.
        min_background_chroma: nor one whose channels differ by less than this share of the
            largest: on a grey scene (a lab, concrete, a white table) a shadow is not told from
            a grey link in front of it. On the renders of `benchmarks/shadow_masks.py` (with
            shadows: precision 0.803 -> 0.804, recall 0.764 -> 0.773; without: recall 0.768 ->
            0.776); on `panda_teleop` (a grey lab, evaluation only) without it the test took
            2000-8500 pixels of the white and grey arm out of each frame's mask, with it 21-75.
    """

    min_ratio: float = 0.15
    max_ratio: float = 0.95
    max_spread: float = 0.12
    min_background_level: float = 0.08
    min_background_chroma: float = 0.15

    def __post_init__(self) -> None:
        check_fields(self, "shadows", positive=("min_ratio", "max_ratio", "max_spread",
                                                 "min_background_level"),
                     non_negative=("min_background_chroma",))
        if not self.min_ratio < self.max_ratio <= 1.0:
            raise InputError(f"shadows: need min_ratio < max_ratio <= 1, got {self.min_ratio} "
                             f"and {self.max_ratio}")


def shadow_pixels(frame: np.ndarray, background: np.ndarray, gain: float,
                  settings: ShadowSettings) -> np.ndarray:
    """(H, W) bool: the pixels of an RGB frame (H, W, 3; divided by its exposure `gain`) that
    are a shadow on the background (H, W, 3) (module doc; pure)."""
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape != np.shape(background) or frame.shape[2] != 3:
        raise InputError(f"frame has shape {frame.shape} and the background "
                         f"{np.shape(background)}, expected two (H, W, 3)")
    f = frame.astype(np.float32) / np.float32(gain)
    b = np.asarray(background, np.float32)
    readable = b.min(axis=2) >= settings.min_background_level * COLOUR_LEVELS
    if settings.min_background_chroma > 0:
        high_b = b.max(axis=2)
        readable &= high_b - b.min(axis=2) >= settings.min_background_chroma * high_b
    ratio = f / np.maximum(b, 1.0)
    high, low = ratio.max(axis=2), ratio.min(axis=2)
    return (readable & (high <= settings.max_ratio) & (low >= settings.min_ratio)
            & (high - low <= settings.max_spread * high))


def colourless(image: np.ndarray) -> bool:
    """Whether an RGB image (H, W, 3) has no colour: `GREY_SHARE` of its pixels grey (a
    monochrome camera's frames, or grey images stored as RGB).

    >>> grey, rgb = np.full((2, 2, 3), 90, np.uint8), np.eye(3, dtype=np.uint8)[None] * 90
    >>> colourless(grey), colourless(rgb)
    (True, False)
    """
    spread = np.ptp(np.asarray(image, np.int16), axis=2)
    return bool(np.mean(spread <= GREY_SPREAD_LEVELS) >= GREY_SHARE)
