"""Whether a fixed camera stayed put while it recorded: the still scene's motion in the image.

A calibration of all frames solves one extrinsic for every frame. A camera knocked while it
recorded (a bump, a kicked tripod, a clamp that slipped) breaks that: one extrinsic fits
neither the frames before nor after, and nothing else names it (the residuals grow, the verdict
blames the keypoints or the model, and a small move passes as a good fit).

The scene behind the arm does not move by itself, so its motion in the image is the camera's.
Each compared frame, its exposure matched to the first's, is set against the first: corners
tracked into it (pyramidal Lucas-Kanade, both ways) with a similarity fitted to them by RANSAC
(the still scene is the largest set of corners moving together; the arm's move each their own
way), and the image shift by phase correlation, for scenes whose corners do not track. A
fitted move is a camera pose when it displaces an image corner by more than `move_px` and the
first frame's textured pixels vote for it: a pixel votes for the hypothesis (moved back by it,
or unmoved) under which the frame differs from the first clearly less (by `noise_level`);
pixels on the arm, flat ones and texture running along the move abstain. The votes are the
guard: where the arm fills the view the fit may follow the arm, and the scene does not vote.

Every frame is then set against every pose found (a frame whose own tracks failed still shows
the pose it shares with others): moved where its pixels vote clearly for one, still where they
vote clearly against all, otherwise not judged. Still stretches split where consecutive judged
frames differ by more than `move_px`; the verdict names the ones to calibrate alone (`dream
calibrate --frame-range START:STOP`).

    >>> rng = np.random.default_rng(0)
    >>> scene = cv2.GaussianBlur(rng.random((120, 160)).astype(np.float32), (0, 0), 2.0)
    >>> knocked = np.roll(scene, (2, 3), axis=(0, 1))          # the camera turned a little
    >>> motion = camera_motion(np.stack([scene] * 3 + [knocked] * 3), np.arange(6))
    >>> motion.moved.tolist(), motion.stretches()
    ([False, False, False, True, True, True], [(0, 2), (3, 5)])
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from dream.errors import InputError
from dream.polish.objective import evenly_spaced
from dream.quality import CHECK, UNRELIABLE, Finding
from dream.settings_checks import check_fields

GREY_MAX = 255           # 8-bit grey levels for the corner tracker
IMAGE_CORNERS = 4        # a frame's displacement: the largest over its four corners
UNTOLD = -1              # a frame whose pixels tell neither a move nor none
LISTED_STRETCHES = 3     # more still stretches than this: a shaking mount, the longest named


@dataclass(frozen=True)
class SteadinessSettings:
    """Every constant of the steadiness check (module doc); pixel figures are per
    `width_px` of image width (frames wider than it are compared shrunk to it).

    Attributes:
        width_px: frames are compared at this width at most.
        max_frames: frames compared, evenly spaced over the recording.
        blur_px: Gaussian blur (sigma) before tracking and comparing (sensor noise).
        corners, corner_quality, corner_spacing_px: corners of the first frame tracked
            (OpenCV `goodFeaturesToTrack`'s count, quality level and least distance).
        window_px, levels: the tracker's window and pyramid levels.
        round_trip_px: a track is kept when tracking it back lands this near its start.
        ransac_px: a corner agrees with a similarity within this (RANSAC threshold).
        min_points: fewer kept tracks than this and the frame is not judged.
        textured_quantile, min_gradient: the first frame's pixels above this quantile of its
            gradient magnitude, and above `min_gradient` grey levels per pixel, are the
            textured ones the frames are compared on (levels in [0, 1]).
        min_level: pixels darker than this take no part in matching each frame's exposure
            to the first's (`_exposure_gain`).
        match_px, noise_level: a textured pixel matches where it differs by less than
            `match_px` pixels' worth of its gradient plus `noise_level`.
        min_votes, vote_ratio: pixels vote clearly for a hypothesis when more than
            `min_votes` of the textured ones favour it and `vote_ratio` times as many as
            favour the other (on 60 rendered fixed-camera scenes with clutter, close-ups and a
            second robot, no frame of a steady camera was called moved).
        min_match: a frame is judged only where, under the best pose, at least this share of
            the textured pixels match: frames under other light or another white balance
            (the ten photos of `franka_offline`) match nowhere, and no pose is claimed.
        max_poses: camera poses told apart at most (a camera that moved more often than this
            is judged against the first ones).
        pose_spacing: a fitted move within this many `move_px` of a pose already found is
            that pose again (a poorer fit of it), not another.
        min_moved_frames: fewer compared frames than this shown moved claim no move (in a
            smooth scene filled by the arm, two frames of a steady camera voted for a 6 px
            move); a knocked camera stays knocked, a shaking one shakes, for many frames.
        move_px: a frame moved when an image corner moves more than this (0.2 deg at 60 deg).
        unreliable_px: beyond this the verdict is `unreliable` (a panda render knocked half
            way: 1 / 2 / 4 px put the pose 9 / 18 / 46 mm off the camera before, 4 mm unknocked).
    """

    width_px: int = 320
    max_frames: int = 200
    blur_px: float = 1.0
    corners: int = 400
    corner_quality: float = 0.01
    corner_spacing_px: float = 5.0
    window_px: int = 21
    levels: int = 3
    round_trip_px: float = 0.5
    ransac_px: float = 1.0
    min_points: int = 8
    textured_quantile: float = 0.75
    min_gradient: float = 0.04
    match_px: float = 0.5
    noise_level: float = 0.02
    min_level: float = 0.05
    min_votes: float = 0.05
    vote_ratio: float = 2.0
    min_match: float = 0.3
    max_poses: int = 8
    pose_spacing: float = 2.0
    min_moved_frames: int = 3
    move_px: float = 1.0
    unreliable_px: float = 2.0

    def __post_init__(self) -> None:
        check_fields(self, "steadiness",
                     positive_ints=("width_px", "max_frames", "corners", "window_px", "levels",
                                    "min_points", "max_poses", "min_moved_frames"),
                     positive=("vote_ratio", "pose_spacing", "corner_quality",
                               "corner_spacing_px", "round_trip_px", "ransac_px",
                               "min_gradient", "match_px", "move_px", "unreliable_px"),
                     non_negative=("blur_px", "min_votes", "noise_level", "min_level"))
        for name in ("min_match", "textured_quantile"):
            if not 0 < getattr(self, name) < 1:
                raise InputError(f"steadiness parameter {name} must lie in (0, 1), got "
                                 f"{getattr(self, name)}")
        if self.unreliable_px < self.move_px:
            raise InputError(f"steadiness: unreliable_px ({self.unreliable_px}) must be at "
                             f"least move_px ({self.move_px})")

    def compared(self, count: int) -> np.ndarray:
        """The frames compared of `count`: up to `max_frames`, evenly spaced, first and last."""
        return evenly_spaced(np.arange(count), self.max_frames)


@dataclass(frozen=True)
class CameraMotion:
    """The still scene's motion over the compared frames (module doc).

    Attributes:
        indices: (n,) the compared frames' indices in the recording, in time order.
        shifts_px: (n, 4, 2) how far each image corner moved against the first compared
            frame, pixels of the full image; zero where the frame did not move (or was not
            judged).
        moved: (n,) the frames judged moved. judged: (n,) the frames whose pixels told moved
            or still (module doc).
        move_px, unreliable_px: the settings' limits in pixels of the full image.
    """

    indices: np.ndarray
    shifts_px: np.ndarray
    moved: np.ndarray
    judged: np.ndarray
    move_px: float
    unreliable_px: float

    def __post_init__(self) -> None:
        n = len(self.indices)
        if self.shifts_px.shape != (n, IMAGE_CORNERS, 2) or self.moved.shape != (n,) \
                or self.judged.shape != (n,):
            raise InputError(f"camera motion: shifts {self.shifts_px.shape}, moved "
                             f"{self.moved.shape} and judged {self.judged.shape} must match "
                             f"{n} frames")

    def steps(self) -> tuple[np.ndarray, np.ndarray]:
        """How far the image moved between consecutive judged frames: (m - 1,) pixels, and
        (m - 1, 2) the recording indices of each pair."""
        shifts, indices = self.shifts_px[self.judged], self.indices[self.judged]
        sizes = np.linalg.norm(np.diff(shifts, axis=0), axis=2).max(axis=1, initial=0.0)
        return sizes, np.stack([indices[:-1], indices[1:]], axis=1)

    @property
    def largest_px(self) -> float:
        """The largest move of an image corner between any two judged frames (px)."""
        shifts = self.shifts_px[self.judged]
        if not len(shifts):
            return 0.0
        spread = shifts[:, None] - shifts[None, :]
        return float(np.linalg.norm(spread, axis=3).max())

    def stretches(self) -> list[tuple[int, int]]:
        """The still stretches: (first, last) recording indices of runs of judged frames
        with no step above `move_px` between them (one where the camera stayed)."""
        indices = self.indices[self.judged]
        if not len(indices):
            return []
        sizes, _ = self.steps()
        bounds = np.split(np.arange(len(indices)), np.flatnonzero(sizes > self.move_px) + 1)
        return [(int(indices[b[0]]), int(indices[b[-1]])) for b in bounds]

    def to_dict(self, names: list[str]) -> dict[str, Any]:
        """RESULT.json's `steadiness` (`names`: the recording's frame names)."""
        return {"compared_frames": int(len(self.indices)), "judged": int(self.judged.sum()),
                "moved": int(self.moved.sum()), "largest_move_px": self.largest_px,
                "move_px": self.move_px,
                "stretches": [[names[a], names[b]] for a, b in self.stretches()]}


def camera_motion(grey: np.ndarray, indices: np.ndarray,
                  settings: SteadinessSettings | None = None,
                  image_width: int | None = None) -> CameraMotion:
    """The still scene's motion (module doc) over grey frames (n, H, W) in [0, 1], taken in
    time order from the recording's frames `indices` (n,); frames wider than `width_px` are
    shrunk to it here (or were, by `shrunk`, as they were read: then `image_width` gives the
    recording's own width, in whose pixels the motion is reported).

    Raises:
        InputError: frames not (n, H, W) with n >= 1, or `indices` not (n,).
    """
    settings = settings or SteadinessSettings()
    grey = np.asarray(grey, np.float32)
    indices = np.asarray(indices, int)
    if grey.ndim != 3 or not len(grey) or indices.shape != (len(grey),):
        raise InputError(f"steadiness: frames {grey.shape} and indices {indices.shape} must be "
                         "(n, H, W) and (n,)")
    work = np.stack([_blurred(shrunk(f, settings), settings) for f in grey])
    work *= np.array([_exposure_gain(work[0], f, settings) for f in work],
                     np.float32)[:, None, None]
    height, width = work.shape[1:]
    to_full = (image_width or grey.shape[2]) / width
    limit = settings.move_px * width / settings.width_px
    corners = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]],
                       float)
    reference = _Reference.of(work[0], settings)
    poses = _camera_poses(reference, work, corners, limit, settings)
    shown = np.array([_pose_shown(reference, frame, poses, settings) for frame in work])
    if np.count_nonzero(shown > 0) < settings.min_moved_frames:
        shown[shown > 0] = UNTOLD
    moved, judged = shown > 0, shown >= 0
    shifts = np.zeros((len(work), IMAGE_CORNERS, 2))
    for i in np.flatnonzero(moved):
        shifts[i] = _corner_shifts(poses[shown[i]], corners) * to_full
    per_limit = width / settings.width_px * to_full
    return CameraMotion(indices, shifts, moved, judged, settings.move_px * per_limit,
                        settings.unreliable_px * per_limit)


def _pose_shown(reference: _Reference, frame: np.ndarray, poses: list[np.ndarray],
                settings: SteadinessSettings) -> int:
    """The pose `frame` shows: an index into `poses` (0: still), UNTOLD where its pixels cannot
    tell (module doc)."""
    errors = [reference.errors(frame, A) for A in poses]   # poses[0]: unmoved
    if max(reference.matching(e, settings) for e in errors) < settings.min_match:
        return UNTOLD
    votes = [_votes(e, errors[0], settings) for e in errors[1:]]
    if not votes:
        return 0
    best = int(np.argmax([a - b for a, b in votes]))
    if _clear(*votes[best], settings):
        return best + 1
    # still only where every pose loses clearly
    return 0 if all(_clear(b, a, settings) for a, b in votes) else UNTOLD


def _camera_poses(reference: _Reference, work: np.ndarray, corners: np.ndarray, limit: float,
                  settings: SteadinessSettings) -> list[np.ndarray]:
    """The camera's poses seen in the frames, as image moves (2, 3) from the first frame's:
    the first pose (no move), then each move fitted to a frame (the better voted of the
    tracked similarity and the phase shift) that displaces a corner more than `limit`,
    explains the frame better than no move (`min_match`, `_clear` votes) and lies more
    than `pose_spacing` times `limit` from every pose so far. Every frame is then judged
    against all of them: one whose own tracks failed (the arm across its corners) still shows
    its pose."""
    poses = [np.eye(2, 3)]
    for frame in work:
        fits = [A for A in (reference.move_to(frame, settings), reference.shift_to(frame))
                if A is not None]
        if not fits or len(poses) > settings.max_poses:
            continue
        still = reference.errors(frame, poses[0])
        scored = [(A, errors, _votes(errors, still, settings))
                  for A, errors in ((A, reference.errors(frame, A)) for A in fits)]
        A, errors, votes = max(scored, key=lambda fit: fit[2][0] - fit[2][1])
        shift = _corner_shifts(A, corners)
        if np.linalg.norm(shift, axis=1).max() <= limit or any(
                np.linalg.norm(shift - _corner_shifts(P, corners), axis=1).max()
                <= settings.pose_spacing * limit for P in poses[1:]):
            continue
        if reference.matching(errors, settings) >= settings.min_match \
                and _clear(*votes, settings):
            poses.append(A)
    return poses


def _votes(moved: np.ndarray, still: np.ndarray, settings: SteadinessSettings
           ) -> tuple[float, float]:
    """The shares of the textured pixels that a frame explains better (by `noise_level`) moved
    back by a move, and unmoved, from its `_Reference.errors` under each. Pixels that cannot
    tell (flat along the move, or on the arm) vote for neither."""
    both = np.isfinite(moved) & np.isfinite(still)
    if not both.any():
        return 0.0, 0.0
    return (float(np.mean(moved[both] < still[both] - settings.noise_level)),
            float(np.mean(still[both] < moved[both] - settings.noise_level)))


def _clear(for_one: float, for_other: float, settings: SteadinessSettings) -> bool:
    """Whether pixel votes (`_votes`) clearly favour the first hypothesis."""
    return for_one > settings.min_votes and for_one > settings.vote_ratio * for_other


def _corner_shifts(A: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """How far the image move A (2, 3) takes each of `corners` (4, 2)."""
    return corners @ A[:, :2].T + A[:, 2] - corners


def shrunk(grey: np.ndarray, settings: SteadinessSettings | None = None) -> np.ndarray:
    """One grey frame (H, W) shrunk to `width_px` where wider (float32).

    >>> shrunk(np.zeros((480, 640)), SteadinessSettings()).shape
    (240, 320)
    """
    settings = settings or SteadinessSettings()
    height, width = grey.shape
    if width <= settings.width_px:
        return np.asarray(grey, np.float32)
    size = (settings.width_px, max(1, round(height * settings.width_px / width)))
    return cv2.resize(np.asarray(grey, np.float32), size, interpolation=cv2.INTER_AREA)


def _exposure_gain(reference: np.ndarray, frame: np.ndarray, settings: SteadinessSettings
                   ) -> float:
    """The gain that brings `frame` to `reference`'s exposure (a camera on automatic exposure
    scales every pixel): the median ratio over the pixels brighter than `min_level` in both,
    most of them the still scene's whether the camera moved a few pixels or not (over the
    textured pixels alone, where the arm can be most of them, the ratio is the arm's)."""
    lit = (frame > settings.min_level) & (reference > settings.min_level)
    return float(np.median(reference[lit] / frame[lit])) if lit.any() else 1.0


