"""Effect injection: measured-like keypoint-only sequences of a world that differs from the model.

The "true world" is the nominal robot and camera changed by a `ModelExtension`
(`dream.extension`); the written data is what a user would log from it, so `dream diagnose`
can be tested against a known answer:

- labels (`Frame.uv_labels`): the TRUE keypoints (joint offsets, link lengths, keypoint bias, at
  the true joint values of the image time) projected through the TRUE camera (corrected
  intrinsics, distortion) from the TRUE per-frame extrinsic (after a camera move
  `T_cam_base_after = dT @ T_cam_base_before`), plus Gaussian pixel noise; labels outside the
  image are NaN.
- joints (`Frame.joints`): the joint READINGS, without the offsets; with a time offset tau the
  reading stamped at image time t is the reading signal at t - tau (the readings lag), so
  `effective_joints(readings, times, tau)` recovers the signal at the image times.
- camera (`Sequence.camera`): the NOMINAL camera (the intrinsics the user believes, no
  distortion).
- `Frame.timestamp`: the image times, s; `Frame.T_cam_base_true`: the true per-frame extrinsic;
  `Sequence.T_cam_base_reference`: None.

The motion is a smooth random joint trajectory (sums of low-frequency sinusoids; needed for a
time offset) or independent random configurations. The camera, the motion and the pixel noise
are drawn from `spec.seed` alone, in that order, so two extensions injected with one seed differ
only by their effects.

`random_effect` draws one effect of the vocabulary with a realistic random magnitude
(`EFFECT_RANGES`); `random_effects` merges several. Units: metres, radians, seconds, pixels.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.errors import InputError
from dream.extension import (
    EFFECT_NAMES,
    CameraMove,
    ModelExtension,
    extended_camera,
    extended_points,
    frames_after_move,
)
from dream.robot import Robot, load_robot
from dream.robot.tree import MIN_OFFSET_M
from dream.sample import SampleSpec, random_camera_pose, random_joints
from dream.sequence import Frame, Sequence
from dream.transforms import skew, transform_points

MOTIONS = ("trajectory", "random")

# ----- trajectory shape ------------------------------------------------------------------------
CENTRE_JITTER_FRACTION = 0.3           # trajectory centre within +-this share of the half range
COMPONENT_WEIGHT_RANGE = (0.3, 1.0)    # relative amplitudes of a joint's sinusoids
RELATIVE_FREQUENCY_RANGE = (0.5, 2.0)  # relative frequencies of a joint's sinusoids

# ----- realistic effect magnitudes (drawn uniformly in these ranges, random sign/direction) ----
JOINT_OFFSET_RANGE_RAD = (math.radians(0.5), math.radians(3.0))  # on one identifiable joint
DISTORTION_K1_RANGE = (0.03, 0.2)                 # |k1| of plumb_bob; k2 = p1 = p2 = 0
FOCAL_ERROR_RANGE = (0.01, 0.05)                  # |true / nominal - 1| of fx and fy (same)
TIME_OFFSET_RANGE_S = (0.020, 0.150)              # |readings lag|, s
LINK_LENGTH_RANGE_M = (0.005, 0.020)              # |metres added| along one joint's origin
CAMERA_TRANSLATION_RANGE_M = (0.005, 0.020)       # camera_moved: translation, random direction
CAMERA_ROTATION_RANGE_RAD = (math.radians(0.5), math.radians(2.0))  # ... or rotation
CAMERA_MOVE_FRAME_FRACTION = (0.2, 0.8)           # the move happens in the middle 60 % of frames
CAMERA_MOVE_ROTATION_PROB = 0.5                   # chance that a camera move is a rotation
KEYPOINT_BIAS_RANGE_M = (0.010, 0.030)            # |offset| on one keypoint, random direction

EFFECT_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "joint_offset": {"offset_rad": JOINT_OFFSET_RANGE_RAD},
    "lens_distortion": {"abs_k1": DISTORTION_K1_RANGE},
    "intrinsics_error": {"abs_focal_error_fraction": FOCAL_ERROR_RANGE},
    "time_offset": {"abs_seconds": TIME_OFFSET_RANGE_S},
    "link_length": {"abs_metres": LINK_LENGTH_RANGE_M},
    "camera_moved": {"translation_m": CAMERA_TRANSLATION_RANGE_M,
                     "rotation_rad": CAMERA_ROTATION_RANGE_RAD,
                     "frame_fraction": CAMERA_MOVE_FRAME_FRACTION},
    "keypoint_bias": {"metres": KEYPOINT_BIAS_RANGE_M},
}

# ----- identifiability probes ------------------------------------------------------------------
PROBE_SEED = 20240611            # fixed: the probes never draw from the caller's rng
PROBE_CONFIGS = 16               # random configurations the probes look at
PROBE_RANGE_FRACTION = 0.8       # ... drawn in this central part of the joint limits
PROBE_STRETCH_M = 1e-3           # finite-difference step of a link length change, m
MIN_KEYPOINT_MOTION = 1e-3       # RMS keypoint motion per unit change (m/rad, m/m) to count
MIN_NON_RIGID_FRACTION = 0.05    # share of that motion a fixed extrinsic must fail to explain


def _pair(value, what: str, lo_limit: float = -math.inf, hi_limit: float = math.inf,
          strict_lower: bool = False) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a [low, high] pair of numbers, got {value!r}") from None
    low_ok = lo > lo_limit if strict_lower else lo >= lo_limit
    if not (math.isfinite(lo) and math.isfinite(hi) and low_ok and lo <= hi <= hi_limit):
        raise InputError(f"{what} = [{lo}, {hi}] must satisfy {lo_limit} "
                         f"{'<' if strict_lower else '<='} low <= high <= {hi_limit}")
    return lo, hi


@dataclass(frozen=True)
class InjectionSpec:
    """How to draw an injected sequence. Metres, radians, seconds, pixels.

    Attributes:
        robot: built-in robot name (`dream robots`) or URDF path.
        num_frames: frames of the sequence (>= 2).
        pixel_noise_px: standard deviation of the Gaussian label noise per axis, px.
        frame_period_s: time between images, s.
        motion: "trajectory" (smooth random joint trajectory) or "random" (independent random
            configurations, still timestamped; no time offset can be injected).
        distance_m, elevation_rad, target_base_m, target_jitter_m, roll_rad: the fixed camera's
            placement (as `dream.sample.SampleSpec`): distance from an aim point near
            `target_base_m` (jittered per axis by up to `target_jitter_m`), elevation above the
            base's horizontal plane, roll about the optical axis up to +-`roll_rad`.
        joint_range_fraction: the motion stays in this central part of each joint's range.
        trajectory_components: sinusoids summed per joint.
        peak_speed_rad_s: per joint, the bound on its speed (sum of the components' peak
            speeds) is drawn in this range, rad/s.
        max_amplitude_rad: largest total excursion of a joint from its centre, rad (keeps
            continuous joints of +-2 pi from spinning around).
        width, height, fx, fy: the nominal camera (principal point at the image centre), px.
        seed: every random draw of the sequence comes from it.
    """

    robot: str = "panda"
    num_frames: int = 100
    pixel_noise_px: float = 1.5
    frame_period_s: float = 0.1
    motion: str = "trajectory"
    distance_m: tuple[float, float] = (1.2, 2.0)
    elevation_rad: tuple[float, float] = (math.radians(5.0), math.radians(45.0))
    target_base_m: tuple[float, float, float] = (0.0, 0.0, 0.4)
    target_jitter_m: float = 0.1
    roll_rad: float = math.radians(10.0)
    joint_range_fraction: float = 0.7
    trajectory_components: int = 3
    peak_speed_rad_s: tuple[float, float] = (0.5, 1.5)
    max_amplitude_rad: float = 1.5
    width: int = 640
    height: int = 480
    fx: float = 600.0
    fy: float = 600.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.robot, str) or not self.robot:
            raise InputError("robot must be a robot name or URDF path",
                             fix="e.g. robot='panda' (see dream robots)")
        for name in ("num_frames", "trajectory_components", "width", "height", "seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise InputError(f"{name} must be a whole number, got {value!r}")
            object.__setattr__(self, name, int(value))
        if self.num_frames < 2:
            raise InputError(f"num_frames must be >= 2, got {self.num_frames}",
                             fix="give a sequence of at least 2 frames")
        if self.trajectory_components < 1:
            raise InputError("trajectory_components must be >= 1")
        if self.width < 1 or self.height < 1:
            raise InputError(f"image size must be positive, got {self.width}x{self.height}")
        for name, positive in (("pixel_noise_px", False), ("frame_period_s", True),
                               ("target_jitter_m", False), ("roll_rad", False),
                               ("max_amplitude_rad", True), ("fx", True), ("fy", True)):
            value = getattr(self, name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise InputError(f"{name} must be a number, got {value!r}") from None
            if not math.isfinite(value) or value < 0 or (positive and value == 0):
                raise InputError(f"{name} = {value} must be a finite number "
                                 f"{'> 0' if positive else '>= 0'}")
            object.__setattr__(self, name, value)
        if self.motion not in MOTIONS:
            raise InputError(f"motion '{self.motion}' is unknown",
                             fix=f"use one of {', '.join(MOTIONS)}")
        object.__setattr__(self, "distance_m", _pair(self.distance_m, "distance_m", 0.0,
                                                     strict_lower=True))
        object.__setattr__(self, "elevation_rad", _pair(self.elevation_rad, "elevation_rad",
                                                        -math.pi / 2, math.pi / 2,
                                                        strict_lower=True))
        object.__setattr__(self, "peak_speed_rad_s", _pair(self.peak_speed_rad_s,
                                                           "peak_speed_rad_s", 0.0,
                                                           strict_lower=True))
        if len(self.target_base_m) != 3 or not all(math.isfinite(float(v))
                                                   for v in self.target_base_m):
            raise InputError(f"target_base_m must be 3 finite metres, got {self.target_base_m}")
        object.__setattr__(self, "target_base_m", tuple(float(v) for v in self.target_base_m))
        if not 0 < self.joint_range_fraction <= 1:
            raise InputError(f"joint_range_fraction must be in (0, 1], got "
                             f"{self.joint_range_fraction}")

    @property
    def camera(self) -> CameraIntrinsics:
        """The nominal camera: what the user believes (and what is written)."""
        return CameraIntrinsics(self.fx, self.fy, (self.width - 1) / 2, (self.height - 1) / 2,
                                self.width, self.height)

    @property
    def times_s(self) -> np.ndarray:
        """(F,) image times, s."""
        return np.arange(self.num_frames) * self.frame_period_s

    @property
    def frame_names(self) -> tuple[str, ...]:
        return tuple(f"{i:06d}" for i in range(self.num_frames))

    def sample_spec(self) -> SampleSpec:
        """The camera placement as `dream.sample` describes it."""
        return SampleSpec(robot=self.robot, num_frames=self.num_frames,
                          pixel_noise_px=self.pixel_noise_px, distance_m=self.distance_m,
                          elevation_rad=self.elevation_rad, target_base_m=self.target_base_m,
                          target_jitter_m=self.target_jitter_m, roll_rad=self.roll_rad,
                          joint_range_fraction=self.joint_range_fraction, fx=self.fx,
                          fy=self.fy, width=self.width, height=self.height,
                          frame_period_s=self.frame_period_s, seed=self.seed)


# ----- motion ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class JointTrajectory:
    """q_j(t) = centre_j + sum_m amplitude_jm * sin(2 pi frequency_jm t + phase_jm).

    Attributes:
        centre: (J,) rad. amplitude: (J, M) rad (>= 0). frequency_hz: (J, M) Hz (> 0).
        phase_rad: (J, M) rad.
    """

    centre: np.ndarray
    amplitude: np.ndarray
    frequency_hz: np.ndarray
    phase_rad: np.ndarray

    def __post_init__(self) -> None:
        centre = np.array(self.centre, dtype=float)
        if centre.ndim != 1:
            raise InputError(f"trajectory centre must be (J,), got shape {centre.shape}")
        shape = None
        for name in ("amplitude", "frequency_hz", "phase_rad"):
            a = np.array(getattr(self, name), dtype=float)
            if a.ndim != 2 or a.shape[0] != len(centre) or (shape and a.shape != shape):
                raise InputError(f"trajectory {name} must be (J={len(centre)}, M), got "
                                 f"shape {a.shape}")
            shape = a.shape
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        if not (np.all(np.isfinite(centre)) and np.all(np.isfinite(self.amplitude))
                and np.all(np.isfinite(self.frequency_hz)) and np.all(np.isfinite(self.phase_rad))):
            raise InputError("trajectory parameters must be finite")
        if np.any(self.amplitude < 0) or np.any(self.frequency_hz <= 0):
            raise InputError("trajectory amplitudes must be >= 0 and frequencies > 0")
        centre.setflags(write=False)
        object.__setattr__(self, "centre", centre)

    @property
    def peak_speed_bound(self) -> np.ndarray:
        """(J,) upper bound of each joint's speed, rad/s."""
        return np.sum(2 * np.pi * self.frequency_hz * self.amplitude, axis=1)


