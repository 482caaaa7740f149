"""Extrinsic calibration from keypoint observations of many frames.

A fixed camera sees the robot in F joint configurations. Every keypoint of every frame is a
2D-3D correspondence with the same `T_cam_base`, so `calibrate_all` solves one pose from all of
them together (not an average of per-frame poses): hypotheses from single-frame solutions and
from random minimal samples across frames are ranked by MSAC, and the best is refined with a
robust loss and outlier rejection. `calibrate_each` solves every frame alone (moving camera).

The fit's covariance assumes independent detection errors; a keypoint network's errors are not:
the same keypoint is misplaced the same way in many frames (a wrist taken for the hand, a
consistent offset from the link origin), which more frames do not average out.
`keypoint_jackknife` measures that part: the spread of the solutions with one keypoint (in every
frame) left out at a time, the delete-one-group jackknife with the keypoints as groups. A single
frame's fit is as optimistic (a misplaced keypoint is one of a handful): `calibrate_each` gives
every frame its own keypoint jackknife, from its leave-out solutions (`frame_leave_outs`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, replace

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import CalibrationError, DreamError, InputError
from dream.pnp import (
    NoSolution,
    PoseFit,
    SolverSettings,
    check_correspondences,
    degeneracy,
    increment_between,
    initial_pose,
    refine_best,
    solve_pnp_batch,
)
from dream.refined_uncertainty import jackknife_covariance
from dream.transforms import camera_position_covariance

log = logging.getLogger(__name__)

FIX_NO_FRAME_ALONE = ("use --frames all (one extrinsic from all frames together needs fewer "
                      "keypoints per frame), or give frames with at least 4 keypoints found, "
                      "not all on one line")
FIX_NO_EXTRINSIC = ("give data whose frames show more of the robot's keypoints (labels or "
                    "detections), at least 4 in all and not all on one line")


@dataclass(frozen=True)
class Observations:
    """2D keypoint observations with their 3D positions in the base frame.

    Attributes:
        P_base: (F, K, 3) keypoint positions from forward kinematics, m.
        uv: (F, K, 2) observed pixels, NaN where a keypoint was not found.
        confidence: (F, K) detection confidence (1 for labels), weights of the fit.
        frame_names: F names. keypoint_names: K names.
    """

    P_base: np.ndarray
    uv: np.ndarray
    confidence: np.ndarray
    frame_names: tuple[str, ...]
    keypoint_names: tuple[str, ...]

    def __post_init__(self) -> None:
        F, K = len(self.frame_names), len(self.keypoint_names)
        for name, shape in (("P_base", (F, K, 3)), ("uv", (F, K, 2)), ("confidence", (F, K))):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != shape:
                raise InputError(f"observations {name} has shape {a.shape}, expected {shape}")
            object.__setattr__(self, name, a)

    @property
    def found(self) -> np.ndarray:
        """(F, K) True where a keypoint was observed."""
        return np.all(np.isfinite(self.uv), -1) & np.isfinite(self.confidence) & \
            (self.confidence > 0)

    @property
    def uv_found(self) -> np.ndarray:
        """(F, K, 2) `uv` with NaN where a keypoint was not observed (`found`)."""
        return np.where(self.found[..., None], self.uv, np.nan)

    @property
    def confidence_found(self) -> np.ndarray:
        """(F, K) `confidence` with 0 where a keypoint was not observed (`found`)."""
        return np.where(self.found, self.confidence, 0.0)


MIN_JACKKNIFE_GROUPS = 3   # leave-out solutions below which no spread is estimated


@dataclass(frozen=True)
class KeypointJackknife:
    """The delete-one-keypoint jackknife of an extrinsic (all frames', or one frame's).

    Attributes:
        covariance: (6, 6) jackknife covariance of xi (the fit's parametrisation: rotation about
            and translation along the camera axes, at the all-keypoint solution):
            (G - 1) / G * sum_k (xi_k - mean)(xi_k - mean)^T over the G solutions xi_k with
            keypoint k left out.
        left_out: the names of the G keypoints whose leave-out solution entered it.
    """

    covariance: np.ndarray
    left_out: tuple[str, ...]

    def __post_init__(self) -> None:
        if np.shape(self.covariance) != (6, 6):
            raise InputError(f"jackknife covariance has shape {np.shape(self.covariance)}, "
                             "expected (6, 6)")
        if len(self.left_out) < MIN_JACKKNIFE_GROUPS:
            raise InputError(f"a keypoint jackknife needs at least {MIN_JACKKNIFE_GROUPS} "
                             f"leave-out solutions, got {len(self.left_out)}")


@dataclass(frozen=True)
class FrameSolution:
    """A frame's own single-frame solution (or why there is none) and, when computed
    (`calibrate_each`), its keypoint jackknife (None: not computed or not estimable) and the
    leave-out solutions it came from: (keypoint left out, T_cam_base) of each that solved."""

    name: str
    fit: PoseFit | NoSolution
    keypoints_found: int
    jackknife: KeypointJackknife | None = None
    leave_outs: tuple[tuple[str, np.ndarray], ...] = ()

    @property
    def covariance(self) -> np.ndarray | None:
        """(6, 6) covariance of the frame's extrinsic: the fit's plus its jackknife's (None
        without a solution)."""
        if not isinstance(self.fit, PoseFit):
            return None
        return _fit_plus_jackknife(self.fit, self.jackknife)


def _fit_plus_jackknife(fit: PoseFit, jackknife: KeypointJackknife | None) -> np.ndarray:
    """The fit's covariance plus, when there is one, the jackknife's."""
    if jackknife is None:
        return fit.covariance
    return fit.covariance + jackknife.covariance


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of a calibration.

    Attributes:
        mode: "all" (one pose from every frame) or "each" (one pose per frame).
        fit: the reported extrinsic's fit; in "each" mode the best-determined frame's.
        frames: per-frame single-frame solutions.
        residuals_px: (F, K, 2) residuals of every observation under the pose reported for its
            frame (the joint pose in "all" mode), NaN where none.
        inlier: (F, K) observations kept by the fit that reports them.
        jackknife: the keypoint jackknife of the reported extrinsic (an "all" result's from
            `with_keypoint_jackknife`, an "each" result's from its frame), or None.
    """

    mode: str
    fit: PoseFit
    frames: tuple[FrameSolution, ...]
    residuals_px: np.ndarray
    inlier: np.ndarray
    jackknife: KeypointJackknife | None = None

    @property
    def covariance(self) -> np.ndarray:
        """(6, 6) covariance of the reported extrinsic: the fit's (independent detection errors)
        plus, when present, the keypoint jackknife's (errors a keypoint's detections share
        across frames). The sum counts the independent part twice: with independent errors it
        errs on the safe side."""
        return _fit_plus_jackknife(self.fit, self.jackknife)

    @property
    def T_cam_base(self) -> np.ndarray:
        """(4, 4) the reported extrinsic: maps base-frame points into the camera frame."""
        return self.fit.T_cam_base

    @property
    def sigma_translation_m(self) -> np.ndarray:
        """(3,) 1-sigma of the translation along the camera axes, m (of `covariance`)."""
        return np.sqrt(np.diag(self.covariance)[3:])

    @property
    def sigma_camera_position_base_m(self) -> np.ndarray:
        """(3,) 1-sigma of the camera's position in the base frame along base x, y, z, m (of
        `covariance`, the rotation's share included: RESULT.json's
        `sigma_camera_position_base_m`)."""
        return np.sqrt(np.diag(camera_position_covariance(self.T_cam_base, self.covariance)))

    @property
    def sigma_rotation_rad(self) -> np.ndarray:
        """(3,) 1-sigma of the rotation about the camera axes, rad (of `covariance`)."""
        return np.sqrt(np.diag(self.covariance)[:3])

    @property
    def frames_used(self) -> int:
        if self.mode == "all":
            return int(np.any(self.inlier, axis=1).sum())
        return sum(isinstance(f.fit, PoseFit) for f in self.frames)

    @property
    def reported_frame(self) -> int | None:
        """The index of the frame whose solution is reported ("each" mode); None in "all"
        mode."""
        if self.mode != "each":
            return None
        return next(i for i, f in enumerate(self.frames) if f.fit is self.fit)

    def T_cam_base_of_frame(self, i: int) -> np.ndarray | None:
        """The extrinsic reported for frame i (None when that frame has no solution)."""
        if self.mode == "all":
            return self.fit.T_cam_base
        fit = self.frames[i].fit
        return fit.T_cam_base if isinstance(fit, PoseFit) else None


