"""The quality verdict of a calibration: `good`, `check` or `unreliable`, with the reasons.

A small reprojection error does not make a calibration right. The verdict looks at what the
error cannot show:

- **kept share**: a robust keypoint fit discards the detections that disagree with it. When
  most of them disagree, the fit may stand on a small consensus of a biased set (a detector that
  misplaces keypoints on these photos, joint readings that do not match the images) and fit
  those few to a fraction of a pixel at a pose centimetres off. A kept image refinement
  (`--polish`, `--refine edges`) does not rest on that consensus, so it softens the verdict.
- **condition**: the reported 1-sigma of the camera position and rotation, with the
  worst-constrained direction named in words and the motion that would constrain it.
- **duplicate frames**: frames with the same joint readings and the same detections count as
  independent evidence in the 1-sigma, which they are not.
- **static arm**: frames whose keypoints hardly move add no geometry.
- **frames' agreement** (`--frames each`): the reported frame is judged by its own kept
  share and 1-sigma, and by how far the other frames' poses lie from it: with a fixed camera
  they should agree within that 1-sigma.

The condition is that of the pose written: where an image refinement was kept, its own 1-sigma
(`dream.refined_uncertainty`), not the keypoint fit's.

RESULT.json's `quality` object: `detections`, `kept`, `kept_share`, `verdict` and `warnings`
(one sentence each, with what to do).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from dream.calibration import CalibrationResult, Observations
from dream.errors import InputError
from dream.transforms import invert_T, rotation_angle_between, skew

# Below this share of the detections kept by the fit, the verdict is at least "check". With the
# bundled model on rendered fixed-camera scenes (benchmarks/edge_align.py's seeds 100-119)
# the all-frames fit keeps 66-89 % of the detections.
MIN_KEPT_SHARE = 0.5
# Limits on the reported 1-sigma (the fit's plus the keypoint jackknife's) of the camera
# position and rotation: "check" beyond the first (a centimetre, a degree: too loose for
# grasping), "unreliable" beyond the second.
POSITION_SIGMA_CHECK_M = 0.01
POSITION_SIGMA_UNRELIABLE_M = 0.05
ROTATION_SIGMA_CHECK_RAD = np.deg2rad(1.0)
ROTATION_SIGMA_UNRELIABLE_RAD = np.deg2rad(5.0)
DEPTH_AXIS_COS = 0.8          # a direction this close to the optical axis counts as depth
DUPLICATE_JOINTS_M = 1e-6     # keypoints this close in the base frame: the same readings
DUPLICATE_UV_PX = 0.05        # detections this close (median): the same image again
STATIC_MOTION_M = 0.01        # keypoints moving less than this across frames: a static arm
STILL_IMAGE_PX = 10.0         # a static arm's detections moving more than this (median over
                              # the keypoints of each one's largest move): a frozen joint log
MIN_AGREEMENT_FRAMES = 2      # other frames' poses below which a per-frame result's agreement
                              # with them is not judged
GOOD, CHECK, UNRELIABLE = "good", "check", "unreliable"
LEVELS = (GOOD, CHECK, UNRELIABLE)


@dataclass(frozen=True)
class Quality:
    """The verdict on a calibration (module doc).

    Attributes:
        detections: keypoint detections found. kept: of them, inliers of the fit.
        verdict: GOOD, CHECK or UNRELIABLE. warnings: why, one sentence each with what to do.
    """

    detections: int
    kept: int
    verdict: str
    warnings: tuple[str, ...]

    def __post_init__(self) -> None:
        if not 0 <= self.kept <= self.detections:
            raise InputError(f"kept ({self.kept}) must lie in [0, detections "
                             f"({self.detections})]")
        if self.verdict not in LEVELS:
            raise InputError(f"verdict must be one of {', '.join(LEVELS)}, got "
                             f"'{self.verdict}'")

    @property
    def kept_share(self) -> float:
        return self.kept / self.detections if self.detections else 0.0

    def to_dict(self) -> dict[str, Any]:
        """RESULT.json's `quality` object."""
        return {"detections": self.detections, "kept": self.kept,
                "kept_share": self.kept_share, "verdict": self.verdict,
                "warnings": list(self.warnings)}


Finding = tuple[str, str]   # (level, sentence)