def trajectory_joints(trajectory: JointTrajectory, times_s: np.ndarray) -> np.ndarray:
    """(T,) times, s -> (T, J) joint values of the trajectory, rad."""
    t = np.asarray(times_s, dtype=float)
    if t.ndim != 1:
        raise InputError(f"times must be (T,), got shape {t.shape}")
    angle = 2 * np.pi * trajectory.frequency_hz * t[:, None, None] + trajectory.phase_rad
    return trajectory.centre + np.sum(trajectory.amplitude * np.sin(angle), axis=-1)


def random_trajectory(rng: np.random.Generator, robot: Robot,
                      spec: InjectionSpec) -> JointTrajectory:
    """A smooth random trajectory inside the central `spec.joint_range_fraction` of the limits.

    Per joint: a centre near the middle of the range, a total amplitude that reaches (but does
    not leave) that central part, split over `trajectory_components` sinusoids of random
    relative frequencies, scaled so that the speed bound is a draw of `spec.peak_speed_rad_s`.
    """
    J, M = robot.num_joints, spec.trajectory_components
    mid = (robot.joint_lower + robot.joint_upper) / 2
    half = (robot.joint_upper - robot.joint_lower) / 2 * spec.joint_range_fraction
    centre = mid + rng.uniform(-1, 1, J) * half * CENTRE_JITTER_FRACTION
    total = np.minimum(half - np.abs(centre - mid), spec.max_amplitude_rad)
    weights = rng.uniform(*COMPONENT_WEIGHT_RANGE, (J, M))
    amplitude = total[:, None] * weights / weights.sum(axis=1, keepdims=True)
    relative = rng.uniform(*RELATIVE_FREQUENCY_RANGE, (J, M))
    speed = rng.uniform(*spec.peak_speed_rad_s, J)
    raw = np.sum(2 * np.pi * relative * amplitude, axis=1)
    scale = np.where(raw > 0, speed / np.maximum(raw, np.finfo(float).tiny), 1.0)
    phase = rng.uniform(0, 2 * np.pi, (J, M))
    return JointTrajectory(centre, amplitude, relative * scale[:, None], phase)


