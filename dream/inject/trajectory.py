"""The smooth random joint motion of an injected sequence: sums of low-frequency sinusoids."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.errors import InputError
from dream.inject.settings import InjectionSettings
from dream.robot import Robot

CENTRE_JITTER_FRACTION = 0.3           # trajectory centre within +-this share of the half range
COMPONENT_WEIGHT_RANGE = (0.3, 1.0)    # relative amplitudes of a joint's sinusoids
RELATIVE_FREQUENCY_RANGE = (0.5, 2.0)  # relative frequencies of a joint's sinusoids


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
                      spec: InjectionSettings) -> JointTrajectory:
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
