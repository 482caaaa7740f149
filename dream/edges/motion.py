"""Motion masks of a fixed camera: the pixels where a frame differs from the scene behind the arm.

The colour background model is the per-pixel median of many frames (evenly spaced, as
`dream.edges.background`); a pixel of a frame is "moving" when one of its colour channels
differs from it by at least `threshold`, once the frame's exposure is matched to the model's
(`dream.edges.exposure`: a camera on automatic exposure) and, where `shadow` asks, it is not a
cast shadow (the scene darkened alike in every channel: `dream.edges.shadow`). An opening
removes speckle (sensor noise, compression), a closing bridges thin gaps, and blobs smaller
than `min_area_fraction` of the image go. Then hysteresis: the pixels that differ by at least
`weak_threshold` (opened and closed alike) join the mask where they connect to it, so a link
only a little unlike the scene behind it is not cut off where it touches one that differs
clearly, and faint differences alone stay out. Last, the outline is put where the frame is
halfway between the arm and the scene: a pixel within `edge_px` of the mask's border stays only
where it differs by at least `edge_fraction` of the largest difference near it, so a blurred
edge (the lens, a video codec's smoothing) does not widen the mask by the width of its ramp.
What the mask holds is the moving arm, plus what of its shadow is not told apart (a coloured
light, a shadow on a dark surface) and anything else that moved; what it misses is any part of
the arm that matches the scene behind it in colour, and the links that never move (they are in
the background model). So a motion mask suits a polish of the moving links only (`dream
calibrate --polish --motion-masks`) and inspection (`dream masks`), not the robot's full
silhouette.

    >>> import numpy as np
    >>> frames = np.zeros((9, 40, 40, 3), np.uint8)
    >>> frames[0, 10:30, 10:30] = 200                  # something in frame 0 only
    >>> masks = motion_masks(frames, background_rgb(frames, MotionSettings()), MotionSettings())
    >>> int(masks[0].sum()), int(masks[1:].sum())
    (400, 0)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from dream.edges.background import background_indices
from dream.edges.compression import BLOCK_PX, block_step_ratio
from dream.edges.exposure import ExposureSettings, exposure_gain
from dream.edges.shadow import ShadowSettings, colourless, shadow_pixels
from dream.errors import InputError
from dream.sequence import Sequence
from dream.settings_checks import check_fields

log = logging.getLogger(__name__)

COLOUR_LEVELS = 255.0     # 8-bit colour channels are compared in [0, 1]


@dataclass(frozen=True)
class MotionSettings:
    """Every constant of the motion masks (module doc); set on rendered fixed-camera scenes.

    Attributes:
        threshold: a channel must differ from the background by at least this ([0, 1]).
        weak_threshold: pixels that differ by this much join the mask where they connect to
            it (hysteresis; equal to `threshold`: none). 0.05 on `real_world.yaml` renders
            of panda, ur5 and xarm7 (seeds 1000-1004): recall of the moving links 0.88 ->
            0.89, a dark arm on a dark floor 0.64 -> 0.71, precision 0.865 -> 0.861.
        open_px, close_px: radii of the opening and the closing, pixels per 320 px of width.
        min_area_fraction: blobs smaller than this share of the image are dropped.
        edge_px, edge_fraction: the border band's radius (pixels per 320 px of width) and the
            share of the largest difference within it a pixel of the band must reach (module
            doc; `edge_px` 0: none). A fixed threshold puts a blurred edge's outline where its
            ramp falls to the threshold, outside the arm by up to the blur's width (more where
            the arm differs strongly from the scene), and the silhouettes then fit a camera
            nearer the arm; half the local contrast is the edge itself (0.4: within 1 px of a
            blurred edge the largest difference falls short of the arm's full contrast). 1 px
            and 0.4 hold the outline of a bright square blurred by up to 0.9 px exactly. Masks of
            panda, ur5 and xarm7 `real_world.yaml` renders (seeds 1000-1002) against the
            rendered robot: blurred by a Gaussian of 0.7 px (`sensor.blur_px`), precision
            0.802 -> 0.839; through VP9, 0.831 -> 0.851; as rendered, 0.862 -> 0.866 (recall
            0.004-0.005 lower in each).
        background_frames: frames whose per-pixel median is the background (evenly spaced;
            where the arm rests in one pose in most frames, each pose counts once:
            `dream.edges.background.background_indices`).
        min_background_frames: fewer frames, so counted, give no background model (an error).
            Its median holds the scene wherever the arm covers a pixel in fewer than half of
            them; 5 lets a recording of 7 photos calibrate without keypoints (renders of xarm7
            and panda at 960x540 with a second robot: 5 of 6 within 1 cm, the sixth
            `unreliable`).
        min_moving_frames: at least this many of the frames looked at must show motion (a
            mask covering `min_area_fraction` of the image) for the masks to be made: as many
            as a background model needs, and the search's 1-sigma leaves out one of five frame
            groups in turn. No share of the frames is asked for: in a close-up of the base the
            moving links pass through the view in a few frames only, and those frames' masks
            are right, while an arm at rest for most of the recording is told by its joint
            readings (`background_indices`), not by its masks.
        static_link_m: links whose vertices move less than this over the frames are in the
            background model, so not in the masks (`dream.silhouette.static_links`).
        compressed_step_ratio: a recording whose frames' differences from the background
            model step at least this much more across JPEG's block grid than elsewhere (the
            median over the background's frames; `dream.edges.compression`) is block-compressed:
            its ringing beside the arm differs from the background by more than
            `weak_threshold`, so the hysteresis is off there (`recording_settings`). Rendered
            PNG scenes 0.93-1.13 (60 benchmark scenes), JPEG at quality 75 1.29-1.73; at 95
            1.05-1.09, not told apart.
        exposure: each frame's exposure is matched to the background model's before they are
            compared, and the model's frames to their first median before the median is taken
            again (where the arm covers a pixel in some frames, the median of the others is
            at their exposure; `dream.edges.exposure`); None compares them as read.
        shadow: with settings, the pixels where the frame is the background darkened by one
            factor in every channel (the arm's cast shadow on the floor or the table,
            `dream.edges.shadow`) are left out of the masks, unless the background has no
            colour; None (the default) keeps them. On `real_world.yaml` renders of panda, ur5
            and xarm7 (seeds 1000-1004, 30 frames; `benchmarks/shadow_masks.py`) with the
            first light casting shadows, precision against the rendered robot 0.662 -> 0.804,
            recall 0.782 -> 0.773; without shadows 0.883 -> 0.882 and 0.782 -> 0.776. Not the
            default: the search from a guess on the same scenes without shadows lost one held-
            object scene to it (panda seed 1004, 6.4 -> 13.2 mm), and with shadows it gave
            the same 13 of 15 (docs/benchmarks.md).
    """

    threshold: float = 0.1
    weak_threshold: float = 0.05
    open_px: float = 1.0
    close_px: float = 2.0
    min_area_fraction: float = 0.002
    edge_px: float = 1.0
    edge_fraction: float = 0.4
    background_frames: int = 60
    min_background_frames: int = 5
    min_moving_frames: int = 5
    static_link_m: float = 0.005
    compressed_step_ratio: float = 1.2
    exposure: ExposureSettings | None = field(default_factory=ExposureSettings)
    shadow: ShadowSettings | None = None

    def __post_init__(self) -> None:
        check_fields(self, "motion masks",
                     positive_ints=("background_frames", "min_background_frames",
                                    "min_moving_frames"),
                     positive=("threshold", "weak_threshold", "static_link_m",
                               "compressed_step_ratio"),
                     non_negative=("open_px", "close_px", "min_area_fraction", "edge_px",
                                   "edge_fraction"))
        for name in ("threshold", "min_area_fraction", "edge_fraction"):
            if getattr(self, name) > 1:
                raise InputError(f"motion masks: {name} must not exceed 1, got "
                                 f"{getattr(self, name)}")
        if self.weak_threshold > self.threshold:
            raise InputError(f"motion masks: weak_threshold {self.weak_threshold} must not "
                             f"exceed threshold {self.threshold}")


def background_rgb(frames: np.ndarray, settings: MotionSettings) -> np.ndarray:
    """The per-pixel median (H, W, 3) uint8 of RGB frames (F, H, W, 3).

    Raises:
        InputError: not (F, H, W, 3), or fewer than `min_background_frames` frames.
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[3] != 3:
        raise InputError(f"frames have shape {frames.shape}, expected (F, H, W, 3)")
    if len(frames) < settings.min_background_frames:
        raise InputError(f"{len(frames)} frames are too few for a background model (at least "
                         f"{settings.min_background_frames})",
                         fix="record more frames of the fixed camera with the arm moving")
    background = np.median(frames, axis=0)
    gains = [frame_gain(f, background, settings) for f in frames]
    if all(g == 1.0 for g in gains):
        return background.astype(np.uint8)
    matched = np.stack([f if g == 1.0 else np.clip(np.rint(
        f.astype(np.float32) / np.float32(g)), 0, COLOUR_LEVELS).astype(np.uint8)
        for f, g in zip(frames, gains, strict=True)])
    return np.median(matched, axis=0).astype(np.uint8)


def frame_gain(frame: np.ndarray, background: np.ndarray, settings: MotionSettings) -> float:
    """The exposure gain an RGB frame is divided by before it is compared with the
    background (both in 0-255; `dream.edges.exposure`): 1 where none is, or where
    `settings.exposure` is None."""
    if settings.exposure is None:
        return 1.0
    return exposure_gain(np.asarray(frame, np.float32) / COLOUR_LEVELS,
                         np.asarray(background, np.float32) / COLOUR_LEVELS, settings.exposure)


def colour_difference(frame: np.ndarray, background: np.ndarray, gain: float) -> np.ndarray:
    """(H, W) the largest difference of any channel (0-255 levels) of an RGB frame divided by
    its exposure `gain` (`frame_gain`) from the background (H, W, 3)."""
    if gain == 1.0:
        return np.abs(frame.astype(np.int16) - background.astype(np.int16)).max(axis=2)
    return np.abs(frame.astype(np.float32) / np.float32(gain)
                  - background.astype(np.float32)).max(axis=2)


def disk(radius: float) -> np.ndarray | None:
    """An elliptic structuring element of `radius` pixels (rounded); None below one pixel."""
    r = int(round(radius))
    return None if r < 1 else cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)