# ----- the true world ----------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class InjectedWorld:
    """The true world behind an injected sequence and what is written from it.

    Attributes:
        spec, extension: what was asked.
        robot: the nominal robot.
        camera_nominal: written camera; camera_true: the camera the labels are projected with.
        times_s: (F,) image times, s.
        joints_at_images: (F, J) the reading signal at the image times (what
            `effective_joints(readings, times_s, tau)` should recover), rad.
        readings: (F, J) the written joint readings (lagging by the time offset), rad.
        T_cam_base: (F, 4, 4) the true extrinsic of each frame.
        P_base: (F, K, 3) the true keypoints in the base frame, m.
        uv_true: (F, K, 2) their noise-free projections through the true camera, px.
        uv_labels: (F, K, 2) the written labels: noisy, NaN outside the image, px.
        trajectory: the motion when `spec.motion == "trajectory"`, else None.
    """

    spec: InjectionSpec
    extension: ModelExtension
    robot: Robot
    camera_nominal: CameraIntrinsics
    camera_true: CameraIntrinsics
    times_s: np.ndarray
    joints_at_images: np.ndarray
    readings: np.ndarray
    T_cam_base: np.ndarray
    P_base: np.ndarray
    uv_true: np.ndarray
    uv_labels: np.ndarray
    trajectory: JointTrajectory | None


