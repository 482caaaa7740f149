"""Whether the keypoints agree with the camera's principal point: a wrong cx, cy (the image
centre given for a calibrated camera's, an image cropped after calibrating, another stream's
intrinsics) turns a keypoint calibration's camera by about atan(shift / f), and the keypoint
fit absorbs it with a small residual. A rotation and a moved principal point shift the
keypoints alike only to first order: across a wide view and the arm's depth they differ, so
keypoints accurate enough tell them apart. The pose and the shift (du, dv) are fitted together
on the fit's inlier keypoints (`dream.keypoint_camera_fit`), and each component's 1-sigma is
the larger of the fit's and a jackknife over the keypoints' names (a detector's bias on one
keypoint moves the shift more than its pixel noise says).

    >>> from dream.camera import project
    >>> from dream.transforms import look_at, transform_points
    >>> camera = CameraIntrinsics(500.0, 500.0, 319.5, 239.5, 640, 480)
    >>> T = look_at(np.array([1.5, 0.2, 0.8]), np.array([0.0, 0.0, 0.4]))
    >>> P = np.random.default_rng(0).uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (60, 3))
    >>> seen = CameraIntrinsics(500.0, 500.0, 331.5, 231.5, 640, 480)
    >>> shift, _, _ = principal_fit().fit(P, project(seen, transform_points(T, P)), camera, T)
    >>> np.round(shift, 3).tolist()
    [12.0, -8.0]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from dream.calibration import CalibrationResult, Observations
from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.keypoint_camera_fit import KeypointCameraFit, inlier_keypoints, principal_columns
from dream.pnp import increment_between
from dream.quality import CHECK, Finding

MAX_STEP_PX = 1000.0          # a Gauss-Newton step of the shift beyond this: no answer


@dataclass(frozen=True)
class PrincipalCheckSettings:
    """The principal-point check's constants (set on renders:
    `benchmarks/keypoint_intrinsics.py`).

    Attributes:
        min_angle_rad: a shift that turns the camera by less than this agrees, however
            significant (the keypoints' own biases ask for turns this large on renders
            calibrated through their own intrinsics).
        z: a larger turn is a finding only where a component of the shift lies this many
            1-sigmas from 0.
        iterations: Gauss-Newton steps of the joint fit.
        min_keypoints: fewer inlier keypoints: no check.
        min_groups: the jackknife leaves out one keypoint name at a time; fewer names seen:
            the fit's 1-sigma alone.
    """

    min_angle_rad: float = float(np.deg2rad(1.5))
    z: float = 3.0
    iterations: int = 20
    min_keypoints: int = 20
    min_groups: int = 3

    def __post_init__(self) -> None:
        if not (0 < self.min_angle_rad < np.pi / 2 and self.z > 0 and self.iterations > 0
                and self.min_keypoints > 8 and self.min_groups >= 2):
            raise InputError(f"invalid PrincipalCheckSettings {self}")


@dataclass(frozen=True)
class KeypointPrincipal:
    """The principal-point shift (du, dv) the keypoints ask for, in pixels, its 1-sigma, how
    far it turns the camera (atan |shift / f|), and `xi` (6,): the move (xi of `dream.pnp`)
    from the result's pose to the pose fitted through the asked point (None: not known)."""

    shift_px: np.ndarray
    sigma_px: np.ndarray
    sigma_fit_px: np.ndarray
    sigma_jackknife_px: np.ndarray | None
    angle_rad: float
    keypoints: int
    xi: np.ndarray | None = None

    def beyond_limit(self, settings: PrincipalCheckSettings = PrincipalCheckSettings()) -> bool:
        """Whether the asked shift turns the camera by more than `min_angle_rad`."""
        return self.angle_rad > settings.min_angle_rad

    def unresolved(self, settings: PrincipalCheckSettings = PrincipalCheckSettings()) -> bool:
        """A turn beyond the limit with no component beyond `z` 1-sigmas: the keypoints can
        tell neither that the given point is wrong nor that it is right."""
        return self.beyond_limit(settings) and not bool(
            np.any(np.abs(self.shift_px) > settings.z * self.sigma_px))

    def to_dict(self, settings: PrincipalCheckSettings = PrincipalCheckSettings()
                ) -> dict[str, Any]:
        jackknife = self.sigma_jackknife_px
        return {"shift_px": self.shift_px.tolist(), "sigma_px": self.sigma_px.tolist(),
                "sigma_fit_px": self.sigma_fit_px.tolist(),
                "sigma_jackknife_px": None if jackknife is None else jackknife.tolist(),
                "angle_rad": self.angle_rad, "keypoints": self.keypoints,
                "beyond_limit": self.beyond_limit(settings),
                "unresolved": self.unresolved(settings),
                "xi_asked": None if self.xi is None else self.xi.tolist()}


