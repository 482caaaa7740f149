"""Built-in synthetic sample: keypoint-only measured-like sequences (no rendering).

A fixed camera on a shell around the robot looks at it; the robot takes random joint
configurations; the 2D labels are the true projections plus Gaussian pixel noise, and optionally
some labels are replaced by uniformly random pixels (outliers). Ground truth is exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.errors import InputError
from dream.robot import Robot, load_robot
from dream.sequence import Frame, Sequence
from dream.transforms import look_at, transform_points


@dataclass(frozen=True)
class SampleSettings:
    """How to draw a sample sequence. Metres, radians, pixels, seconds."""

    robot: str = "panda"
    keypoints: tuple[str, ...] | None = None   # keypoint links (None: the built-in robot's)
    num_frames: int = 20
    pixel_noise_px: float = 1.0
    outlier_fraction: float = 0.0
    distance_m: tuple[float, float] = (1.0, 2.0)
    elevation_rad: tuple[float, float] = (np.deg2rad(5.0), np.deg2rad(50.0))
    target_base_m: tuple[float, float, float] = (0.0, 0.0, 0.4)  # camera aims near this point
    target_jitter_m: float = 0.1
    roll_rad: float = np.deg2rad(10.0)
    joint_range_fraction: float = 0.8   # joints uniform in this central part of their range
    fx: float = 600.0
    fy: float = 600.0
    width: int = 640
    height: int = 480
    frame_period_s: float = 0.1
    seed: int = 0

    def __post_init__(self) -> None:
        if self.keypoints is not None:
            if isinstance(self.keypoints, str) or not self.keypoints or not all(
                    isinstance(k, str) and k for k in self.keypoints):
                raise InputError(f"keypoints must be link names, got {self.keypoints!r}")
            object.__setattr__(self, "keypoints", tuple(self.keypoints))
        if isinstance(self.num_frames, bool) or not isinstance(self.num_frames, (int, np.integer)) \
                or self.num_frames < 1:
            raise InputError(f"num_frames must be a whole number >= 1, got {self.num_frames!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or self.seed < 0:
            raise InputError(f"seed must be a whole number >= 0, got {self.seed!r}")
        if not math.isfinite(self.outlier_fraction) or not 0.0 <= self.outlier_fraction <= 1.0:
            raise InputError(f"outlier_fraction must be in [0, 1], got {self.outlier_fraction}")
        if not math.isfinite(self.pixel_noise_px) or self.pixel_noise_px < 0:
            raise InputError(f"pixel_noise_px must be a finite number >= 0, got "
                             f"{self.pixel_noise_px}")
        lo, hi = self.distance_m
        if not 0 < lo <= hi:
            raise InputError(f"distance_m must be an increasing pair of positive metres, got "
                             f"{self.distance_m}")
        if not 0 < self.joint_range_fraction <= 1:
            raise InputError("joint_range_fraction must be in (0, 1]")

    @property
    def camera(self) -> CameraIntrinsics:
        return CameraIntrinsics(self.fx, self.fy, (self.width - 1) / 2, (self.height - 1) / 2,
                                self.width, self.height)


def random_camera_pose(rng: np.random.Generator, spec: SampleSettings) -> np.ndarray:
    """T_cam_base on the spec's shell, aimed near the robot."""
    radius = rng.uniform(*spec.distance_m)
    azimuth = rng.uniform(0.0, 2 * np.pi)
    elevation = rng.uniform(*spec.elevation_rad)
    target = np.asarray(spec.target_base_m) + rng.uniform(-1, 1, 3) * spec.target_jitter_m
    position = target + radius * np.array([np.cos(elevation) * np.cos(azimuth),
                                           np.cos(elevation) * np.sin(azimuth),
                                           np.sin(elevation)])
    return look_at(position, target, rng.uniform(-spec.roll_rad, spec.roll_rad))


def random_joints(rng: np.random.Generator, robot: Robot, n: int,
                  range_fraction: float = 1.0) -> np.ndarray:
    """(n, J) joint vectors uniform in the central `range_fraction` of each joint's limits."""
    mid = (robot.joint_lower + robot.joint_upper) / 2
    half = (robot.joint_upper - robot.joint_lower) / 2 * range_fraction
    return rng.uniform(mid - half, mid + half, size=(n, len(robot.joint_names)))


def make_sample(spec: SampleSettings) -> Sequence:
    """A keypoint-only sequence with noisy labels and exact ground truth."""
    rng = np.random.default_rng(spec.seed)
    robot = load_robot(spec.robot, spec.keypoints)
    camera = spec.camera
    T_cam_base = random_camera_pose(rng, spec)
    joints = random_joints(rng, robot, spec.num_frames, spec.joint_range_fraction)
    P_cam = transform_points(T_cam_base, robot.forward_kinematics(joints))
    uv_true = project(camera, P_cam)
    uv = uv_true + rng.normal(0.0, spec.pixel_noise_px, uv_true.shape)
    outlier = rng.random(uv.shape[:2]) < spec.outlier_fraction
    random_px = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], uv.shape)
    uv = np.where(outlier[..., None], random_px, uv)
    frames = tuple(
        Frame(name=f"{i:06d}", joints=joints[i], timestamp=i * spec.frame_period_s,
              uv_labels=uv[i], P_cam_labels=P_cam[i], T_cam_base_true=T_cam_base)
        for i in range(spec.num_frames))
    return Sequence(robot=robot.name, camera=camera, joint_names=robot.joint_names,
                    keypoint_names=robot.keypoint_names, frames=frames,
                    T_cam_base_reference=T_cam_base)