def solve_frames(obs: Observations, camera: CameraIntrinsics, settings: SolverSettings,
                 frame_cameras: SequenceOf[CameraIntrinsics] | None = None
                 ) -> tuple[FrameSolution, ...]:
    """Every frame solved alone (with its own intrinsics where `frame_cameras` gives them);
    a frame without a solution says why."""
    fits = solve_pnp_batch(obs.P_base, obs.uv_found, _cameras(obs, camera, frame_cameras),
                           confidence=obs.confidence_found, settings=settings)
    for name, fit in zip(obs.frame_names, fits, strict=True):
        if isinstance(fit, NoSolution):
            log.debug("frame %s: %s", name, fit.reason)
    return tuple(FrameSolution(name, fit, int(found.sum()))
                 for name, fit, found in zip(obs.frame_names, fits, obs.found, strict=True))


def _cameras(obs: Observations, camera: CameraIntrinsics,
             frame_cameras: SequenceOf[CameraIntrinsics] | None) -> SequenceOf[CameraIntrinsics]:
    """Each frame's intrinsics: `frame_cameras`, or `camera` for every frame."""
    if frame_cameras is None:
        return [camera] * len(obs.frame_names)
    if len(frame_cameras) != len(obs.frame_names):
        raise InputError(f"{len(frame_cameras)} frame cameras for {len(obs.frame_names)} frames")
    return frame_cameras