def check_extension(spec: InjectionSpec, robot: Robot, extension: ModelExtension) -> None:
    """Refuse an extension this spec cannot inject (InputError)."""
    if not isinstance(extension, ModelExtension):
        raise InputError("extension must be a dream.extension.ModelExtension",
                         fix="use ModelExtension() for the nominal world")
    if extension.robot and extension.robot != robot.name:
        raise InputError(f"the extension is for robot '{extension.robot}', the spec's robot is "
                         f"'{robot.name}'", fix="inject an extension of this robot")
    if extension.time_offset_s and spec.motion != "trajectory":
        raise InputError("a time offset needs a continuous motion",
                         fix="use motion='trajectory' to inject time_offset")


def frame_poses(T_cam_base_before: np.ndarray, after: np.ndarray,
                extension: ModelExtension) -> np.ndarray:
    """(F, 4, 4) true extrinsic per frame: dT @ T from the camera move on (`after`), else T.

    Args:
        T_cam_base_before: (4, 4) extrinsic before the move. after: (F,) bool.
    """
    T = np.asarray(T_cam_base_before, dtype=float)
    after = np.asarray(after, dtype=bool)
    if T.shape != (4, 4) or after.ndim != 1:
        raise InputError(f"frame_poses needs T (4, 4) and after (F,), got {T.shape}, "
                         f"{after.shape}")
    poses = np.broadcast_to(T, (len(after), 4, 4)).copy()
    if extension.camera_moved is not None:
        poses[after] = extension.camera_moved.T_after_before @ T
    return poses


