"""The lens's radial distortion the robot's outlines ask for (pure). Raw images of a lens with
barrel or pincushion distortion, given with intrinsics for rectified ones (K alone, the
distortion coefficients left out), bend the arm's outline by a share of its distance from the
image centre growing with the square of it: no pose through the given camera matches every
frame, and the search settles centimetres off with a principal point or a focal length that
makes up for part of it (on nine rendered scenes of three arms at 640x480 through fx = fy =
420 px, k1 -0.2, k2 0.05, given without them: 21-79 mm and up to 5.8 deg off, a principal point
3.4-5.9 deg off adopted in three, the truth outside every 95 % ellipsoid).

Fitted as the focal length is (`dream.coarse.camera_fit.fit_parameter`): from the search's
winner, rounds of the finish through the camera with the plumb_bob k1 moved, its contour points
and a joint fit over (pose, step). The parameter is the radial shift at the image's corner
(`corner_shift`: the distorted radius there over the undistorted, less 1, to first order:
k1 times the corner's squared normalised radius), so that its limits hold for any lens and
image size; k2 and the tangential terms stay as given. The shift is adopted where

- it differs from 0 by more than `min_sigmas` 1-sigmas (frame groups left out in turn, and
  links where something carried is left out) and by more than `min_change`;
- the finish's IoU through it beats the IoU through the given camera by more than
  `min_iou_gain` (the overlap is a second cue; the outlines alone can be pulled);
- it lies within `max_change` (beyond, the intrinsics or the pose are badly wrong: the verdict
  says so, and the given ones are kept).

    >>> camera = CameraIntrinsics(420.0, 420.0, 319.5, 239.5, 640, 480)
    >>> round(with_corner_shift(camera, -0.1).distortion[0], 4)
    -0.1099
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.camera_fit import (
    BEYOND,
    REFUTED,
    WITHIN,
    CameraFit,
    ParameterSettings,
    adopted_pose_covariance,
    fit_parameter,
)
from dream.coarse.carried import CarriedRegion
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.silhouette import RobotMeshes


@dataclass(frozen=True)
class DistortionSettings(ParameterSettings):
    """How the radial distortion is fitted and when it is adopted (module doc; the fields of
    `dream.coarse.camera_fit.ParameterSettings`, the value the corner shift): `min_change`
    0.01 moves the corner of a 640x480 image by 4 px; beyond `max_change` 0.4 the lens is one
    plumb_bob's k1 does not describe."""

    min_change: float = 0.01
    max_change: float = 0.4
    derivative_step: float = 1e-3
    what: ClassVar[str] = "distortion fit"


@dataclass(frozen=True)
class DistortionEstimate:
    """The fitted radial distortion (module doc).

    Attributes:
        shift: the corner shift that explains the outlines best (0: as given); sigma: its
            1-sigma (NaN without enough frame groups).
        iou_given, iou_fitted: the finish's IoU through the given camera and the fitted one.
        rounds: the rounds run. adopted: whether the search goes on with it; reason: why.
        camera: the given camera with k1 moved (adopted or not); given: as given.
        T_cam_base: (4, 4) the finish through `camera`.
        xi_per_shift: (6,) how the finish's pose moves (xi of `dream.pnp`) per unit of shift;
            sigma_used: the 1-sigma it is weighed with (`sigma` and the floor in quadrature).
    """

    shift: float
    sigma: float
    iou_given: float
    iou_fitted: float
    rounds: int
    adopted: bool
    reason: str
    camera: CameraIntrinsics
    given: CameraIntrinsics
    T_cam_base: np.ndarray
    xi_per_shift: np.ndarray
    sigma_used: float

    @property
    def pose_covariance(self) -> np.ndarray:
        """(6, 6) what the adopted shift's uncertainty adds to the pose's covariance (zero
        where it was not adopted)."""
        return adopted_pose_covariance(self.adopted, self.sigma_used, self.xi_per_shift)

    def to_dict(self) -> dict:
        return {"corner_shift": self.shift,
                "sigma": self.sigma if np.isfinite(self.sigma) else None,
                "iou_given": self.iou_given, "iou_fitted": self.iou_fitted,
                "rounds": self.rounds, "adopted": self.adopted, "reason": self.reason,
                "sigma_used": self.sigma_used, "xi_per_shift": self.xi_per_shift.tolist(),
                "given": {"distortion": list(self.given.dist_coeffs)},
                "used": {"distortion": list((self.camera if self.adopted
                                             else self.given).dist_coeffs)}}


def corner_radius2(camera: CameraIntrinsics) -> float:
    """The squared normalised radius of the image's corner farthest from the principal point.

    >>> round(corner_radius2(CameraIntrinsics(100.0, 100.0, 50.0, 40.0, 100, 80)), 6)
    0.41
    """
    x = max(camera.cx, camera.width - camera.cx) / camera.fx
    y = max(camera.cy, camera.height - camera.cy) / camera.fy
    return float(x * x + y * y)