def _random_hypotheses(P: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                       settings: SolverSettings) -> list[np.ndarray]:
    rng = np.random.default_rng(settings.seed)
    hypotheses = []
    n = len(P)
    if n < settings.ransac_sample_size:
        return hypotheses
    for _ in range(settings.ransac_hypotheses):
        sample = rng.choice(n, settings.ransac_sample_size, replace=False)
        if degeneracy(P[sample], settings) is None:
            T = initial_pose(P[sample], uv[sample], camera)
            if not isinstance(T, NoSolution):
                hypotheses.append(T)
    return hypotheses


def calibrate_all(obs: Observations, camera: CameraIntrinsics,
                  settings: SolverSettings | None = None,
                  frames: tuple[FrameSolution, ...] | None = None) -> CalibrationResult:
    """One `T_cam_base` minimising the robust reprojection error over all frames at once."""
    settings = settings or SolverSettings()
    frames = frames if frames is not None else solve_frames(obs, camera, settings)
    P = obs.P_base.reshape(-1, 3)
    uv = obs.uv_found.reshape(-1, 2)
    conf = obs.confidence_found.reshape(-1)
    P, uv, conf, usable = check_correspondences(P, uv, conf)
    reason = degeneracy(P[usable], settings)
    if reason is not None:
        raise CalibrationError(f"no extrinsic can be solved: {reason} over all frames",
                               fix=FIX_NO_EXTRINSIC)
    hypotheses = [f.fit.T_cam_base for f in frames if isinstance(f.fit, PoseFit)]
    all_points = initial_pose(P[usable], uv[usable], camera)
    if not isinstance(all_points, NoSolution):
        hypotheses.append(all_points)
    hypotheses += _random_hypotheses(P[usable], uv[usable], camera, settings)
    fit = refine_best(P, uv, camera, hypotheses, conf, usable, settings)
    if isinstance(fit, NoSolution):
        raise CalibrationError(f"no extrinsic can be solved: {fit.reason}",
                               fix=FIX_NO_EXTRINSIC)
    shape = obs.uv.shape
    return CalibrationResult("all", fit, frames, fit.residuals_px.reshape(shape),
                             fit.inlier.reshape(shape[:2]))


def keypoint_jackknife(result: CalibrationResult, obs: Observations, camera: CameraIntrinsics,
                       settings: SolverSettings | None = None) -> KeypointJackknife | None:
    """The delete-one-keypoint jackknife of an all-frames result: `calibrate_all` again with
    each observed keypoint left out of every frame (the same per-frame solutions among the
    hypotheses). None when fewer than `MIN_JACKKNIFE_GROUPS` of these are solvable."""
    if result.mode != "all":
        raise InputError("the keypoint jackknife is for all-frames results (--frames all)")
    settings = settings or SolverSettings()
    names = obs.keypoint_names
    xis, left_out = [], []
    for k in np.flatnonzero(np.any(obs.found, axis=0)):
        confidence = obs.confidence.copy()
        confidence[:, k] = 0.0
        subset = Observations(obs.P_base, obs.uv, confidence, obs.frame_names, names)
        try:
            fit = calibrate_all(subset, camera, settings, frames=result.frames).fit
        except DreamError as exc:
            log.debug("keypoint jackknife without %s: %s", names[k], exc)
            continue
        xis.append(increment_between(result.fit.T_cam_base, fit.T_cam_base))
        left_out.append(names[k])
    return _jackknife(xis, left_out)


def _jackknife(xis: list[np.ndarray], left_out: list[str]) -> KeypointJackknife | None:
    """The jackknife of the G leave-out solutions xi_k (6,) (None when G is too small)."""
    if len(xis) < MIN_JACKKNIFE_GROUPS:
        return None
    return KeypointJackknife(jackknife_covariance(np.array(xis)), tuple(left_out))