def noisy_labels(uv_true: np.ndarray, noise_px: np.ndarray,
                 camera: CameraIntrinsics) -> np.ndarray:
    """(F, K, 2) labels: projections plus noise, NaN where outside the image (or behind)."""
    uv = np.asarray(uv_true, dtype=float) + np.asarray(noise_px, dtype=float)
    if uv.shape[-1:] != (2,):
        raise InputError(f"labels must be (..., 2), got shape {uv.shape}")
    inside = camera.in_image(uv) & np.all(np.isfinite(uv), -1)
    return np.where(inside[..., None], uv, np.nan)


def inject(spec: InjectionSpec, extension: ModelExtension | None = None) -> InjectedWorld:
    """The true world of `spec` changed by `extension` (None: nominal), deterministic in
    `spec.seed` (camera, then motion, then noise, whatever the extension)."""
    extension = ModelExtension() if extension is None else extension
    robot = load_robot(spec.robot)
    check_extension(spec, robot, extension)
    rng = np.random.default_rng(spec.seed)
    T_before = random_camera_pose(rng, spec.sample_spec())
    times = spec.times_s
    tau = extension.time_offset_s or 0.0
    trajectory = None
    if spec.motion == "trajectory":
        trajectory = random_trajectory(rng, robot, spec)
        joints_at_images = trajectory_joints(trajectory, times)
        readings = trajectory_joints(trajectory, times - tau)
    else:
        joints_at_images = random_joints(rng, robot, spec.num_frames, spec.joint_range_fraction)
        readings = joints_at_images
    noise = rng.normal(0.0, spec.pixel_noise_px, (spec.num_frames, robot.num_keypoints, 2))
    kinematic = dataclasses.replace(extension, time_offset_s=None)  # joints already at images
    P_base = extended_points(robot, joints_at_images, times, kinematic)
    T_cam_base = frame_poses(T_before, frames_after_move(spec.frame_names, extension), extension)
    camera_true = extended_camera(spec.camera, extension)
    uv_true = project(camera_true, transform_points(T_cam_base[:, None], P_base))
    return InjectedWorld(spec, extension, robot, spec.camera, camera_true, times,
                         joints_at_images, readings, T_cam_base, P_base, uv_true,
                         noisy_labels(uv_true, noise, camera_true), trajectory)


def sequence_of(world: InjectedWorld) -> Sequence:
    """What a user would log from the world: readings, labels, nominal camera, image times."""
    frames = tuple(
        Frame(name=name, joints=world.readings[i], timestamp=float(world.times_s[i]),
              uv_labels=world.uv_labels[i], T_cam_base_true=world.T_cam_base[i])
        for i, name in enumerate(world.spec.frame_names))
    return Sequence(robot=world.robot.name, camera=world.camera_nominal,
                    joint_names=world.robot.joint_names,
                    keypoint_names=world.robot.keypoint_names, frames=frames,
                    T_cam_base_reference=None)