def principal_fit(iterations: int = 20) -> KeypointCameraFit:
    """The joint fit over (pose, du, dv)."""
    from dream.coarse.principal import with_principal_shift

    return KeypointCameraFit(with_principal_shift, 2, principal_columns, MAX_STEP_PX,
                             iterations)


def turn_angle(shift_px: np.ndarray, camera: CameraIntrinsics) -> float:
    """How far a principal point moved by `shift_px` turns the camera: atan |shift / f|.

    >>> round(float(np.rad2deg(turn_angle(np.array([10.0, 0.0]), CameraIntrinsics(
    ...     500.0, 500.0, 320.0, 240.0, 640, 480)))), 3)
    1.146
    """
    return float(np.arctan(np.hypot(shift_px[0] / camera.fx, shift_px[1] / camera.fy)))


def keypoint_principal(result: CalibrationResult, obs: Observations, camera: CameraIntrinsics,
                       settings: PrincipalCheckSettings = PrincipalCheckSettings()
                       ) -> KeypointPrincipal | None:
    """The principal-point shift an all-frames result's inlier keypoints ask for (None: too
    few, another mode, or no answer from the fit or from one of its leave-one-name-out fits:
    the fit's own 1-sigma alone would flag a detector's bias on one keypoint)."""
    points = inlier_keypoints(result, obs, settings.min_keypoints)
    if points is None:
        return None
    P, uv, names = points
    estimate = principal_fit(settings.iterations).estimate(P, uv, names, camera,
                                                           result.T_cam_base,
                                                           settings.min_groups)
    if estimate is None:
        return None
    shift, sigma_fit, jackknife, T_asked = estimate
    sigma = sigma_fit if jackknife is None else np.maximum(sigma_fit, jackknife)
    return KeypointPrincipal(shift, sigma, sigma_fit, jackknife, turn_angle(shift, camera),
                             len(P), increment_between(result.T_cam_base, T_asked))


def keypoint_principal_finding(principal: KeypointPrincipal | None, camera: CameraIntrinsics,
                               settings: PrincipalCheckSettings = PrincipalCheckSettings()
                               ) -> Finding | None:
    """`check` where the keypoints ask for a principal point that turns the camera by more
    than `min_angle_rad`, a component of it beyond `z` 1-sigmas; None where they agree (or
    there was no check).

    >>> camera = CameraIntrinsics(300.0, 300.0, 159.5, 119.5, 320, 240)
    >>> def asked(du, dv, sigma):
    ...     shift = np.array([du, dv])
    ...     return KeypointPrincipal(shift, np.full(2, sigma), np.full(2, sigma), None,
    ...                              turn_angle(shift, camera), 200)
    >>> keypoint_principal_finding(asked(2.0, -1.0, 0.1), camera) is None    # 0.4 deg
    True
    >>> keypoint_principal_finding(asked(12.0, -8.0, 5.0), camera) is None   # within 3 sigma
    True
    >>> keypoint_principal_finding(asked(12.0, -8.0, 1.0), camera)[0]
    'check'
    """
    if principal is None or not principal.beyond_limit(settings) or \
            principal.unresolved(settings):
        return None
    (du, dv), (su, sv) = principal.shift_px, principal.sigma_px
    return CHECK, (f"the keypoints fit best with the principal point moved by {du:+.1f}, "
                   f"{dv:+.1f} px (1-sigma {su:.1f}, {sv:.1f}): cx, cy {camera.cx + du:.1f}, "
                   f"{camera.cy + dv:.1f} instead of {camera.cx:.1f}, {camera.cy:.1f}, which "
                   f"turns the camera by {np.rad2deg(principal.angle_rad):.1f} deg; check the "
                   "intrinsics (the image centre given for a calibrated camera's cx, cy? an "
                   "image cropped after calibrating? another stream's intrinsics?)")
