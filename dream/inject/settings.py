"""`InjectionSettings`: how an injected sequence is drawn (robot, camera, motion, noise)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.sample import SampleSettings

MOTIONS = ("trajectory", "random")


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
class InjectionSettings:
    """How to draw an injected sequence. Metres, radians, seconds, pixels.

    Attributes:
        robot: built-in robot name (`dream robots`) or URDF path.
        num_frames: frames of the sequence (>= 2).
        pixel_noise_px: standard deviation of the Gaussian label noise per axis, px.
        frame_period_s: time between images, s.
        motion: "trajectory" (smooth random joint trajectory) or "random" (independent random
            configurations, still timestamped; no time offset can be injected).
        distance_m, elevation_rad, target_base_m, target_jitter_m, roll_rad: the fixed camera's
            placement (as `dream.sample.SampleSettings`): distance from an aim point near
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

    def sample_settings(self) -> SampleSettings:
        """The camera placement as `dream.sample` describes it."""
        return SampleSettings(robot=self.robot, num_frames=self.num_frames,
                              pixel_noise_px=self.pixel_noise_px, distance_m=self.distance_m,
                              elevation_rad=self.elevation_rad, target_base_m=self.target_base_m,
                              target_jitter_m=self.target_jitter_m, roll_rad=self.roll_rad,
                              joint_range_fraction=self.joint_range_fraction, fx=self.fx,
                              fy=self.fy, width=self.width, height=self.height,
                              frame_period_s=self.frame_period_s, seed=self.seed)