def make_injected_sequence(spec: InjectionSpec,
                           extension: ModelExtension | None = None) -> Sequence:
    """A measured-like keypoint-only sequence of the world `extension` describes (module doc).

    Write it with `dream.io.write_dream(sequence, folder)`."""
    return sequence_of(inject(spec, extension))


# ----- which effects a fixed camera can see ------------------------------------------------

def rigid_motion_residual(dP: np.ndarray, P: np.ndarray) -> float:
    """Share of a keypoint motion that no constant rigid motion of the base frame explains.

    Fits dP ~ w x P + v (one small rotation w and translation v for all configurations and
    keypoints: what a fixed extrinsic absorbs) by least squares.

    Args:
        dP: (C, K, 3) motion of the keypoints per unit change. P: (C, K, 3) keypoints, m.
    Returns:
        ||residual|| / ||dP|| in [0, 1] (0 when dP is zero).
    """
    dP, P = np.asarray(dP, dtype=float), np.asarray(P, dtype=float)
    if dP.shape != P.shape or dP.shape[-1:] != (3,):
        raise InputError(f"dP {dP.shape} and P {P.shape} must both be (..., 3)")
    b = dP.reshape(-1)
    norm = float(np.linalg.norm(b))
    if norm == 0.0:
        return 0.0
    points = P.reshape(-1, 3)
    A = np.concatenate([-skew(points), np.broadcast_to(np.eye(3), (len(points), 3, 3))], axis=2)
    A = A.reshape(-1, 6)
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    return float(np.linalg.norm(A @ x - b) / norm)


def _probe_joints(robot: Robot) -> np.ndarray:
    return random_joints(np.random.default_rng(PROBE_SEED), robot, PROBE_CONFIGS,
                         PROBE_RANGE_FRACTION)


def _visible_change(dP: np.ndarray, P: np.ndarray) -> bool:
    rms = float(np.sqrt(np.mean(np.sum(dP ** 2, axis=-1))))
    return rms >= MIN_KEYPOINT_MOTION and rigid_motion_residual(dP, P) >= MIN_NON_RIGID_FRACTION


def identifiable_joints(robot: Robot) -> tuple[str, ...]:
    """Joints whose offset a fixed camera can tell from the extrinsic: the keypoints move
    (non-zero `keypoint_jacobian` column) and not as one rigid body (for a fixed-base arm the
    first joint only turns everything about its axis, which the extrinsic absorbs)."""
    q = _probe_joints(robot)
    P = robot.forward_kinematics(q)
    jac = robot.keypoint_jacobian(q)
    return tuple(name for j, name in enumerate(robot.joint_names)
                 if _visible_change(jac[..., j], P))


def stretchable_joints(robot: Robot) -> tuple[str, ...]:
    """Joints (fixed ones too) on the chains to the keypoints whose origin offset is non-zero
    and whose length change moves the keypoints in a way the extrinsic cannot absorb."""
    q = _probe_joints(robot)
    P = robot.forward_kinematics(q)
    out = []
    for joint in robot.chain_joints:
        if np.linalg.norm(joint.origin[:3, 3]) < max(MIN_OFFSET_M, PROBE_STRETCH_M):
            continue
        stretched = robot.with_link_length_changes({joint.name: PROBE_STRETCH_M})
        dP = (stretched.forward_kinematics(q) - P) / PROBE_STRETCH_M
        if _visible_change(dP, P):
            out.append(joint.name)
    return tuple(out)


def moving_keypoints(robot: Robot) -> tuple[str, ...]:
    """Keypoints that move with the joints. A keypoint that never moves (the base link's)
    projects to one pixel of a fixed camera in every frame, so the component of its bias along
    the viewing ray is unobservable: `dream diagnose` reports it as not identifiable, and such
    a bias is not drawn here (its truth could not be compared in 3D)."""
    q = _probe_joints(robot)
    P = robot.forward_kinematics(q)
    spread = np.sqrt(np.mean(np.sum((P - P.mean(axis=0)) ** 2, axis=-1), axis=0))
    return tuple(k for k, s in zip(robot.keypoint_names, spread, strict=True)
                 if s >= MIN_KEYPOINT_MOTION)


