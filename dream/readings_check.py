"""Whether the joint readings are those of the images: a joint's sign convention flipped (the
controller's axis against the URDF's), two neighbouring joint columns swapped, or readings paired
with the image one frame early or late put the keypoints elsewhere than the images show them. A
robust keypoint fit then keeps the frames where the mistake moves them least and can land far
off with a small residual (a base joint negated: a metre off, and called `good`).

Each such mistake is a hypothesis: the keypoints are moved by the readings so corrected and the
pose fitted again from scratch. A hypothesis is named in the verdict where it explains (within
`explained_width` of the image's width of its fit) `min_gain` more of the detections than the
readings as given and at least `min_resolved` of those they leave unexplained, on the same
frames (at most `max_frames` of them). Readings that leave no more than `min_unexplained` of
the detections unexplained are not questioned.

    >>> joints = np.array([[0.3, -1.0, 0.0], [0.5, -1.2, 0.0], [0.4, -1.1, 0.0]])
    >>> for mistake in reading_hypotheses(joints, ("a", "b", "c")):
    ...     print(mistake.what)
    joint 'a' negated
    joint 'b' negated
    joints 'a' and 'b' swapped
    joints 'b' and 'c' swapped
    the readings one frame early (each image carries the next frame's readings)
    the readings one frame late (each image carries the previous frame's readings)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from dream.calibration import CalibrationResult, Observations, calibrate_all
from dream.camera import CameraIntrinsics
from dream.errors import DreamError, InputError
from dream.pnp.settings import SolverSettings
from dream.polish.objective import evenly_spaced
from dream.quality import UNRELIABLE, Finding

log = logging.getLogger(__name__)

SAME_POINT_M = 1e-6      # keypoints of the readings and of the observations agree within this
# frames the readings are shifted by (reading of image i := reading of image i - lag): the
# mistake that shift corrects, and what to do
LAGS = {1: ("the readings one frame early (each image carries the next frame's readings)",
            "pair each image with the reading before it"),
        -1: ("the readings one frame late (each image carries the previous frame's readings)",
             "pair each image with the reading after it")}


@dataclass(frozen=True)
class ReadingsCheckSettings:
    """The readings check's constants (set on renders: `benchmarks/readings_check.py`).

    Attributes:
        explained_width: a detection within this share of the image's width of its
            projection at a fit is explained by it (10 px of the 320-pixel-wide renders the
            constants were set on: a network's keypoints err in proportion to the image).
        min_unexplained: readings that leave no more than this share of the detections
            unexplained are not questioned.
        min_gain: a finding needs a hypothesis that explains this share of the detections more
            than the readings as given,
        min_resolved: and this share of the detections they leave unexplained.
        min_change_rad: a hypothesis that changes no reading by more than this is not tried
            (negating a joint that stays near zero, swapping two that read alike; metres for
            a prismatic joint).
        max_frames: the hypotheses are compared on at most this many frames, evenly spaced
            (each is a fit from scratch: the cost grows with the frames).
    """

    explained_width: float = 10.0 / 320.0
    min_unexplained: float = 0.03
    min_gain: float = 0.03
    min_resolved: float = 0.5
    min_change_rad: float = 0.05
    max_frames: int = 100

    def __post_init__(self) -> None:
        if not (0 < self.explained_width < 1 and 0 <= self.min_unexplained < 1
                and 0 < self.min_gain < 1 and 0 < self.min_resolved <= 1
                and self.min_change_rad >= 0 and self.max_frames >= 3):
            raise InputError(f"invalid ReadingsCheckSettings {self}")


@dataclass(frozen=True)
class Mistake:
    """One hypothesis: `what` went wrong, the `joints` (F, J) corrected for it, the `frames`
    (F,) they cover (a shift leaves one out), and what to `fix`."""

    what: str
    joints: np.ndarray
    frames: np.ndarray
    fix: str


@dataclass(frozen=True)
class ReadingsCheck:
    """The outcome: the detections the readings as given explain, the hypotheses tried, and the
    one that explains the most more than they do (None: none tried, or none explains more),
    with its count and theirs over the detections of the frames compared that it covers."""

    detections: int
    explained: int
    tried: tuple[str, ...]
    best: Mistake | None = None
    best_detections: int = 0
    best_explained: int = 0
    given_explained_there: int = 0
    explained_px: float | None = None

    @property
    def gain(self) -> float:
        """The best hypothesis' explained share minus the given readings' on its frames."""
        if self.best is None or not self.best_detections:
            return 0.0
        return (self.best_explained - self.given_explained_there) / self.best_detections

    @property
    def resolved(self) -> float:
        """The share of the detections the given readings leave unexplained (on the best
        hypothesis' frames) that it explains."""
        unexplained = self.best_detections - self.given_explained_there
        if self.best is None or unexplained <= 0:
            return 0.0
        return (self.best_explained - self.given_explained_there) / unexplained

    def to_dict(self) -> dict[str, Any]:
        return {"detections": self.detections, "explained": self.explained,
                "tried": list(self.tried), "best": None if self.best is None else self.best.what,
                "best_detections": self.best_detections, "best_explained": self.best_explained,
                "given_explained_there": self.given_explained_there,
                "explained_within_px": self.explained_px, "gain": self.gain,
                "resolved": self.resolved}


def reading_hypotheses(joints: np.ndarray, joint_names: tuple[str, ...] | list[str],
                       min_change_rad: float = ReadingsCheckSettings.min_change_rad
                       ) -> list[Mistake]:
    """The mistakes worth trying (pure): each joint negated, each two neighbouring joints
    swapped, the readings one frame early and one frame late."""
    joints = np.asarray(joints, dtype=float)
    if joints.ndim != 2 or joints.shape[1] != len(joint_names):
        raise InputError(f"joints of shape {joints.shape} for {len(joint_names)} joint names")
    every, count = np.ones(len(joints), bool), joints.shape[1]
    out = []
    for j in range(count):
        if np.max(np.abs(joints[:, j])) * 2 > min_change_rad:
            changed = joints.copy()
            changed[:, j] *= -1
            out.append(Mistake(f"joint '{joint_names[j]}' negated", changed, every,
                               "negate its readings (the controller counts that joint the "
                               "other way round from the URDF's axis)"))
    for j in range(count - 1):
        if np.max(np.abs(joints[:, j] - joints[:, j + 1])) > min_change_rad:
            changed = joints.copy()
            changed[:, [j, j + 1]] = joints[:, [j + 1, j]]
            out.append(Mistake(f"joints '{joint_names[j]}' and '{joint_names[j + 1]}' swapped",
                               changed, every, "swap the two columns' names"))
    if len(joints) >= 3:
        for lag, (what, fix) in LAGS.items():
            changed = np.roll(joints, lag, axis=0)
            frames = np.ones(len(joints), bool)
            if lag > 0:
                frames[:lag] = False
            else:
                frames[lag:] = False
            if np.max(np.abs(changed[frames] - joints[frames])) > min_change_rad:
                out.append(Mistake(what, changed, frames, fix))
    return out


def explained(residuals_px: np.ndarray, found: np.ndarray, threshold_px: float) -> np.ndarray:
    """(F, K) detections within `threshold_px` of their projection."""
    with np.errstate(invalid="ignore"):
        return found & (np.linalg.norm(residuals_px, axis=-1) < threshold_px)


def check_readings(result: CalibrationResult, obs: Observations, robot: Any,
                   joints: np.ndarray, camera: CameraIntrinsics,
                   settings: ReadingsCheckSettings = ReadingsCheckSettings(),
                   solver: SolverSettings | None = None) -> ReadingsCheck | None:
    """The readings check of an all-frames keypoint result (None for another mode): `joints`
    (F, J) the readings in `robot`'s joint order that gave `obs.P_base`."""
    if result.mode != "all":
        return None
    if not np.allclose(robot.forward_kinematics(joints), obs.P_base, atol=SAME_POINT_M):
        raise InputError("the joint readings given to the readings check are not those of the "
                         "observations' keypoints", fix="pass the readings, in the robot's "
                         "joint order, that made observations.P_base")
    found, within_px = obs.found, settings.explained_width * camera.width
    given = explained(result.residuals_px, found, within_px)
    detections, count = int(found.sum()), int(given.sum())
    if not detections or count >= (1 - settings.min_unexplained) * detections:
        return ReadingsCheck(detections, count, (), explained_px=within_px)
    hypotheses = reading_hypotheses(joints, tuple(robot.joint_names), settings.min_change_rad)
    log.info("readings check: %d of %d detections explained; trying %d mistakes in the "
             "readings", count, detections, len(hypotheses))
    best = ReadingsCheck(detections, count, tuple(m.what for m in hypotheses),
                         explained_px=within_px)
    compared = evenly_spaced(np.arange(len(joints)), settings.max_frames)
    for mistake in hypotheses:
        seen = found[compared] & mistake.frames[compared, None]
        moved = Observations(robot.forward_kinematics(mistake.joints[compared]),
                             np.where(seen[..., None], obs.uv[compared], np.nan),
                             np.where(seen, obs.confidence[compared], 0.0),
                             tuple(obs.frame_names[i] for i in compared), obs.keypoint_names)
        try:
            fit = calibrate_all(moved, camera, solver)
        except DreamError:
            continue
        tried = ReadingsCheck(detections, count, best.tried, mistake, int(seen.sum()),
                              int(explained(fit.residuals_px, seen, within_px).sum()),
                              int((given[compared] & seen).sum()), within_px)
        if tried.gain > best.gain:
            best = tried
    return best


def readings_finding(check: ReadingsCheck | None,
                     settings: ReadingsCheckSettings = ReadingsCheckSettings()
                     ) -> Finding | None:
    """`unreliable` where a mistake in the readings explains the images far better (pure).

    >>> late = reading_hypotheses(np.arange(8.0).reshape(4, 2), ("a", "b"))[-1]
    >>> readings_finding(ReadingsCheck(100, 60, ("x",), late, 100, 98, 60, 10.0))[0]
    'unreliable'
    >>> readings_finding(ReadingsCheck(100, 60, ("x",), late, 100, 66, 60, 10.0)) is None
    True
    """
    if check is None or check.best is None or check.gain < settings.min_gain \
            or check.resolved < settings.min_resolved:
        return None
    return UNRELIABLE, (
        f"the joint readings look wrong: the keypoints agree far better with {check.best.what}: "
        f"{check.best_explained} of {check.best_detections} detections lie within "
        f"{check.explained_px:.3g} px of the fit, against {check.given_explained_there} with "
        f"the readings as given; {check.best.fix}, then calibrate again")