def _blurred(grey: np.ndarray, settings: SteadinessSettings) -> np.ndarray:
    return cv2.GaussianBlur(grey, (0, 0), settings.blur_px) if settings.blur_px > 0 else grey


@dataclass(frozen=True)
class _Reference:
    """The first compared frame: its grey levels and their 8-bit copy, its corners to track,
    its textured pixels and gradient magnitude, and the window of its phase correlation."""

    grey: np.ndarray
    grey8: np.ndarray
    points: np.ndarray | None
    textured: np.ndarray
    gradient: np.ndarray
    window: np.ndarray

    @classmethod
    def of(cls, grey: np.ndarray, settings: SteadinessSettings) -> _Reference:
        grey8 = _eight_bit(grey)
        points = cv2.goodFeaturesToTrack(grey8, settings.corners, settings.corner_quality,
                                         settings.corner_spacing_px)
        gradient = np.hypot(*np.gradient(grey)).astype(np.float32)
        textured = gradient > max(float(np.quantile(gradient, settings.textured_quantile)),
                                  settings.min_gradient)
        window = cv2.createHanningWindow(grey.shape[::-1], cv2.CV_64F)
        return cls(grey, grey8, points, textured, gradient, window)

    def move_to(self, frame: np.ndarray, settings: SteadinessSettings) -> np.ndarray | None:
        """The similarity (2, 3) taking this frame's still scene to `frame`'s; None where
        too few corners track both ways."""
        if self.points is None or len(self.points) < settings.min_points:
            return None
        frame8 = _eight_bit(frame)
        lk = {"winSize": (settings.window_px, settings.window_px), "maxLevel": settings.levels}
        ahead, ok, _ = cv2.calcOpticalFlowPyrLK(self.grey8, frame8, self.points, None, **lk)
        back, ok_back, _ = cv2.calcOpticalFlowPyrLK(frame8, self.grey8, ahead, None, **lk)
        returned = np.linalg.norm(back - self.points, axis=2)[:, 0] < settings.round_trip_px
        kept = (ok[:, 0] == 1) & (ok_back[:, 0] == 1) & returned
        if kept.sum() < settings.min_points:
            return None
        A, _ = cv2.estimateAffinePartial2D(self.points[kept], ahead[kept], method=cv2.RANSAC,
                                           ransacReprojThreshold=settings.ransac_px)
        return A

    def shift_to(self, frame: np.ndarray) -> np.ndarray:
        """The image shift (as a move (2, 3)) taking this frame to `frame` by phase
        correlation: a second guess where the corners do not track (a smooth or repetitive
        scene)."""
        (dx, dy), _ = cv2.phaseCorrelate(self.grey.astype(np.float64),
                                         frame.astype(np.float64), self.window)
        return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])

    def errors(self, frame: np.ndarray, A: np.ndarray) -> np.ndarray:
        """How far `frame`, moved back by `A`, differs from this frame at each textured pixel
        (NaN where the move takes it outside `frame`)."""
        height, width = self.grey.shape
        seen = cv2.warpAffine(frame, A.astype(np.float32), (width, height),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        return np.abs(seen[self.textured] - self.grey[self.textured])

    def matching(self, errors: np.ndarray, settings: SteadinessSettings) -> float:
        """The share of the textured pixels a frame matches, from its `errors` under a move:
        within `match_px` of their gradient plus `noise_level`."""
        inside = np.isfinite(errors)
        if not inside.any():
            return 0.0
        tolerance = (settings.match_px * self.gradient[self.textured][inside]
                     + settings.noise_level)
        return float(np.mean(errors[inside] < tolerance))


def _eight_bit(grey: np.ndarray) -> np.ndarray:
    return np.clip(grey * GREY_MAX, 0, GREY_MAX).astype(np.uint8)


def steadiness_finding(motion: CameraMotion | None, names: list[str]) -> Finding | None:
    """The verdict's finding on a camera that moved (`names`: the recording's frame names);
    None where it stayed put or could not be judged.

    >>> still = CameraMotion(np.arange(2), np.zeros((2, 4, 2)), np.zeros(2, bool),
    ...                      np.ones(2, bool), 1.0, 4.0)
    >>> steadiness_finding(still, ["a", "b"]) is None
    True
    """
    if motion is None or not motion.moved.any():
        return None
    largest = motion.largest_px
    sizes, pairs = motion.steps()
    k = int(np.argmax(sizes))
    stretches = motion.stretches()
    level = UNRELIABLE if largest > motion.unreliable_px else CHECK
    seen = (f"the camera moved while it recorded: the scene behind the arm shifts up to "
            f"{largest:.1f} px between frames (the largest step {sizes[k]:.1f} px, between "
            f"frames {names[pairs[k, 0]]} and {names[pairs[k, 1]]}), and one extrinsic cannot "
            "fit frames seen from more than one camera pose")
    if len(stretches) < 2:
        return level, seen + ("; it drifted rather than jumped: record again with the camera "
                              "fixed firmly")
    if len(stretches) > LISTED_STRETCHES:
        a, b = max(stretches, key=lambda ab: ab[1] - ab[0])
        return level, seen + (f"; it moved between {len(stretches)} still stretches (a "
                              "shaking or slipping mount): record again with the camera fixed "
                              f"firmly, or calibrate the longest stretch alone (--frame-range "
                              f"{a}:{b + 1})")
    ranges = ", ".join(f"--frame-range {a}:{b + 1}" for a, b in stretches)
    return level, seen + (f"; calibrate each still stretch alone ({ranges}), or record again "
                          "with the camera fixed firmly")