# ----- random effects --------------------------------------------------------------------

def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def _direction(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random unit vector (3,)."""
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _pick(rng: np.random.Generator, names: SequenceOf[str], what: str, robot: Robot) -> str:
    if not names:
        raise InputError(f"robot '{robot.name}' has no {what}",
                         fix="inject another effect for this robot")
    return names[int(rng.integers(len(names)))]


def random_effect(effect_name: str, rng: np.random.Generator, robot: Robot,
                  spec: InjectionSpec) -> ModelExtension:
    """One effect of the vocabulary with a random magnitude in `EFFECT_RANGES`, random sign or
    direction, for `robot` seen as `spec` describes (camera_moved: a frame in the middle of
    `spec`'s frames; intrinsics_error: `spec`'s focal lengths scaled)."""
    if effect_name not in EFFECT_NAMES:
        raise InputError(f"unknown effect '{effect_name}'",
                         fix=f"use one of {', '.join(EFFECT_NAMES)}")
    if not isinstance(robot, Robot):
        raise InputError("random_effect needs a dream Robot (dream.robot.load_robot)")
    name = robot.name
    if effect_name == "joint_offset":
        joint = _pick(rng, identifiable_joints(robot), "identifiable joint", robot)
        value = _sign(rng) * rng.uniform(*JOINT_OFFSET_RANGE_RAD)
        return ModelExtension(joint_offset_rad={joint: value}, robot=name)
    if effect_name == "lens_distortion":
        k1 = _sign(rng) * rng.uniform(*DISTORTION_K1_RANGE)
        return ModelExtension(distortion=(k1, 0.0, 0.0, 0.0), robot=name)
    if effect_name == "intrinsics_error":
        scale = 1.0 + _sign(rng) * rng.uniform(*FOCAL_ERROR_RANGE)
        camera = spec.camera
        return ModelExtension(intrinsics=(camera.fx * scale, camera.fy * scale, camera.cx,
                                          camera.cy), robot=name)
    if effect_name == "time_offset":
        if spec.motion != "trajectory":
            raise InputError("a time offset needs a continuous motion",
                             fix="use motion='trajectory' to inject time_offset")
        return ModelExtension(time_offset_s=_sign(rng) * rng.uniform(*TIME_OFFSET_RANGE_S),
                              robot=name)
    if effect_name == "link_length":
        joint = _pick(rng, stretchable_joints(robot), "joint with a stretchable offset", robot)
        value = _sign(rng) * rng.uniform(*LINK_LENGTH_RANGE_M)
        return ModelExtension(link_length_m={joint: value}, robot=name)
    if effect_name == "camera_moved":
        first, last = CAMERA_MOVE_FRAME_FRACTION
        lo = max(1, math.ceil(first * spec.num_frames))
        hi = min(spec.num_frames - 1, max(lo, math.floor(last * spec.num_frames)))
        frame = spec.frame_names[int(rng.integers(lo, hi + 1))]
        if rng.random() < CAMERA_MOVE_ROTATION_PROB:
            move = CameraMove(frame, rotation_rad=_direction(rng)
                              * rng.uniform(*CAMERA_ROTATION_RANGE_RAD))
        else:
            move = CameraMove(frame, translation_m=_direction(rng)
                              * rng.uniform(*CAMERA_TRANSLATION_RANGE_M))
        return ModelExtension(camera_moved=move, robot=name)
    # keypoint_bias
    keypoint = _pick(rng, moving_keypoints(robot), "moving keypoint", robot)
    offset = _direction(rng) * rng.uniform(*KEYPOINT_BIAS_RANGE_M)
    return ModelExtension(keypoint_bias_m={keypoint: offset}, robot=name)


def random_effects(names: SequenceOf[str], rng: np.random.Generator, robot: Robot,
                   spec: InjectionSpec) -> ModelExtension:
    """Several effects (each drawn by `random_effect`, in order) merged into one extension."""
    if isinstance(names, str):
        names = (names,)
    names = tuple(names)
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InputError(f"effects repeat: {', '.join(repeated)}", fix="name each effect once")
    out = ModelExtension(robot=robot.name)
    for effect in names:
        out = out.merged(random_effect(effect, rng, robot, spec))
    return out