def motion_masks(frames: np.ndarray, background: np.ndarray, settings: MotionSettings,
                 gains: list[float] | None = None) -> np.ndarray:
    """(F, H, W) bool motion masks of RGB frames (F, H, W, 3) against `background` (H, W, 3)
    (module doc; pure); `gains`: the frames' `frame_gain`s where the caller has them."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[1:] != np.shape(background):
        raise InputError(f"frames have shape {frames.shape} and the background "
                         f"{np.shape(background)}, expected (F, H, W, 3) and (H, W, 3)")
    F, H, W, _ = frames.shape
    per_width = W / 320.0
    opening, closing = disk(settings.open_px * per_width), disk(settings.close_px * per_width)
    band = disk(settings.edge_px * per_width)
    min_area = settings.min_area_fraction * H * W
    out = np.zeros((F, H, W), bool)
    shadow = settings.shadow if settings.shadow is not None and not colourless(background) \
        else None
    for f in range(F):
        gain = frame_gain(frames[f], background, settings) if gains is None else gains[f]
        diff = colour_difference(frames[f], background, gain)
        if shadow is not None:
            diff = np.where(shadow_pixels(frames[f], background, gain, shadow), 0, diff)
        strong = _cleaned(diff >= settings.threshold * COLOUR_LEVELS, opening, closing)
        count, labels, stats, _ = cv2.connectedComponentsWithStats(strong, connectivity=8)
        big = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= min_area)
        out[f] = np.isin(labels, big[big > 0])
        if settings.weak_threshold < settings.threshold and out[f].any():
            weak = _cleaned(diff >= settings.weak_threshold * COLOUR_LEVELS, opening, closing)
            _, labels = cv2.connectedComponents(weak, connectivity=8)
            joined = np.unique(labels[out[f]])
            out[f] |= np.isin(labels, joined[joined > 0])
        if band is not None and settings.edge_fraction > 0:
            out[f] = edge_trimmed(out[f], diff, band, settings.edge_fraction)
    return out


def edge_trimmed(mask: np.ndarray, diff: np.ndarray, band: np.ndarray, fraction: float
                 ) -> np.ndarray:
    """`mask` (H, W) bool without the pixels within the structuring element `band` of its
    border whose difference `diff` (H, W) is under `fraction` of the largest difference of the
    mask within `band` of them: the outline moved to where a blurred edge is half-way (pure).

        >>> diff = np.array([[0, 20, 60, 100, 100, 100, 100, 60, 20, 0]] * 3)
        >>> edge_trimmed(diff >= 20, diff, disk(1.5), 0.5)[1].astype(int)
        array([0, 0, 1, 1, 1, 1, 1, 1, 0, 0])
    """
    mask8 = mask.astype(np.uint8)
    inside = cv2.erode(mask8, band, borderType=cv2.BORDER_REPLICATE).astype(bool)
    local = cv2.dilate(np.where(mask, diff, 0).astype(np.float32), band)
    return mask & (inside | (diff >= np.float32(fraction) * local))


def _cleaned(mask: np.ndarray, opening: np.ndarray | None, closing: np.ndarray | None
             ) -> np.ndarray:
    """A bool mask as uint8, opened and then closed (either skipped where None)."""
    mask = mask.astype(np.uint8)
    if opening is not None:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, opening)
    if closing is not None:
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, closing)
    return mask


def check_motion(coverage: np.ndarray, settings: MotionSettings, what: str) -> None:
    """Refuse the masks of a recording where the arm hardly moves in view: fewer than
    `min_moving_frames` frames have at least `min_area_fraction` of their image in the mask
    (`coverage`: (F,) shares).

    Raises:
        InputError: naming `what` (the data) and the fix.
    """
    moving = np.asarray(coverage) >= settings.min_area_fraction
    if moving.sum() < settings.min_moving_frames:
        raise InputError(f"only {int(moving.sum())} of {len(moving)} frames show motion against "
                         f"the background model (at least {settings.min_moving_frames} needed): "
                         "the arm hardly moves in view", what, "record the arm moving through "
                         "the view (motion masks need a moving arm), or give robot masks")


def recording_settings(frames: np.ndarray, background: np.ndarray, settings: MotionSettings
                       ) -> MotionSettings:
    """`settings` for a recording whose RGB frames (F, H, W, 3) give `background`: without
    the hysteresis (`weak_threshold` raised to `threshold`) where the frames are
    block-compressed (`compressed_step_ratio`), else as given."""
    if settings.weak_threshold >= settings.threshold or min(background.shape[:2]) < 2 * BLOCK_PX:
        return settings
    grey_background = cv2.cvtColor(background, cv2.COLOR_RGB2GRAY).astype(np.float32)
    ratios = []
    for frame in frames:
        grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY).astype(np.float32)
        ratios.append(block_step_ratio(grey / np.float32(frame_gain(frame, background, settings))
                                       - grey_background))
    if np.median(ratios) < settings.compressed_step_ratio:
        return settings
    log.info("the frames are block-compressed (JPEG; block steps %.2f times the others): motion "
             "masks without the hysteresis", float(np.median(ratios)))
    return replace(settings, weak_threshold=settings.threshold)


def sequence_background(sequence: Sequence, settings: MotionSettings) -> np.ndarray:
    """The colour background model (H, W, 3) of a fixed-camera `sequence` (its images read at
    `background_frames` evenly spaced frames).

    Raises:
        InputError: frames without images, or too few frames (the fix in the message).
    """
    return sequence_motion_model(sequence, settings)[0]


def sequence_motion_model(sequence: Sequence, settings: MotionSettings
                          ) -> tuple[np.ndarray, MotionSettings]:
    """`sequence_background` and the `recording_settings` of the same frames.

    Raises:
        InputError: frames without images, or too few frames (the fix in the message).
    """
    from dream.io import load_image

    camera = sequence.fixed_camera("make motion masks against one background")
    missing = [f.name for f in sequence.frames if f.image_path is None]
    if missing:
        raise InputError(f"motion masks need the images, and frame {missing[0]} has none",
                         sequence.source, "add the images")
    if len(sequence) < settings.min_background_frames:
        raise InputError(f"{len(sequence)} frames are too few for a background model (at least "
                         f"{settings.min_background_frames})", sequence.source,
                         "record more frames of the fixed camera with the arm moving")
    chosen = background_indices(sequence, settings.background_frames)
    if len(chosen) < settings.min_background_frames:
        raise InputError(f"the arm hardly moves: its joint readings show {len(chosen)} distinct "
                         f"poses in {len(sequence)} frames, and a background model needs "
                         f"{settings.min_background_frames}", sequence.source,
                         "record the arm moving through the view, or give robot masks")
    frames = np.stack([load_image(sequence.frames[int(i)], camera) for i in chosen])
    background = background_rgb(frames, settings)
    return background, recording_settings(frames, background, settings)


def sequence_motion_masks(sequence: Sequence, indices: np.ndarray, settings: MotionSettings,
                          background: np.ndarray | None = None) -> np.ndarray:
    """(n, H, W) bool motion masks of the frames `indices` of a fixed-camera `sequence`
    (`background` and `settings`: its `sequence_motion_model`, made when no background is
    given), refused when the arm hardly moves in them (`check_motion`)."""
    from dream.io import load_image

    if background is None:
        background, settings = sequence_motion_model(sequence, settings)
    camera = sequence.camera
    masks = np.stack([motion_masks(load_image(sequence.frames[int(i)], camera)[None],
                                   background, settings)[0] for i in indices])
    check_motion(masks.reshape(len(masks), -1).mean(axis=1), settings, str(sequence.source))
    return masks
