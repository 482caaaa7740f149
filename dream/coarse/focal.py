"""The focal length the robot's outlines ask for (pure). Where the arm's distance from a fixed
camera varies over the frames, its silhouettes fix the focal length along with the pose: a
camera that slides back grows a near link less than a far one, a longer focal length grows both
alike. A few per cent off in the given fx, fy moves the camera centimetres along its axis (on
15 rendered scenes given fx, fy 4 % off, the search's winner lay 19-78 mm off, median 57 mm).

From the search's winner at the given intrinsics, up to `rounds` of: the finish at the current
scale s (fx and fy times s: `dream.coarse.scales.finish_scale`), its contour points there
(`Scales.contour`), and Levenberg-Marquardt over (pose, log s) on those points
(`dream.coarse.camera_fit.CameraFit` on the finish's objective), until the step in log s falls
below `step_tolerance`. Its 1-sigma: the same fit on the last round's points with each of
`jackknife_groups` frame groups left out in turn (the leave-out fits' spread); where the search
left out something the arm carries that the model lacks (`region`), also with each link's points
left out in turn, the two spreads in quadrature: what the arm carries pulls the outline of the
link it moves with alike in every frame, which the frame groups do not see (a Kinova holding an
object about 19 x 15 x 16 cm, given its own fx, fy: the outlines asked for x1.015 at a
frame-group 1-sigma of 0.45 %, and adopted it, the camera 15.6 mm off; the links' spread makes
it 0.7 %, and kept as given the camera lies 6.2 mm off). Elsewhere the links differ in how well
they tell the scale, not in what pulls them, and their spread would refuse scales that are right
(ur5 seed 1003 given fx, fy 4 % short: 26.6 mm off and `good` with it). The fitted scale is
adopted only where

- it differs from 1 by more than `min_sigmas` 1-sigmas and by more than `min_change`;
- the finish-scale IoU at it (the pose refined there) beats the IoU at the given focal length
  by more than `min_iou_gain`: the overlap is a second cue, and the outlines alone can be pulled
  (on the 60 rendered scenes given their own fx, fy they asked for x0.88-0.99 beyond 3 sigma in
  7 of 57, and the overlap refused each);
- it lies within `max_change` of 1 (beyond, the intrinsics or the pose are badly wrong: the
  verdict says so, and the given intrinsics are kept).

    >>> FocalSettings().max_change
    0.15
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from dream.arrays import finite_list_or_none
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
class FocalSettings(ParameterSettings):
    """How the focal-length scale is fitted and when it is adopted (module doc; the fields of
    `dream.coarse.camera_fit.ParameterSettings`, the value log s).

    The defaults were set on rendered scenes: `min_iou_gain`, given fx, fy 4 % off, the
    adopted scales gained 0.0027-0.0225, and given them right the scales beyond 3 sigma gained
    at most 0.00003 (xarm7 seed 1000's automatic search); `sigma_floor`, given fx, fy 4 % off,
    the adopted scales lay 0.03-1.6 % from the truth, rms 0.66 %, where the jackknife said
    0.05-0.9 %.
    """

    what: ClassVar[str] = "focal fit"


@dataclass(frozen=True)
class FocalEstimate:
    """The fitted focal-length scale (module doc).

    Attributes:
        scale: fx and fy times this explain the outlines best; sigma: 1-sigma of its log (about
            the relative 1-sigma; NaN without enough frame groups; with a carried region
            the frame groups' and the links' jackknives in quadrature).
        iou_given, iou_fitted: the finish-scale IoU at the given focal length and at the fitted
            one (each with the pose refined there).
        rounds: the rounds run. adopted: whether the search goes on with it; reason: why.
        camera: the given camera with fx, fy scaled (adopted or not); given: as given.
        T_cam_base: (4, 4) the finish at the fitted scale.
        xi_per_log_scale: (6,) how the finish's pose moves (xi of `dream.pnp`) per unit of
            log s at the fitted scale (NaN where not adopted: not measured); sigma_used: the
            1-sigma of log s it is weighed with (`sigma` and `FocalSettings.sigma_floor` in
            quadrature).
    """

    scale: float
    sigma: float
    iou_given: float
    iou_fitted: float
    rounds: int
    adopted: bool
    reason: str
    camera: CameraIntrinsics
    given: CameraIntrinsics
    T_cam_base: np.ndarray
    xi_per_log_scale: np.ndarray
    sigma_used: float

    @property
    def pose_covariance(self) -> np.ndarray:
        """(6, 6) what the adopted scale's uncertainty adds to the pose's covariance (zero
        where it was not adopted: the given intrinsics are then taken as they are)."""
        return adopted_pose_covariance(self.adopted, self.sigma_used ** 2,
                                       self.xi_per_log_scale)

    def to_dict(self) -> dict:
        given = self.given
        return {"scale": self.scale,
                "sigma_relative": self.sigma if np.isfinite(self.sigma) else None,
                "iou_given": self.iou_given, "iou_fitted": self.iou_fitted,
                "rounds": self.rounds, "adopted": self.adopted, "reason": self.reason,
                "sigma_used": self.sigma_used,
                "xi_per_log_scale": finite_list_or_none(self.xi_per_log_scale),
                "given": {"fx": given.fx, "fy": given.fy},
                "used": {"fx": self.camera.fx if self.adopted else given.fx,
                         "fy": self.camera.fy if self.adopted else given.fy}}


def with_focal_scale(camera: CameraIntrinsics, scale: float) -> CameraIntrinsics:
    """`camera` with fx and fy times `scale` (the principal point kept).

    >>> with_focal_scale(CameraIntrinsics(100.0, 100.0, 50.0, 40.0, 100, 80), 1.1).fx
    110.00000000000001
    """
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"a focal-length scale must be positive, got {scale}")
    return replace(camera, fx=camera.fx * scale, fy=camera.fy * scale)


def _scaled(camera: CameraIntrinsics, p: np.ndarray) -> CameraIntrinsics:
    """`camera` with fx, fy times exp(p[0]): the focal fit's parameter is log s."""
    return with_focal_scale(camera, float(np.exp(p[0])))


def camera_fit(settings: FocalSettings) -> CameraFit:
    """The joint fit over (pose, log s) that `settings` ask for."""
    return CameraFit(_scaled, 1, settings.derivative_step, settings.lm_iterations)


def fit_focal(P: np.ndarray, meshes: RobotMeshes, masks: np.ndarray, camera: CameraIntrinsics,
              T_cam_base: np.ndarray, search: SearchSettings,
              settings: FocalSettings | None = None, held: bool = False,
              region: CarriedRegion | None = None) -> FocalEstimate:
    """The focal-length scale the outlines of the frames P (F, V, 3) in `masks` (F, H, W) ask
    for, from the search's winner `T_cam_base` at `camera` (module doc); `held`, `region`: as
    the search's `Scales`."""
    settings = settings or FocalSettings()
    fitted = fit_parameter(P, meshes, masks, lambda p: _scaled(camera, p), T_cam_base, search,
                           camera_fit(settings), settings.how, held, region)
    log_s, sigma = float(fitted.value[0]), float(fitted.sigma[0])
    adopted, reason = _decision(log_s, sigma, fitted.iou_given, fitted.iou_fitted, settings)
    return FocalEstimate(float(np.exp(log_s)), sigma, fitted.iou_given, fitted.iou_fitted,
                         fitted.rounds, adopted, reason,
                         with_focal_scale(camera, float(np.exp(log_s))), camera,
                         fitted.T_cam_base, fitted.xi_per_unit(adopted)[:, 0],
                         float(np.sqrt(settings.covariance_used(fitted.covariance)[0, 0])))


def _decision(log_s: float, sigma: float, iou_given: float, iou_fitted: float,
              settings: FocalSettings) -> tuple[bool, str]:
    """(adopted, why) of a fitted log scale (module doc): a change within the noise or one the
    overlap does not confirm leaves the given fx, fy standing; one both cues confirm beyond
    `max_change` is not adopted either, and its reason starts with "beyond".

    >>> _decision(0.04, 0.003, 0.50, 0.51, FocalSettings())[1][:50]
    'the outlines ask for fx, fy x1.041 (1-sigma 0.3 %)'
    >>> _decision(0.04, 0.003, 0.50, 0.49, FocalSettings())[0]
    False
    """
    told = f"x{np.exp(log_s):.3f} (1-sigma {100 * sigma:.1f} %)"
    decided = settings.decide(log_s, sigma, iou_given, iou_fitted)
    if decided == WITHIN:
        return False, (f"the given fx, fy stand: the outlines ask for {told}, within "
                       f"{settings.min_sigmas:g} sigma or {100 * settings.min_change:g} %")
    if decided == REFUTED:
        return False, (f"the given fx, fy stand: the outlines ask for {told}, but the overlap "
                       f"does not agree (IoU {iou_given:.3f} -> {iou_fitted:.3f})")
    if decided == BEYOND:
        return False, (f"beyond {settings.max_change:.0%}: the outlines and the overlap ask "
                       f"for fx, fy {told}; the given ones were kept")
    return True, (f"the outlines ask for fx, fy {told}, and the overlap agrees (IoU "
                  f"{iou_given:.3f} -> {iou_fitted:.3f})")