def kept_finding(detections: int, kept: int, refined_by: str | None = None,
                 min_kept_share: float = MIN_KEPT_SHARE) -> Finding | None:
    """The kept-share finding (pure); `refined_by` names an image refinement that was kept
    ("the silhouette polish", "the edge alignment").

    >>> kept_finding(70, 20)[0]
    'unreliable'
    >>> kept_finding(210, 180) is None
    True
    """
    if not 0 < min_kept_share <= 1:
        raise InputError(f"min_kept_share must lie in (0, 1], got {min_kept_share}")
    share = kept / detections if detections else 0.0
    if share >= min_kept_share:
        return None
    warning = (f"only {kept} of {detections} keypoint detections ({share:.0%}) agree with the "
               "keypoint pose: it may follow a biased few, and its RMSE and 1-sigma do not "
               "measure its error")
    if refined_by:
        return CHECK, warning + f"; the pose kept is {refined_by}'s, which does not rest on them"
    return UNRELIABLE, warning + ("; check the overlays (--overlays DIR) or refine with the "
                                 "images (--polish with masks, --refine edges without)")


def camera_position_covariance(covariance: np.ndarray, T_cam_base: np.ndarray) -> np.ndarray:
    """(3, 3) covariance of the camera position, in camera axes, from the (6, 6) covariance of
    the fit's parameters (rotation about, then translation along the camera axes;
    `dream.calibration`): the camera centre moves by -[t]x w - d for a rotation w and a shift
    d."""
    t = T_cam_base[:3, 3]
    J = np.hstack([-skew(t), -np.eye(3)])
    return J @ covariance @ J.T


def condition_findings(covariance: np.ndarray, T_cam_base: np.ndarray) -> list[Finding]:
    """The camera position's and rotation's 1-sigma against the limits, the worst direction
    in words."""
    findings = []
    values, vectors = np.linalg.eigh(camera_position_covariance(covariance, T_cam_base))
    sigma, direction = float(np.sqrt(max(values[-1], 0.0))), vectors[:, -1]
    if sigma > POSITION_SIGMA_CHECK_M:
        if abs(direction[2]) >= DEPTH_AXIS_COS:
            what = ("depth along the camera axis is poorly constrained; move the arm towards and "
                    "away from the camera")
        else:
            what = ("the camera position across the view is poorly constrained; move the arm "
                    "across the whole image, and turn its wrist")
        level = UNRELIABLE if sigma > POSITION_SIGMA_UNRELIABLE_M else CHECK
        findings.append((level, f"camera position 1-sigma {sigma * 1e3:.1f} mm: {what}"))
    rotation = float(np.sqrt(max(np.linalg.eigvalsh(covariance[:3, :3])[-1], 0.0)))
    if rotation > ROTATION_SIGMA_CHECK_RAD:
        level = UNRELIABLE if rotation > ROTATION_SIGMA_UNRELIABLE_RAD else CHECK
        findings.append((level, f"camera rotation 1-sigma {np.rad2deg(rotation):.2f} deg: record "
                                "configurations that spread the arm over the image"))
    return findings


def duplicate_finding(obs: Observations) -> Finding | None:
    """Frames that repeat an earlier frame's joint readings and detections."""
    repeats = 0
    for i in range(1, len(obs.frame_names)):
        same_joints = np.max(np.abs(obs.P_base[:i] - obs.P_base[i]), axis=(1, 2)) \
            < DUPLICATE_JOINTS_M
        for j in np.flatnonzero(same_joints):
            both = obs.found[i] & obs.found[j]
            if both.any() and np.median(np.linalg.norm(obs.uv[i, both] - obs.uv[j, both],
                                                       axis=-1)) < DUPLICATE_UV_PX:
                repeats += 1
                break
    if not repeats:
        return None
    return CHECK, (f"{repeats} of {len(obs.frame_names)} frames repeat another frame's joint "
                   "readings and detections: the 1-sigma counts them as independent, so it is "
                   "too small; drop the repeats or record other configurations")


def static_finding(obs: Observations) -> Finding | None:
    """An arm whose keypoints hardly move across the frames."""
    if len(obs.frame_names) < 2:
        return None
    motion = float(np.max(np.linalg.norm(obs.P_base - obs.P_base[:1], axis=-1)))
    if motion >= STATIC_MOTION_M:
        return None
    with warnings.catch_warnings():     # a keypoint never found: its median is NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        seen = np.linalg.norm(obs.uv - np.nanmedian(obs.uv, axis=0), axis=-1)
        image_px = float(np.nanmedian(np.nanmax(seen, axis=0))) if np.isfinite(seen).any() \
            else 0.0
    if image_px > STILL_IMAGE_PX:
        return UNRELIABLE, (f"the joint readings hardly change (the keypoints move at most "
                            f"{motion * 1e3:.1f} mm) but the keypoints move {image_px:.0f} px "
                            "in the images: the joint log is frozen, or not the one of these "
                            "images; check the readings and their timestamps")
    return CHECK, (f"the keypoints move at most {motion * 1e3:.1f} mm across the "
                   f"{len(obs.frame_names)} frames: they add no geometry to one view; record "
                   "10 or more configurations spread over the workspace")


