"""The principal point the robot's outlines ask for (pure): a check of the given cx, cy.

A principal point given a few per cent of the image off (the image centre for a calibrated
camera's cx, cy) turns the camera: every outline moves alike, and the search follows it with a
rotation of about atan(shift / f) that its own 1-sigma does not hold (on rendered scenes given
cx, cy 12 and -8 px off at 320x240: 2.3-4.8 deg off, the truth at chi-square 4 000-20 000,
three of nine `good`). A rotation and a shifted principal point move the outline alike only to
first order; across a wide view and the arm's depth they differ, so the outlines fix both.

From the search's pose at the given camera, up to `rounds` of: the finish through the current
principal point (`dream.coarse.scales.finish_scale`), its contour points there
(`Scales.contour`), and Levenberg-Marquardt over (pose, du, dv) on those points
(`dream.coarse.camera_fit.CameraFit` on the finish's objective), until the step falls below
`step_tolerance_px`. Where the shift could be a finding, its 1-sigma: the same fit with each of
`jackknife_groups` frame groups left out in turn, and with each link left out (a shifted
principal point moves every link's outline alike; a joint whose reading is off pulls the links
beyond it alike in every frame, which the frame groups do not see: on a rendered xArm7 whose
readings were off by up to 1.35 deg, the frame groups alone let a turn of 2.3 deg through, and
the camera lay 2.1 deg off, where with the links it stays 0.5 deg off). Where the search left
out something the arm carries that the model lacks (`region`), the shift is reported and not
judged: what the arm carries pulls the outline of the link it moves with alike in every frame,
which no leave-out of frames or links bounds (on a rendered UR5 holding an object, given its
own cx, cy, the outlines asked for a turn of 2.5-3.3 deg, beyond 3 of the frame groups'
1-sigmas, and with the links' in quadrature still beyond), and the carried finding already says
the pose may be off.

The outlines alone can be pulled (something the model lacks beside a link, the masks' own
errors), and their jackknife understates that: on 30 rendered scenes given their own cx, cy they
asked for turns of a median 0.31 deg, at most 1.22 deg where nothing carried was left out, some
of them beyond 3 of their 1-sigmas; given cx, cy 12, -8 px off, for 2.2-5.2 deg. So the shift is
a finding only where it turns the camera by more than `min_angle_rad`, lies beyond `min_sigmas`
1-sigmas, and the overlap agrees: the finish-scale IoU through the asked point beats the IoU
through the given one by more than `min_iou_gain` (the focal length's rule,
`dream.coarse.focal`: a second cue; on a rendered TALOS arm, part of it hidden by the floor, the
outlines asked for 6.9 px at a 1-sigma of 2.1 px, a turn of 2.4 deg, and adopted it put the
camera 2.5 deg off; an ask the overlap refuses is unresolved). Where it is a finding, the search
adopts it (`adopt`; `dream.coarse.intrinsics`): the pose is found again through the asked point,
and what that point's error leaves uncertain enters the covariance (the spread over the frame
groups of the pose fitted with the shift free, and the turn of `adopted_floor_rad` per image
axis: `adopted_covariance`). Kept as given (`adopt` False), the pose through the asked principal
point is how far the written pose may lie off, and that move enters its covariance as the image
cues' disagreement does, with the same spread (`PrincipalEstimate.pose_covariance`): with the
shift free the outlines fix the pose less well than through the given camera. A turn beyond the
limit within the noise, or not judged, leaves the principal point unresolved
(`PrincipalEstimate.unresolved`): the outlines then do not tell the camera's intrinsics, nothing
is adopted, and the move to the pose through the asked point enters the covariance as where a
finding is kept, with the turn of a point as far off as asked
(`PrincipalEstimate.unresolved_covariance`).

    >>> PrincipalSettings().min_sigmas
    3.0
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from dream.arrays import finite_or_none
from dream.camera import CameraIntrinsics
from dream.coarse.camera_fit import (
    CameraFit,
    finest_objective,
    frame_group_keeps,
    link_keeps,
    overlap_agrees,
    principal_turn,
)
from dream.coarse.carried import CarriedRegion
from dream.coarse.scales import Scales, finish_scale
from dream.coarse.settings import SearchSettings
from dream.pnp import increment_between
from dream.polish.objective import Objective
from dream.settings_checks import check_fields
from dream.silhouette import RobotMeshes

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PrincipalSettings:
    """How the principal point is fitted and when its shift is a finding (module doc).

    Attributes:
        fit: fit it at all (False: no check, nothing reported).
        rounds: finish / contour / joint-fit rounds at most.
        lm_iterations: Levenberg-Marquardt linearisations per joint fit (the shift carries the
            turn that undoes its move at the image centre, `dream.coarse.camera_fit`: on a
            rendered scene given cx, cy 12, -8 px off, 3 asked for 12.04, -7.93 px, 5 for
            11.98, -8.00).
        step_tolerance_px: the rounds stop after a step below this (image pixels).
        jackknife_groups: frame groups of the 1-sigma.
        min_sigmas: a finding only beyond this many 1-sigmas of the shift.
        min_angle_rad: a finding only where the shift turns the camera by more than this
            (atan(shift / f); set on rendered scenes: given their own cx, cy the outlines asked
            for at most 1.22 deg, given them 12, -8 px off at least 2.2 deg).
        derivative_step_px: the central differences' step in du, dv (the finish's pixels).
        min_iou_gain: a finding only where the finish's IoU through the asked point beats
            that through the given one by more than this (`FocalSettings.min_iou_gain`).
        adopt: a finding is adopted (module doc); False keeps the given cx, cy.
        adopted_floor_rad: where a principal point is adopted (`dream.coarse.intrinsics`,
            `dream.cli.keypoint_pass`), the turn its error leaves, per image axis, at least
            (`adopted_covariance`): the outlines' jackknife understates it (given 12, -8 px
            off, rendered scenes' asked points lay 0.7 px from the truth at a 1-sigma of
            0.1-0.2 px); given their own cx, cy the outlines asked for turns of a median
            0.3 deg (12 rendered scenes, keypoint path).
    """

    fit: bool = True
    rounds: int = 6
    lm_iterations: int = 5
    step_tolerance_px: float = 0.1
    jackknife_groups: int = 5
    min_sigmas: float = 3.0
    min_angle_rad: float = float(np.deg2rad(1.5))
    derivative_step_px: float = 0.05
    min_iou_gain: float = 0.001
    adopted_floor_rad: float = float(np.deg2rad(0.3))
    adopt: bool = True

    def floor_px(self, camera: CameraIntrinsics) -> np.ndarray:
        """(2,) the image pixels of `camera` whose turn is `adopted_floor_rad` (du, dv).

        >>> PrincipalSettings().floor_px(CameraIntrinsics(300.0, 300.0, 160.0, 120.0, 320,
        ...                                               240)).round(2).tolist()
        [1.57, 1.57]
        """
        return np.tan(self.adopted_floor_rad) * np.array([camera.fx, camera.fy])

    def __post_init__(self) -> None:
        check_fields(self, "principal point check",
                     positive_ints=("rounds", "lm_iterations", "jackknife_groups"),
                     positive=("step_tolerance_px", "min_angle_rad", "derivative_step_px"),
                     non_negative=("min_sigmas", "adopted_floor_rad", "min_iou_gain"))


@dataclass(frozen=True)
class PrincipalEstimate:
    """The principal point the outlines ask for (module doc).

    Attributes:
        shift_px: (2,) du, dv from the given cx, cy (image pixels); sigma_px: (2,) their
            1-sigma (NaN where not needed: a turn within the limit, or not judged; or without
            enough frame groups).
        angle_rad: how far the shift turns the camera, atan(|shift / f|).
        rounds: the rounds run. flagged: whether it is a finding; reason: why or why not.
        given: the camera as given. T_cam_base: (4, 4) the finish through the asked point.
        xi: (6,) from the search's pose to `T_cam_base` (xi of `dream.pnp`).
        seconds: how long the check took.
        spread: (6, 6) the frame-group jackknife covariance of the joint fit's pose (xi at
            `T_cam_base`; zero where it was not judged): how well the outlines fix the pose
            through the asked point, the shift free.
        unresolved: a turn beyond the limit within the noise, or not judged (module doc).
        adopted: the search went on through the asked point; floor_px: (2,) the 1-sigma of
            its error assumed then (`PrincipalSettings.floor_px`; zero where not adopted).
        iou_given, iou_asked: the finish-scale IoU through the given and the asked point (NaN
            where the shift was not judged).
    """

    shift_px: np.ndarray
    sigma_px: np.ndarray
    angle_rad: float
    rounds: int
    flagged: bool
    reason: str
    given: CameraIntrinsics
    T_cam_base: np.ndarray
    xi: np.ndarray
    seconds: float = 0.0
    spread: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    unresolved: bool = False
    adopted: bool = False
    floor_px: np.ndarray = field(default_factory=lambda: np.zeros(2))
    iou_given: float = float("nan")
    iou_asked: float = float("nan")

    @property
    def camera(self) -> CameraIntrinsics:
        """The given camera with the asked principal point."""
        return with_principal_shift(self.given, self.shift_px)

    def adopted_with(self, settings: PrincipalSettings) -> PrincipalEstimate:
        """This estimate adopted, with the floor of `settings` (only a finding is)."""
        if not self.flagged:
            raise ValueError("only a flagged principal point is adopted")
        return replace(self, adopted=True, floor_px=settings.floor_px(self.camera))

    @property
    def unresolved_covariance(self) -> np.ndarray:
        """(6, 6) where the shift is unresolved, the turn of a principal point as far off as
        asked in each image axis (`adopted_covariance` of |shift|); zero otherwise. The move
        to the pose through the asked point alone is one direction, and the outlines did not
        fix it: given cx, cy 12, -8 and 24, -16 px off, the six rendered scenes whose
        outlines left it unresolved (something carried beside it) lay 2.2-5.0 deg off, their
        truth at chi-square 3.5-420 with the move and at 1.2-1.7 with this turn too."""
        if not self.unresolved:
            return np.zeros((6, 6))
        return adopted_covariance(self.given, self.T_cam_base, np.abs(self.shift_px))

    @property
    def pose_covariance(self) -> np.ndarray:
        """(6, 6) what a shift that is a finding or unresolved adds to the pose's
        covariance; zero where the given cx, cy stand. Adopted: the pose's spread with the
        shift free (`spread`) and the turn of the asked point's error (`adopted_covariance`
        of `floor_px`). Kept as given: the move to the pose through the asked principal
        point, as a disagreement of two cues, and the same spread (the truth lies near that
        pose, and the two free parameters of the shift loosen the pose along more than the
        move); unresolved, those and `unresolved_covariance` (without it, the rendered
        scenes it names lay at chi-square 7 000-50 000 before the move entered). Added to the
        search's own jackknife, which measures much of the same frame-to-frame noise, it is
        on the safe side: given cx, cy 12, -8 px off and kept, the 6 flagged rendered scenes'
        truths lay at chi-square 1.3-4.2 (6 degrees of freedom)."""
        if not (self.flagged or self.unresolved):
            return np.zeros((6, 6))
        if self.adopted:
            return self.spread + adopted_covariance(self.camera, self.T_cam_base,
                                                    self.floor_px)
        return np.outer(self.xi, self.xi) + self.spread + self.unresolved_covariance

    def to_dict(self) -> dict:
        given = self.given
        sigma = [float(v) if np.isfinite(v) else None for v in self.sigma_px]
        return {"shift_px": self.shift_px.tolist(), "sigma_px": sigma,
                "angle_rad": self.angle_rad, "rounds": self.rounds, "flagged": self.flagged,
                "reason": self.reason, "given": {"cx": given.cx, "cy": given.cy},
                "asked": {"cx": given.cx + float(self.shift_px[0]),
                          "cy": given.cy + float(self.shift_px[1])},
                "T_cam_base_asked": self.T_cam_base.tolist(),
                "spread_xi": self.spread.tolist(), "seconds": self.seconds,
                "unresolved": self.unresolved, "adopted": self.adopted,
                "used": {"cx": self.camera.cx if self.adopted else given.cx,
                         "cy": self.camera.cy if self.adopted else given.cy},
                "sigma_floor_px": self.floor_px.tolist(),
                "iou_given": finite_or_none(self.iou_given),
                "iou_asked": finite_or_none(self.iou_asked)}


def adopted_covariance(camera: CameraIntrinsics, T_cam_base: np.ndarray,
                       sigma_px: np.ndarray) -> np.ndarray:
    """(6, 6) what a principal point adopted with 1-sigma `sigma_px` (du, dv; image pixels of
    `camera`) leaves uncertain in the pose `T_cam_base` calibrated through it (xi of
    `dream.pnp`): each component's turn of the camera about its centre (`principal_turn`; the
    translation moves with it), J diag(sigma^2) J^T.

    >>> camera = CameraIntrinsics(300.0, 300.0, 160.0, 120.0, 320, 240)
    >>> T = np.eye(4); T[2, 3] = 1.5
    >>> C = adopted_covariance(camera, T, np.array([3.0, 0.0]))
    >>> round(float(np.rad2deg(np.sqrt(C[1, 1]))), 3), round(float(np.sqrt(C[3, 3])), 4)
    (0.573, 0.015)
    """
    sigma_px = np.asarray(sigma_px, dtype=float)
    if sigma_px.shape != (2,):
        raise ValueError(f"sigma_px must have shape (2,), got {sigma_px.shape}")
    J = np.zeros((6, 2))
    for k in range(2):
        turned = np.eye(4)
        turned[:3, :3] = principal_turn(camera, np.eye(2)[k])
        J[:, k] = increment_between(T_cam_base, turned @ T_cam_base)
    return J @ np.diag(sigma_px ** 2) @ J.T


def with_principal_shift(camera: CameraIntrinsics, shift_px: np.ndarray) -> CameraIntrinsics:
    """`camera` with cx, cy moved by `shift_px` (du, dv).

    >>> with_principal_shift(CameraIntrinsics(100.0, 100.0, 50.0, 40.0, 100, 80), [2, -1]).cx
    52.0
    """
    du, dv = (float(v) for v in shift_px)
    return replace(camera, cx=camera.cx + du, cy=camera.cy + dv)


def camera_fit(settings: PrincipalSettings) -> CameraFit:
    """The joint fit over (pose, du, dv) that `settings` ask for (du, dv in the fitted
    objective's pixels)."""
    return CameraFit(with_principal_shift, 2, settings.derivative_step_px,
                     settings.lm_iterations, turn_at=principal_turn)


def fit_principal(P: np.ndarray, meshes: RobotMeshes, masks: np.ndarray,
                  camera: CameraIntrinsics, T_cam_base: np.ndarray, search: SearchSettings,
                  settings: PrincipalSettings | None = None, held: bool = False,
                  region: CarriedRegion | None = None) -> PrincipalEstimate:
    """The principal point the outlines of the frames P (F, V, 3) in `masks` (F, H, W) ask
    for, from the search's pose `T_cam_base` through `camera` (module doc); `held`, `region`:
    as the search's `Scales`."""
    settings = settings or PrincipalSettings()
    start = time.perf_counter()

    def scales_at(shift: np.ndarray) -> Scales:
        return finish_scale(P, meshes, masks, with_principal_shift(camera, shift), search,
                            None, held, region)

    fit, shift, rounds = camera_fit(settings), np.zeros(2), 0
    scales = scales_given = scales_at(shift)
    T = T_given = scales.refine(np.asarray(T_cam_base, float))
    # the finest level's masks, so their distance fields, are the same at every shift
    objective = finest_objective(scales)
    to_image = camera.width / objective.camera.width
    for rounds in range(1, settings.rounds + 1):
        T, step = fit.fit(objective, scales.contour(T), T, scales.params.initial_damping)
        shift = shift + step * to_image
        log.debug("principal point round %d: shift %s px", rounds, np.round(shift, 2))
        scales = scales_at(shift)
        objective = objective.with_camera(scales.levels[-1][0])
        if np.max(np.abs(step)) * to_image < settings.step_tolerance_px:
            break
    T = scales.refine(T)
    angle = float(np.arctan(np.hypot(shift[0] / camera.fx, shift[1] / camera.fy)))
    carried = region is not None
    judged = angle > settings.min_angle_rad and not carried
    sigma, spread = (_jackknife(objective, scales, T, settings, len(P), meshes) if judged
                     else (np.full(2, np.nan), np.zeros((6, 6))))
    ious = ((scales_given.iou(T_given), scales.iou(T)) if judged
            else (float("nan"), float("nan")))
    flagged, reason = _decision(shift, sigma * to_image, angle, carried, settings, ious)
    return PrincipalEstimate(shift, sigma * to_image, angle, rounds, flagged, reason, camera, T,
                             increment_between(T_given, T), time.perf_counter() - start,
                             spread, unresolved=angle > settings.min_angle_rad and not flagged,
                             iou_given=float(ious[0]), iou_asked=float(ious[1]))


def _jackknife(objective: Objective, scales: Scales, T: np.ndarray,
               settings: PrincipalSettings, frames: int, meshes: RobotMeshes
               ) -> tuple[np.ndarray, np.ndarray]:
    """(the 1-sigma (2,) of the shift in `objective`'s pixels, the covariance (6, 6) of the
    pose): the delete-one-group jackknife over frame groups of the contour points of `scales`
    at T, and that over the links with enough of them added (`link_keeps`: a shifted
    principal point moves every link's outline alike, a joint reading that is off moves those
    beyond it only); NaN and zero with fewer than `MIN_GROUPS` frame groups."""
    contour = scales.contour(T)
    keeps = frame_group_keeps(contour, frames, settings.jackknife_groups)
    if keeps is None:
        return np.full(2, np.nan), np.zeros((6, 6))
    shifts_covariance, pose_covariance = camera_fit(settings).jackknife_spreads(
        objective, contour, T, scales.params.initial_damping,
        [keeps, link_keeps(contour, meshes)])
    return np.sqrt(np.diag(shifts_covariance)), pose_covariance


def _decision(shift: np.ndarray, sigma: np.ndarray, angle_rad: float, carried: bool,
              settings: PrincipalSettings, ious: tuple[float, float] | None = None
              ) -> tuple[bool, str]:
    """(a finding, why) of an asked shift (module doc); `sigma` NaN where it was not needed;
    `ious` (through the given point, through the asked one; None: not scored).

    >>> _decision(np.array([12.0, -8.0]), np.array([0.3, 0.2]), 0.06, False,
    ...           PrincipalSettings())[0]
    True
    >>> _decision(np.array([1.0, 0.5]), np.full(2, np.nan), 0.006, False,
    ...           PrincipalSettings())[1][-49:]
    'ask for +1.0, +0.5 px, turning the camera 0.3 deg'
    >>> _decision(np.array([12.0, -8.0]), np.full(2, np.nan), 0.06, True,
    ...           PrincipalSettings())[1][:57]
    'not judged: something the arm carries pulls the outlines '
    >>> _decision(np.array([12.0, -8.0]), np.array([0.3, 0.2]), 0.06, False,
    ...           PrincipalSettings(), (0.70, 0.70))[1].endswith("(IoU 0.700 -> 0.700)")
    True
    """
    spread = (f" (1-sigma {sigma[0]:.1f}, {sigma[1]:.1f})" if np.all(np.isfinite(sigma))
              else "")
    told = (f"{shift[0]:+.1f}, {shift[1]:+.1f} px{spread}, turning the camera "
            f"{np.rad2deg(angle_rad):.1f} deg")
    if angle_rad <= settings.min_angle_rad:
        return False, f"the given cx, cy stand: the outlines ask for {told}"
    if carried:
        return False, f"not judged: something the arm carries pulls the outlines ({told})"
    if not np.any(np.abs(shift) > settings.min_sigmas * np.nan_to_num(sigma, nan=np.inf)):
        return False, (f"the given cx, cy stand: the outlines ask for {told}, within "
                       f"{settings.min_sigmas:g} sigma")
    if ious is not None and not overlap_agrees(*ious, settings.min_iou_gain):
        return False, (f"the given cx, cy stand: the outlines ask for {told}, but the overlap "
                       f"does not agree (IoU {ious[0]:.3f} -> {ious[1]:.3f})")
    return True, f"the outlines ask for the principal point {told}"