def frame_leave_outs(obs: Observations, frames: tuple[FrameSolution, ...],
                     cameras: SequenceOf[CameraIntrinsics],
                     settings: SolverSettings | None = None
                     ) -> tuple[tuple[tuple[str, np.ndarray], ...], ...]:
    """Each solved frame solved again (`solve_pnp`) without each of its observed keypoints in
    turn, every such problem of every frame in one `solve_pnp_batch` call: per frame, (keypoint
    left out, T_cam_base) of the leave-outs that solved (none for a frame without a
    solution)."""
    if len(frames) != len(obs.frame_names) or len(cameras) != len(frames):
        raise InputError(f"{len(frames)} frame solutions and {len(cameras)} cameras for "
                         f"{len(obs.frame_names)} frames")
    settings = settings or SolverSettings()
    solved = np.array([isinstance(f.fit, PoseFit) for f in frames], bool)
    fi, ki = np.nonzero(obs.found & solved[:, None])          # problem j: frame fi[j] without ki[j]
    if len(fi) == 0:
        return ((),) * len(frames)
    confidence = obs.confidence_found[fi]
    confidence[np.arange(len(fi)), ki] = 0.0
    fits = solve_pnp_batch(obs.P_base[fi], obs.uv_found[fi], [cameras[f] for f in fi.tolist()],
                           confidence=confidence, settings=settings)
    return tuple(tuple((obs.keypoint_names[ki[j]], fits[j].T_cam_base)
                       for j in np.flatnonzero(fi == f).tolist()
                       if isinstance(fits[j], PoseFit))
                 for f in range(len(frames)))


def _frame_jackknife(frame: FrameSolution, leave_outs: tuple[tuple[str, np.ndarray], ...]
                     ) -> KeypointJackknife | None:
    """A frame's delete-one-keypoint jackknife from its leave-out solutions."""
    if not leave_outs:
        return None
    return _jackknife([increment_between(frame.fit.T_cam_base, T) for _, T in leave_outs],
                      [name for name, _ in leave_outs])


def with_keypoint_jackknife(result: CalibrationResult, obs: Observations,
                            camera: CameraIntrinsics,
                            settings: SolverSettings | None = None) -> CalibrationResult:
    """`result` with its `keypoint_jackknife` (unchanged when there is none)."""
    jackknife = keypoint_jackknife(result, obs, camera, settings)
    return result if jackknife is None else replace(result, jackknife=jackknife)


def calibrate_each(obs: Observations, camera: CameraIntrinsics,
                   settings: SolverSettings | None = None,
                   frame_cameras: SequenceOf[CameraIntrinsics] | None = None
                   ) -> CalibrationResult:
    """Every frame solved alone (`frame_cameras`: each frame's own intrinsics, default
    `camera`), each with its leave-out solutions (`frame_leave_outs`) and the keypoint
    jackknife they give; the reported
    extrinsic is the best-determined frame's: the smallest trace of its covariance (fit plus
    jackknife) among the frames with a jackknife (a frame too sparse for one has only its
    fit's, which understates it), among all solved frames when none has one."""
    settings = settings or SolverSettings()
    cameras = _cameras(obs, camera, frame_cameras)
    frames = solve_frames(obs, camera, settings, cameras)
    solved = [i for i, f in enumerate(frames) if isinstance(f.fit, PoseFit)]
    if not solved:
        reasons = sorted({f.fit.reason for f in frames})
        raise CalibrationError("no frame could be solved alone: " + "; ".join(reasons),
                               fix=FIX_NO_FRAME_ALONE)
    leave_outs = frame_leave_outs(obs, frames, cameras, settings)
    frames = tuple(replace(f, jackknife=_frame_jackknife(f, lo), leave_outs=lo)
                   for f, lo in zip(frames, leave_outs, strict=True))
    F, K = obs.uv.shape[:2]
    residuals = np.full((F, K, 2), np.nan)
    inlier = np.zeros((F, K), bool)
    for i in solved:
        residuals[i] = frames[i].fit.residuals_px
        inlier[i] = frames[i].fit.inlier
    candidates = [i for i in solved if frames[i].jackknife is not None] or solved
    best = frames[min(candidates, key=lambda i: _spread(frames[i].covariance))]
    return CalibrationResult("each", best.fit, frames, residuals, inlier, best.jackknife)


def _spread(covariance: np.ndarray) -> float:
    """The trace of a covariance; infinite when it is not finite (no redundancy)."""
    trace = float(np.trace(covariance))
    return trace if np.isfinite(trace) else np.inf