def quality_from(detections: int, kept: int, findings: list[Finding | None]) -> Quality:
    """The verdict: the most severe level among the findings (GOOD without any)."""
    found = [f for f in findings if f is not None]
    level = max((LEVELS.index(lv) for lv, _ in found), default=0)
    return Quality(detections, kept, LEVELS[level], tuple(text for _, text in found))


def frames_agreement_finding(T_reported: np.ndarray, T_frames: np.ndarray,
                             min_frames: int = MIN_AGREEMENT_FRAMES) -> Finding | None:
    """How the other frames' poses of a per-frame result (`--frames each`) agree with the
    reported one (pure): the median camera-position distance and rotation angle between the
    reported extrinsic T_reported (4, 4) and each other solved frame's T_frames (F, 4, 4; NaN
    rows for frames without a pose). A fixed camera's frames should agree within the reported
    1-sigma; where they lie centimetres apart the per-frame poses follow their detections'
    errors, whichever of them is reported. None with fewer than `min_frames` other poses, or
    when they agree within the 1-sigma limits.

    >>> T = np.eye(4); T[2, 3] = 1.0
    >>> far = T.copy(); far[0, 3] = 0.2
    >>> frames_agreement_finding(T, np.stack([T, far, far, far]))[0]
    'check'
    >>> frames_agreement_finding(T, np.stack([T] * 4)) is None
    True
    """
    T_frames = np.asarray(T_frames, dtype=float)
    if T_frames.ndim != 3 or T_frames.shape[1:] != (4, 4):
        raise InputError(f"frame poses have shape {T_frames.shape}, expected (F, 4, 4)")
    solved = np.all(np.isfinite(T_frames.reshape(len(T_frames), -1)), axis=1)
    others = [T for T in T_frames[solved] if not np.allclose(T, T_reported)]
    if len(others) < min_frames:
        return None
    c0 = invert_T(T_reported)[:3, 3]
    position = float(np.median([np.linalg.norm(invert_T(T)[:3, 3] - c0) for T in others]))
    rotation = float(np.median([rotation_angle_between(T[:3, :3], T_reported[:3, :3])
                                for T in others]))
    if position <= POSITION_SIGMA_CHECK_M and rotation <= ROTATION_SIGMA_CHECK_RAD:
        return None
    # "check", not "unreliable": frames of a camera that moved disagree by design
    return CHECK, (f"the other {len(others)} frames' poses lie a median {position * 1e3:.1f} mm "
                   f"and {np.rad2deg(rotation):.2f} deg from the reported one: with a fixed "
                   "camera they follow their detections' errors (use --frames all, which "
                   "solves one pose from every frame); if the camera moved between frames, "
                   "judge each frame by its own 1-sigma")


def result_quality(result: CalibrationResult, obs: Observations,
                   refined_by: str | None = None, covariance: np.ndarray | None = None,
                   T_cam_base: np.ndarray | None = None,
                   T_frames: np.ndarray | None = None,
                   extra: tuple[Finding | None, ...] | list[Finding] = (),
                   leading: tuple[Finding | None, ...] | list[Finding] = ()) -> Quality:
    """The verdict on a calibration: its detections found and kept, the condition of the pose
    written (`T_cam_base` and its `covariance`: a kept image refinement's own; default the
    keypoint fit's), and, for the one extrinsic of all frames, duplicate frames and a static
    arm; for a per-frame result (`--frames each`), how the frames' poses `T_frames` (F, 4, 4,
    NaN where none; default the keypoint fits') agree with the reported one; `extra`: more
    findings (the silhouettes' cross-check of an edge alignment, `dream.coarse.verdict`);
    `leading`: findings that may cause the others (a mistake in the joint readings), listed
    first."""
    found = obs.found
    detections, kept = int(found.sum()), int(np.sum(result.inlier & found))
    covariance = result.covariance if covariance is None else np.asarray(covariance, float)
    T = result.T_cam_base if T_cam_base is None else np.asarray(T_cam_base, float)
    findings = list(leading) + [kept_finding(detections, kept, refined_by)]
    findings += condition_findings(covariance, T)
    if result.mode == "all":
        findings += [duplicate_finding(obs), static_finding(obs)]
    else:
        if T_frames is None:
            T_frames = np.stack([np.full((4, 4), np.nan) if (Ti := result.T_cam_base_of_frame(i))
                                 is None else Ti for i in range(len(result.frames))])
        findings.append(frames_agreement_finding(T, T_frames))
    return quality_from(detections, kept, findings + list(extra))
