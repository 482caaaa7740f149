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
image size; the tangential terms stay as given. The shift is adopted where

- it differs from 0 by more than `min_sigmas` 1-sigmas (frame groups left out in turn, and
  links where something carried is left out) and by more than `min_change`;
- the finish's IoU through it beats the IoU through the given camera by more than
  `min_iou_gain` (the overlap is a second cue; the outlines alone can be pulled);
- it lies within `max_change` (beyond, the intrinsics or the pose are badly wrong: the verdict
  says so, and the given ones are kept).

Where the outlines ask for a shift through k1 (beyond the first rule), k2 is fitted with it:
the same rounds over (corner shift, k2's share of it), and the lens with k2 replaces the one
without where k2's share passes the first rule and the IoU through it beats the IoU through k1
alone by more than `min_iou_gain`. k1 alone cannot bend an outline near the image's border as
a lens with k2 does: on a rendered scene through k1 -0.2, k2 0.05 given neither, the fit of k1
alone asked -15.6 % at the corner, and the overlap refused it (IoU 0.654 -> 0.645, the pose
22 mm off); with k2, -14.1 % (+4.4 % through k2; the truth -14.0 %, +4.1 %), IoU 0.681 and
the pose 0.6 mm off. k2 is not fitted where k1 is not asked for: on scenes through a lens
without distortion the two terms pull against each other (fitted together on five control
scenes of four arms, k2's share reached -13.8 % at a 1-sigma of 8.2 %). Where k2 was fitted
and not asked for, both lenses match the outlines as well, and the move from the pose through
k1 alone to the pose through both enters the adopted lens's covariance
(`DistortionEstimate.xi_other_lens`).

    >>> camera = CameraIntrinsics(420.0, 420.0, 319.5, 239.5, 640, 480)
    >>> round(with_corner_shift(camera, -0.1).distortion[0], 4)
    -0.1099
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from dream.arrays import finite_list_or_none, finite_or_none
from dream.camera import CameraIntrinsics
from dream.coarse.camera_fit import (
    BEYOND,
    REFUTED,
    WITHIN,
    CameraFit,
    ParameterFit,
    ParameterSettings,
    adopted_pose_covariance,
    fit_parameter,
    overlap_agrees,
)
from dream.coarse.carried import CarriedRegion
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.pnp import increment_between
from dream.silhouette import RobotMeshes


@dataclass(frozen=True)
class DistortionSettings(ParameterSettings):
    """How the radial distortion is fitted and when it is adopted (module doc; the fields of
    `dream.coarse.camera_fit.ParameterSettings`, the value the corner shift): `min_change`
    0.01 moves the corner of a 640x480 image by 4 px; beyond `max_change` 0.4 the lens is one
    plumb_bob's k1 and k2 do not describe. `k2`: fit k2 where the outlines ask for k1."""

    min_change: float = 0.01
    max_change: float = 0.4
    derivative_step: float = 1e-3
    k2: bool = True
    what: ClassVar[str] = "distortion fit"


@dataclass(frozen=True)
class DistortionEstimate:
    """The fitted radial distortion (module doc).

    Attributes:
        shift: the corner shift that explains the outlines best (0: as given); sigma: its
            1-sigma (NaN without enough frame groups).
        k2_share: the part of `shift` through k2 (0 where k1 alone was fitted); k2_sigma: its
            1-sigma (NaN where k1 alone was fitted).
        iou_given, iou_fitted: the finish's IoU through the given camera and the fitted one.
        rounds: the rounds run. adopted: whether the search goes on with it; reason: why.
        camera: the given camera with k1 (and k2) moved (adopted or not); given: as given.
        T_cam_base: (4, 4) the finish through `camera`.
        xi_per_unit: (6, k) how the finish's pose moves (xi of `dream.pnp`) per unit of the
            shift (and of k2's share; NaN where not adopted: not measured); covariance_used:
            (k, k) the covariance they are weighed with (the fit's and the floor).
        xi_other_lens: (6,) the move from `T_cam_base` to the finish through the lens with k2
            where k2 was fitted and not asked for (k1 alone kept: both lenses match the
            outlines as well, and the pose may lie at either); zeros where k2 was not fitted
            or was asked for.
    """

    shift: float
    sigma: float
    k2_share: float
    k2_sigma: float
    iou_given: float
    iou_fitted: float
    rounds: int
    adopted: bool
    reason: str
    camera: CameraIntrinsics
    given: CameraIntrinsics
    T_cam_base: np.ndarray
    xi_per_unit: np.ndarray
    covariance_used: np.ndarray
    xi_other_lens: np.ndarray = field(default_factory=lambda: np.zeros(6))

    @property
    def pose_covariance(self) -> np.ndarray:
        """(6, 6) what the adopted lens's uncertainty adds to the pose's covariance: its
        parameters' through the pose's move per unit of them, and the move to the pose
        through the other lens that matches the outlines as well (`xi_other_lens`); zero
        where it was not adopted."""
        if not self.adopted:
            return np.zeros((6, 6))
        return lens_pose_covariance(self.covariance_used, self.xi_per_unit, self.xi_other_lens)

    def to_dict(self) -> dict:
        return {"corner_shift": self.shift, "sigma": finite_or_none(self.sigma),
                "k2_share": self.k2_share, "k2_sigma": finite_or_none(self.k2_sigma),
                "iou_given": self.iou_given, "iou_fitted": self.iou_fitted,
                "rounds": self.rounds, "adopted": self.adopted, "reason": self.reason,
                "covariance_used": self.covariance_used.tolist(),
                "xi_per_unit": finite_list_or_none(self.xi_per_unit),
                "xi_other_lens": self.xi_other_lens.tolist(),
                "given": {"distortion": list(self.given.dist_coeffs)},
                "used": {"distortion": list((self.camera if self.adopted
                                             else self.given).dist_coeffs)}}


def lens_pose_covariance(covariance_used: np.ndarray, xi_per_unit: np.ndarray,
                         xi_other_lens: np.ndarray) -> np.ndarray:
    """(6, 6) what an adopted lens leaves uncertain in the pose (`DistortionEstimate`'s fields
    or their RESULT.json lists): its parameters' covariance through the pose's move per unit
    of each (`adopted_pose_covariance`) and the move to the pose through the other lens.

    >>> xi, other = np.zeros((6, 1)), np.array([0.0, 0, 0, 0, 0, 0.003])
    >>> round(float(lens_pose_covariance([[1e-4]], xi, other)[5, 5]), 9)
    9e-06
    """
    other = np.asarray(xi_other_lens, dtype=float)
    return adopted_pose_covariance(True, np.asarray(covariance_used, dtype=float),
                                   xi_per_unit) + np.outer(other, other)


def corner_radius2(camera: CameraIntrinsics) -> float:
    """The squared normalised radius of the image's corner farthest from the principal point.

    >>> round(corner_radius2(CameraIntrinsics(100.0, 100.0, 50.0, 40.0, 100, 80)), 6)
    0.41
    """
    x = max(camera.cx, camera.width - camera.cx) / camera.fx
    y = max(camera.cy, camera.height - camera.cy) / camera.fy
    return float(x * x + y * y)


def with_corner_shift(camera: CameraIntrinsics, shift: float, k2_share: float = 0.0
                      ) -> CameraIntrinsics:
    """`camera` with k1 and k2 moved so that the image's corner moves radially by `shift` of
    its radius (to first order), `k2_share` of it through k2; the other coefficients kept."""
    if not (np.isfinite(shift) and np.isfinite(k2_share)):
        raise InputError(f"a corner shift must be finite, got {shift}, {k2_share}")
    R = corner_radius2(camera)
    coeffs = camera.dist_coeffs.copy()
    coeffs[0] += (shift - k2_share) / R
    coeffs[1] += k2_share / R ** 2
    return replace(camera, distortion=tuple(float(c) for c in coeffs))


def _moved(camera: CameraIntrinsics, p: np.ndarray) -> CameraIntrinsics:
    """`camera` through the parameters p: (corner shift[, k2's share])."""
    return with_corner_shift(camera, float(p[0]), float(p[1]) if len(p) > 1 else 0.0)


def fit_distortion(P: np.ndarray, meshes: RobotMeshes, masks: np.ndarray,
                   camera: CameraIntrinsics, T_cam_base: np.ndarray, search: SearchSettings,
                   settings: DistortionSettings | None = None, held: bool = False,
                   region: CarriedRegion | None = None) -> DistortionEstimate:
    """The radial distortion the outlines of the frames P (F, V, 3) in `masks` (F, H, W) ask
    for, from the search's winner `T_cam_base` through `camera` (module doc); `held`,
    `region`: as the search's `Scales`."""
    settings = settings or DistortionSettings()

    def fitted_with(terms: int) -> ParameterFit:
        fit = CameraFit(_moved, terms, settings.derivative_step, settings.lm_iterations)
        return fit_parameter(P, meshes, masks, lambda p: _moved(camera, p), T_cam_base, search,
                             fit, settings.how, held, region)

    fitted, tried, xi_other = fitted_with(1), "", np.zeros(6)
    if settings.k2 and settings.decide(float(fitted.value[0]), float(fitted.sigma[0]),
                                       fitted.iou_given, fitted.iou_fitted) != WITHIN:
        with_k2 = fitted_with(2)
        share, sigma = float(with_k2.value[1]), float(with_k2.sigma[1])
        asked = _k2_asked(share, sigma, fitted.iou_fitted, with_k2.iou_fitted, settings)
        tried = "" if asked else (f"; k2 not asked: {100 * share:+.1f} % at the corner "
                                  f"(1-sigma {100 * sigma:.1f} %, IoU {fitted.iou_fitted:.3f} "
                                  f"-> {with_k2.iou_fitted:.3f})")
        if not asked:
            xi_other = increment_between(fitted.T_cam_base, with_k2.T_cam_base)
        fitted = with_k2 if asked else fitted
    shift, sigma = float(fitted.value[0]), float(fitted.sigma[0])
    k2_share = float(fitted.value[1]) if len(fitted.value) > 1 else 0.0
    k2_sigma = float(fitted.sigma[1]) if len(fitted.value) > 1 else float("nan")
    adopted, reason = _decision(shift, sigma, fitted.iou_given, fitted.iou_fitted, settings,
                                k2_share, k2_sigma)
    return DistortionEstimate(shift, sigma, k2_share, k2_sigma, fitted.iou_given,
                              fitted.iou_fitted, fitted.rounds, adopted, reason + tried,
                              _moved(camera, fitted.value), camera, fitted.T_cam_base,
                              fitted.xi_per_unit(adopted),
                              settings.covariance_used(fitted.covariance), xi_other)


def _k2_asked(share: float, sigma: float, iou_k1: float, iou_k2: float,
              settings: DistortionSettings) -> bool:
    """Whether k2's share of the corner shift, `share` at 1-sigma `sigma`, replaces k1 alone:
    beyond `min_sigmas` 1-sigmas and `min_change`, and the overlap through it beats the one
    through k1 alone (module doc).

    >>> settings = DistortionSettings()
    >>> _k2_asked(0.044, 0.0015, 0.645, 0.681, settings)
    True
    >>> _k2_asked(-0.138, 0.082, 0.855, 0.855, settings), _k2_asked(0.04, 0.001, 0.7, 0.7, settings)
    (False, False)
    """
    return bool(np.isfinite(sigma) and abs(share) > max(settings.min_change,
                                                       settings.min_sigmas * sigma)
                and overlap_agrees(iou_k1, iou_k2, settings.min_iou_gain))


def _decision(shift: float, sigma: float, iou_given: float, iou_fitted: float,
              settings: DistortionSettings, k2_share: float = 0.0,
              k2_sigma: float = float("nan")) -> tuple[bool, str]:
    """(adopted, why) of a fitted corner shift (module doc), `k2_share` of it through k2 at
    1-sigma `k2_sigma` (NaN: k1 alone); one both cues confirm beyond `max_change` is not
    adopted, and its reason starts with "beyond".

    >>> _decision(-0.15, 0.01, 0.60, 0.65, DistortionSettings())[1][:59]
    'the outlines ask for a radial shift of -15.0 % at the corne'
    >>> _decision(-0.15, 0.01, 0.60, 0.60, DistortionSettings())[0]
    False
    """
    through = ("" if not np.isfinite(k2_sigma) else
               f", {100 * k2_share:+.1f} % of it through k2 (1-sigma {100 * k2_sigma:.1f} %)")
    told = f"{100 * shift:+.1f} % at the corner (1-sigma {100 * sigma:.1f} %){through}"
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
        given, used = record["given"]["distortion"][:2], record["used"]["distortion"][:2]
        return CHECK, (f"the robot's outlines ask for lens distortion (a radial shift of "
                       f"{shift:+.1f} % at the image's corner), and their overlap agrees: the "
                       f"pose was found with k1, k2 {used[0]:.3f}, {used[1]:.3f} (given "
                       f"{given[0]:.3f}, {given[1]:.3f}); were raw "
                       "images given with the intrinsics of rectified ones? Give the camera's "
                       "distortion coefficients (camera_info.yaml D), or pass "
                       "--fixed-distortion to keep them")
    if record["reason"].startswith("beyond"):
        return UNRELIABLE, (f"the robot's outlines and their overlap ask for a radial shift of "
                            f"{shift:+.1f} % at the image's corner: the intrinsics or the pose "
                            "found are wrong; check both")
    return None


def crosscheck_distortion_finding(record: dict | None) -> tuple[str, str] | None:
    """The distortion finding of the silhouettes' cross-check (RESULT.json's
    `silhouette_check.distortion`, where nothing is adopted and `asked` says the outlines and
    the overlap ask for it): `check`, the move to the pose through it in the 1-sigma; else as
    `distortion_finding`.

    >>> crosscheck_distortion_finding({"asked": True, "adopted": False, "corner_shift": -0.14,
    ...                                "k2_share": 0.0, "reason": "r"})[0]
    'check'
    >>> crosscheck_distortion_finding(None) is None
    True
    """
    from dream.quality import CHECK

    if record is None or not record["asked"]:
        return distortion_finding(record)      # beyond its range: unreliable; else None
    return CHECK, (f"the robot's outlines ask for lens distortion (a radial shift of "
                   f"{100 * record['corner_shift']:+.1f} % at the image's corner), and their "
                   "overlap agrees: with the given intrinsics the pose written may lie "
                   "centimetres off (in the 1-sigma), and no focal length or principal "
                   "point the outlines ask for is adopted; were raw images given with the "
                   "intrinsics of rectified ones? Give the camera's distortion coefficients "
                   "(camera_info.yaml D)")
