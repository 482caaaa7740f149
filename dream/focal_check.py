"""Whether the keypoints agree with the camera's focal length: a wrong fx, fy (a depth
stream's intrinsics for the colour images, a datasheet's, an image resized after calibrating)
moves a keypoint calibration's camera along its axis by as much, and the keypoint fit absorbs it
with a small residual. A fixed camera that sees the arm at several depths tells the focal
length apart from the distance: the pose and a focal-length scale are fitted together on the
fit's inlier keypoints, and the scale's 1-sigma is the larger of the fit's and a jackknife over
the keypoints (a detector's bias on one keypoint moves the scale more than its pixel noise
says).

    >>> from dream.camera import CameraIntrinsics, project
    >>> from dream.transforms import look_at, transform_points
    >>> rng = np.random.default_rng(0)
    >>> camera = CameraIntrinsics(500.0, 500.0, 319.5, 239.5, 640, 480)
    >>> T = look_at(np.array([1.5, 0.2, 0.8]), np.array([0.0, 0.0, 0.4]))
    >>> P = rng.uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (60, 3))
    >>> uv = project(camera, transform_points(T, P))
    >>> wrong = CameraIntrinsics(550.0, 550.0, 319.5, 239.5, 640, 480)
    >>> scale, _, _ = fit_focal_scale(P, uv, wrong, T)
    >>> round(scale, 3)
    0.909
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from dream.calibration import CalibrationResult, Observations
from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.keypoint_camera_fit import KeypointCameraFit, focal_columns, inlier_keypoints
from dream.pnp import increment_between
from dream.quality import CHECK, Finding

POSE_AND_SCALE = 7            # unknowns of the joint fit: the pose increment and log(scale)
MAX_LOG_STEP = 1.0            # a Gauss-Newton step of log(scale) beyond this: no answer


@dataclass(frozen=True)
class FocalCheckSettings:
    """The focal check's constants (set on renders: `benchmarks/focal_check.py`).

    Attributes:
        tolerance: a scale within this of 1 is no finding, however significant (a lens's
            focal length is known to a few per cent); where nothing else checks the focal
            length, the move through the asked scale enters the 1-sigma all the same
            (`dream.cli.intrinsics_records.with_keypoint_intrinsics`).
        z: a scale farther from 1 than `tolerance` is a finding only this many 1-sigmas away.
        iterations: Gauss-Newton steps of the joint fit.
        min_keypoints: fewer inlier keypoints: no check.
        min_groups: the jackknife leaves out one keypoint name at a time; fewer names seen:
            the fit's 1-sigma alone.
    """

    tolerance: float = 0.04
    z: float = 3.0
    iterations: int = 20
    min_keypoints: int = 20
    min_groups: int = 3

    def __post_init__(self) -> None:
        if not (0 < self.tolerance < 1 and self.z > 0 and self.iterations > 0
                and self.min_keypoints > POSE_AND_SCALE and self.min_groups >= 2):
            raise InputError(f"invalid FocalCheckSettings {self}")


@dataclass(frozen=True)
class KeypointFocal:
    """The focal-length scale the keypoints ask for (1: the given one), the 1-sigma of its
    log, and `xi` (6,): the move (xi of `dream.pnp`) from the result's pose to the pose
    fitted with the asked scale (None: not known)."""

    scale: float
    sigma: float
    sigma_fit: float
    sigma_jackknife: float | None
    keypoints: int
    xi: np.ndarray | None = None

    def beyond_limit(self, settings: FocalCheckSettings = FocalCheckSettings()) -> bool:
        """Whether the asked scale lies more than `tolerance` from 1."""
        return abs(math.log(self.scale)) > math.log1p(settings.tolerance)

    def unresolved(self, settings: FocalCheckSettings = FocalCheckSettings()) -> bool:
        """A scale beyond the limit within `z` 1-sigmas of 1: the keypoints can tell neither
        that the given focal length is wrong nor that it is right."""
        return self.beyond_limit(settings) and abs(math.log(self.scale)) <= \
            settings.z * self.sigma

    def to_dict(self, settings: FocalCheckSettings = FocalCheckSettings()) -> dict[str, Any]:
        return {"scale": self.scale, "sigma": self.sigma, "sigma_fit": self.sigma_fit,
                "sigma_jackknife": self.sigma_jackknife, "keypoints": self.keypoints,
                "beyond_limit": self.beyond_limit(settings),
                "unresolved": self.unresolved(settings),
                "xi_asked": None if self.xi is None else self.xi.tolist()}


def fit_focal_scale(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                    T_cam_base: np.ndarray, iterations: int = 20
                    ) -> tuple[float, float, np.ndarray]:
    """The pose and focal-length scale s (fx, fy times s) that fit `uv` (N, 2) best, from
    `T_cam_base`: returns (s, the fit's 1-sigma of log s, the pose); (NaN, inf, the start)
    where the fit has no answer (`KeypointCameraFit.fit`)."""
    fitted = focal_fit(iterations).fit(P_base, uv, camera, T_cam_base)
    if fitted is None:
        return math.nan, math.inf, np.asarray(T_cam_base, float)
    log_s, covariance, T = fitted
    return math.exp(float(log_s[0])), math.sqrt(float(covariance[0, 0])), T


def focal_fit(iterations: int = 20) -> KeypointCameraFit:
    """The joint fit over (pose, log s)."""
    return KeypointCameraFit(_scaled, 1, focal_columns, MAX_LOG_STEP, iterations)


def keypoint_focal(result: CalibrationResult, obs: Observations, camera: CameraIntrinsics,
                   settings: FocalCheckSettings = FocalCheckSettings()) -> KeypointFocal | None:
    """The focal scale of an all-frames result's inlier keypoints (None: too few, another
    mode, or no answer from the fit or from one of its leave-one-name-out fits)."""
    points = inlier_keypoints(result, obs, settings.min_keypoints)
    if points is None:
        return None
    P, uv, names = points
    estimate = focal_fit(settings.iterations).estimate(P, uv, names, camera, result.T_cam_base,
                                                       settings.min_groups)
    if estimate is None:
        return None
    log_s, sigma_fit, jackknife, T_asked = estimate
    sigma_jackknife = None if jackknife is None else float(jackknife[0])
    return KeypointFocal(math.exp(float(log_s[0])), max(float(sigma_fit[0]),
                                                        sigma_jackknife or 0.0),
                         float(sigma_fit[0]), sigma_jackknife, len(P),
                         increment_between(result.T_cam_base, T_asked))


def keypoint_focal_finding(focal: KeypointFocal | None, camera: CameraIntrinsics,
                           settings: FocalCheckSettings = FocalCheckSettings()
                           ) -> Finding | None:
    """`check` where the keypoints ask for a focal length more than `tolerance` and `z`
    1-sigmas from the given one; None where they agree (or there was no check).

    >>> camera = CameraIntrinsics(300.0, 300.0, 159.5, 119.5, 320, 240)
    >>> keypoint_focal_finding(KeypointFocal(1.02, 0.004, 0.004, None, 200), camera) is None
    True
    >>> keypoint_focal_finding(KeypointFocal(0.91, 0.01, 0.005, 0.01, 200), camera)[0]
    'check'
    """
    if focal is None or not focal.beyond_limit(settings) or focal.unresolved(settings):
        return None
    return CHECK, (f"the keypoints fit best with a focal length x{focal.scale:.3f} the given "
                   f"one (+-{focal.sigma * 100:.1f} %): fx, fy {camera.fx * focal.scale:.1f}, "
                   f"{camera.fy * focal.scale:.1f} instead of {camera.fx:.1f}, "
                   f"{camera.fy:.1f}; a wrong focal length moves the camera along its axis "
                   "by as much (centimetres): check the intrinsics (a depth stream's for the "
                   "colour images? an image resized or cropped after calibrating?)")


def _scaled(camera: CameraIntrinsics, log_s: np.ndarray) -> CameraIntrinsics:
    from dream.coarse.focal import with_focal_scale

    return with_focal_scale(camera, math.exp(float(log_s[0])))
