"""A frame's exposure matched to the background model's before the two are compared (pure).

A camera left on automatic exposure (most webcams and many industrial cameras are) scales
every pixel of a frame when the arm fills more or less of the view or the
light changes. A gain in linear light is the same gain on gamma-encoded values, so a frame 10 %
brighter than the background model differs from it by 20 grey levels on a white wall: more
than the motion masks' threshold, so the masks flood the bright background, and the edge
alignment's test that the background lies just outside an edge fails on every edge. Each
frame's gain (one for all channels) is estimated from the pixels where frame and background
agree (a robust start, the median of their ratios, then least squares over the pixels that
agree under it) and divided out; neither image's dark (noisy ratios) nor saturated pixels take
part. The gain is kept only where more pixels match the background closely under it than
without it (`support_tolerance`): where the arm fills much of the view, the median ratio is
the arm's, not the exposure's, and the frames of a camera of fixed exposure match best as
they are; a gain within `dead_band` of one is left as one too, so such a camera's frames are
compared unchanged.

    >>> background = np.full((4, 4), 0.5)
    >>> frame = 1.2 * background; frame[0, 0] = 0.0            # brighter, one pixel the arm
    >>> round(exposure_gain(frame, background), 6)
    1.2
    >>> float(matched_exposure(frame, background)[1, 1])
    0.5
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.errors import InputError
from dream.settings_checks import check_fields


@dataclass(frozen=True)
class ExposureSettings:
    """Every constant of the exposure match (module doc); levels in [0, 1].

    Attributes:
        agree: after the gain, a pixel within this of the background takes part in the fit
            (the motion masks' own threshold: what differs less is not motion).
        min_level, max_level: pixels darker than `min_level` or at least `max_level` in the
            background or the frame take no part (noisy ratios; saturated highlights).
        rounds: least-squares rounds after the median start.
        min_share: fewer agreeing pixels than this share of the usable ones leave the gain at
            one (the frame and the background do not show one scene).
        support_tolerance: a pixel matches the background closely within this; a gain is
            kept only where more pixels match under it than under one (5 of 255 levels: a
            static camera's noise is 1-2).
        min_support: and only where at least this share of the usable pixels match under
            it: the background must fill most of the view for its exposure to be told from
            the arm's colours (a close-up filled by a smooth arm before a smooth wall can
            match a gain of 1.5 on a third of the pixels).
        dead_band: gains within this of one are left as one: 10 of 255 levels at most, below
            the motion masks' weak threshold (13); on the 60 rendered benchmark scenes,
            whose exposure is fixed, close-ups filled by the arm gave estimates up to 3.2 %
            off one.
    """

    agree: float = 0.1
    min_level: float = 0.05
    max_level: float = 0.98
    rounds: int = 2
    min_share: float = 0.2
    support_tolerance: float = 0.02
    min_support: float = 0.5
    dead_band: float = 0.04

    def __post_init__(self) -> None:
        check_fields(self, "exposure match", positive_ints=("rounds",),
                     positive=("agree", "max_level", "support_tolerance"),
                     non_negative=("min_level", "min_share", "min_support", "dead_band"))
        if not self.min_level < self.max_level <= 1:
            raise InputError(f"exposure match: need 0 <= min_level < max_level <= 1, got "
                             f"{self.min_level} and {self.max_level}")


def exposure_gain(image: np.ndarray, background: np.ndarray,
                  settings: ExposureSettings | None = None) -> float:
    """The gain of `image` over `background` (both (H, W) or (H, W, C), levels in [0, 1];
    module doc); 1 where it cannot be told, does not match more pixels, or lies within
    `dead_band`.

    Raises:
        InputError: images of different shapes.
    """
    settings = settings or ExposureSettings()
    x, b = np.asarray(image, np.float64), np.asarray(background, np.float64)
    if x.shape != b.shape or x.ndim not in (2, 3):
        raise InputError(f"image {x.shape} and background {b.shape} must share one shape, "
                         "(H, W) or (H, W, C)")
    usable = ((b >= settings.min_level) & (b < settings.max_level) & (x >= settings.min_level)
              & (x < settings.max_level))
    if not usable.any():
        return 1.0
    x, b = x[usable], b[usable]
    gain = float(np.median(x / b))
    for _ in range(settings.rounds):
        agree = np.abs(x / gain - b) < settings.agree
        if agree.sum() < settings.min_share * len(x):
            return 1.0
        gain = float(np.dot(x[agree], b[agree]) / np.dot(b[agree], b[agree]))
    if abs(gain - 1.0) <= settings.dead_band:
        return 1.0

    def support(g: float) -> int:
        return int(np.count_nonzero(np.abs(x / g - b) < settings.support_tolerance))

    matched = support(gain)
    return gain if matched > support(1.0) and matched >= settings.min_support * len(x) else 1.0


def matched_exposure(image: np.ndarray, background: np.ndarray,
                     settings: ExposureSettings | None = None) -> np.ndarray:
    """`image` (levels in [0, 1]) divided by its `exposure_gain` over `background`, as
    float32 of the same shape."""
    image = np.asarray(image, np.float32)
    gain = exposure_gain(image, background, settings)
    return image if gain == 1.0 else image / np.float32(gain)