def with_corner_shift(camera: CameraIntrinsics, shift: float) -> CameraIntrinsics:
    """`camera` with k1 moved so that the image's corner moves radially by `shift` of its
    radius (to first order); the other coefficients kept."""
    if not np.isfinite(shift):
        raise InputError(f"a corner shift must be finite, got {shift}")
    coeffs = camera.dist_coeffs.copy()
    coeffs[0] += shift / corner_radius2(camera)
    return replace(camera, distortion=tuple(float(c) for c in coeffs))


def fit_distortion(P: np.ndarray, meshes: RobotMeshes, masks: np.ndarray,
                   camera: CameraIntrinsics, T_cam_base: np.ndarray, search: SearchSettings,
                   settings: DistortionSettings | None = None, held: bool = False,
                   region: CarriedRegion | None = None) -> DistortionEstimate:
    """The radial distortion the outlines of the frames P (F, V, 3) in `masks` (F, H, W) ask
    for, from the search's winner `T_cam_base` through `camera` (module doc); `held`,
    `region`: as the search's `Scales`."""
    settings = settings or DistortionSettings()
    fit = CameraFit(lambda c, p: with_corner_shift(c, float(p[0])), 1,
                    settings.derivative_step, settings.lm_iterations)
    fitted = fit_parameter(P, meshes, masks, lambda v: with_corner_shift(camera, v),
                           T_cam_base, search, fit, settings.how, held, region)
    adopted, reason = _decision(fitted.value, fitted.sigma, fitted.iou_given,
                                fitted.iou_fitted, settings)
    return DistortionEstimate(fitted.value, fitted.sigma, fitted.iou_given, fitted.iou_fitted,
                              fitted.rounds, adopted, reason,
                              with_corner_shift(camera, fitted.value), camera,
                              fitted.T_cam_base, fitted.xi_per_unit,
                              settings.sigma_used(fitted.sigma))


def _decision(shift: float, sigma: float, iou_given: float, iou_fitted: float,
              settings: DistortionSettings) -> tuple[bool, str]:
    """(adopted, why) of a fitted corner shift (module doc); one both cues confirm beyond
    `max_change` is not adopted, and its reason starts with "beyond".

    >>> _decision(-0.15, 0.01, 0.60, 0.65, DistortionSettings())[1][:59]
    'the outlines ask for a radial shift of -15.0 % at the corne'
    >>> _decision(-0.15, 0.01, 0.60, 0.60, DistortionSettings())[0]
    False
    """
    told = f"{100 * shift:+.1f} % at the corner (1-sigma {100 * sigma:.1f} %)"
    decided = settings.decide(shift, sigma, iou_given, iou_fitted)
    if decided == WITHIN:
        return False, (f"the given distortion stands: the outlines ask for a radial shift of "
                       f"{told}, within {settings.min_sigmas:g} sigma or "
                       f"{100 * settings.min_change:g} %")
    if decided == REFUTED:
        return False, (f"the given distortion stands: the outlines ask for a radial shift of "
                       f"{told}, but the overlap does not agree (IoU {iou_given:.3f} -> "
                       f"{iou_fitted:.3f})")
    if decided == BEYOND:
        return False, (f"beyond {settings.max_change:.0%}: the outlines and the overlap ask "
                       f"for a radial shift of {told}; the given distortion was kept")
    return True, (f"the outlines ask for a radial shift of {told}, and the overlap agrees "
                  f"(IoU {iou_given:.3f} -> {iou_fitted:.3f})")


def distortion_finding(record: dict | None) -> tuple[str, str] | None:
    """The verdict's finding on RESULT.json's `start.distortion` (`DistortionEstimate.to_dict`):
    adopted, the pose was found through it and the user's intrinsics need correcting
    (`check`); asked beyond `max_change` by both cues, the intrinsics or the pose are wrong
    (`unreliable`); else none.

    >>> distortion_finding({"adopted": True, "corner_shift": -0.18, "reason": "r",
    ...                     "given": {"distortion": [0.0] * 5},
    ...                     "used": {"distortion": [-0.2, 0, 0, 0, 0]}})[0]
    'check'
    >>> distortion_finding({"adopted": False, "corner_shift": 0.004, "reason": "stands"}) is None
    True
    """
    from dream.quality import CHECK, UNRELIABLE

    if record is None:
        return None
    shift = 100 * record["corner_shift"]
    if record["adopted"]:
        given, used = record["given"]["distortion"][0], record["used"]["distortion"][0]
        return CHECK, (f"the robot's outlines ask for lens distortion (a radial shift of "
                       f"{shift:+.1f} % at the image's corner), and their overlap agrees: the "
                       f"pose was found with k1 {used:.3f} (given {given:.3f}); were raw "
                       "images given with the intrinsics of rectified ones? Give the camera's "
                       "distortion coefficients (camera_info.yaml D), or pass "
                       "--fixed-distortion to keep them")
    if record["reason"].startswith("beyond"):
        return UNRELIABLE, (f"the robot's outlines and their overlap ask for a radial shift of "
                            f"{shift:+.1f} % at the image's corner: the intrinsics or the pose "
                            "found are wrong; check both")
    return None
