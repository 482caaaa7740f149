"""The robot's outlines fitted with the pose over a few camera parameters (pure): the common
part of the focal-length fit (`dream.coarse.focal`) and the principal-point check
(`dream.coarse.principal`).

`CameraFit` holds how a parameter vector p (`size` entries, 0 at the camera as given) moves
the camera (`camera_at`) and, optionally, how it turns the camera with it (`turn_at`: a
rotation C(p) of the camera frame, the pose then C(p) T); `CameraFit.fit` is
Levenberg-Marquardt over (T, p) on fixed contour points of the finish's objective
(`dream.polish.objective.Objective`), its derivatives in p by central differences, and
`CameraFit.jackknife_spreads` the delete-one-group jackknife of p and the pose over fits that
leave groups of those points out in turn. `fit_parameter` fits the parameters so from the search's
winner (the focal length's scale, the lens's radial distortion): rounds of the finish through
the camera at the current values, its contour points and the joint fit, then their covariance
(`parameter_covariance`), the IoU before and after, and how the pose moves with each (made
where asked for: `ParameterFit.sensitivity`).

A parameter whose first-order effect on the image a turn of the camera repeats (a shift of the
principal point) leaves the fit a long narrow valley, along which Levenberg-Marquardt crawls: on
a rendered scene given cx, cy 12, -8 px off, 10 linearisations a fit asked for 10.5, -6.3 px
after 6 rounds, 30 for 12.0, -8.0 (11.5 s). With the turn that undoes the shift's move at the
image centre carried by p (`principal_turn`), the valley is gone: 5 linearisations asked for
12.0, -8.0 px (2.8 s).

    >>> from dream.coarse.focal import with_focal_scale
    >>> fit = CameraFit(lambda camera, p: with_focal_scale(camera, float(np.exp(p[0]))), 1,
    ...                 derivative_step=1e-4, lm_iterations=10)
    >>> fit.size
    1
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.scales import Scales, finish_scale
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.optim import levenberg_marquardt
from dream.pnp import apply_increment, increment_between
from dream.polish.objective import Contour, Objective
from dream.polish.refine import JACKKNIFE_MIN_CONTOUR_POINTS, inner_lm_settings
from dream.refined_uncertainty import (
    MIN_GROUPS,
    frame_groups,
    jackknife_spread,
    links_with_points,
)
from dream.settings_checks import check_fields
from dream.transforms import R_from_rotvec

if TYPE_CHECKING:
    from dream.coarse.carried import CarriedRegion
    from dream.silhouette import RobotMeshes

log = logging.getLogger(__name__)

CameraMap = Callable[[CameraIntrinsics, np.ndarray], CameraIntrinsics]
TurnMap = Callable[[CameraIntrinsics, np.ndarray], np.ndarray]


def principal_turn(camera: CameraIntrinsics, p: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation of the camera frame that moves the image centre by -p[:2]
    pixels of `camera` (the optical axis onto the ray of (cx - du, cy - dv)): what a principal
    point moved by (du, dv) asks of the pose to first order.

    >>> from dream.camera import project
    >>> camera = CameraIntrinsics(100.0, 100.0, 50.0, 40.0, 100, 80)
    >>> C = principal_turn(camera, np.array([4.0, -2.0]))
    >>> np.round(project(camera, (C @ [0.0, 0.0, 1.0])[None]) - [50.0, 40.0], 6).tolist()
    [[-4.0, 2.0]]
    """
    ray = np.array([-float(p[0]) / camera.fx, -float(p[1]) / camera.fy, 1.0])
    ray /= np.linalg.norm(ray)
    axis = np.cross([0.0, 0.0, 1.0], ray)
    sine = np.linalg.norm(axis)
    if sine == 0.0:
        return np.eye(3)
    return R_from_rotvec(axis / sine * np.arctan2(sine, ray[2]))


def finest_objective(scales: Scales) -> Objective:
    """The finish's objective at the finest level of `scales` (its camera and masks)."""
    return scales.objective(-1)


def frame_group_keeps(contour: Contour, frames: int, groups: int) -> list[np.ndarray] | None:
    """For each of `groups` frame groups of `frames` frames, (N,) which contour points lie
    outside it (the points a delete-one-group fit keeps); None with fewer than `MIN_GROUPS`
    groups.

    >>> c = Contour(np.zeros((6, 3)), np.arange(6), np.zeros(6), None)
    >>> frame_group_keeps(c, 6, 3)[0].tolist()               # frames 0 and 3 left out
    [False, True, True, False, True, True]
    >>> frame_group_keeps(c, 6, 2) is None
    True
    """
    found = list(frame_groups(frames, groups).values())
    if len(found) < MIN_GROUPS:
        return None
    return [~np.isin(contour.frame, group) for group in found]


def link_keeps(contour: Contour, meshes: RobotMeshes) -> list[np.ndarray] | None:
    """For each link with at least `JACKKNIFE_MIN_CONTOUR_POINTS` of the contour points, (N,)
    which points lie off it (the points a fit leaving that link out keeps); None where
    `contour` names no vertices or fewer than `MIN_GROUPS` links have points. Something the
    arm carries, or a joint whose reading is off, pulls one link's outline alike in every
    frame, which no frame group sees."""
    if contour.vertex is None:
        return None
    link = meshes.vertex_link[contour.vertex]
    links = links_with_points(meshes.vertex_link, contour.vertex, meshes.links,
                              JACKKNIFE_MIN_CONTOUR_POINTS)
    if len(links) < MIN_GROUPS:
        return None
    return [link != meshes.links.index(name) for name in links]


@dataclass(frozen=True)
class CameraFit:
    """The joint fit of the pose and the camera parameters p (module doc).

    Attributes:
        camera_at: (camera, p (size,)) -> the camera p moves it to (p = 0: unchanged).
        size: how many parameters.
        turn_at: (camera, p) -> (3, 3) the turn of the camera frame p carries (p = 0: the
            identity); None: none.
        derivative_step: the central differences' step in each parameter.
        lm_iterations: Levenberg-Marquardt linearisations per fit.
    """

    camera_at: CameraMap
    size: int
    derivative_step: float
    lm_iterations: int
    turn_at: TurnMap | None = None

    def __post_init__(self) -> None:
        if self.size < 1 or self.lm_iterations < 1:
            raise InputError("camera fit: size and lm_iterations must be at least 1")
        if not self.derivative_step > 0:
            raise InputError("camera fit: derivative_step must be positive")

    def fit(self, objective: Objective, contour: Contour, T: np.ndarray,
            initial_damping: float, keep: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
        """(the pose, p (size,)) of the joint fit on `contour` through `objective`'s camera,
        from T and p = 0, Levenberg-Marquardt starting at `initial_damping`; `keep` (N,)
        weighs the points (default all 1). The pose returned holds p's turn."""
        weights = np.ones(len(contour.s)) if keep is None else np.asarray(keep, float)
        problem = _Problem(self, objective, contour, weights)
        lm = inner_lm_settings(initial_damping, self.lm_iterations)
        T_free, p = levenberg_marquardt(problem, (np.asarray(T, float), np.zeros(self.size)),
                                        lm).x
        return problem.pose(T_free, p), p

    def leave_outs(self, objective: Objective, contour: Contour, T: np.ndarray,
                   initial_damping: float, keeps: list[np.ndarray]
                   ) -> tuple[np.ndarray, np.ndarray]:
        """(G, 6) the poses (xi of `dream.pnp` from T) and (G, size) the parameters of the fits
        from T that keep the contour points `keeps` (G of (N,) bool) in turn."""
        fits = [self.fit(objective, contour, T, initial_damping, keep) for keep in keeps]
        return (np.array([increment_between(T, T_k) for T_k, _ in fits]).reshape(-1, 6),
                np.array([p for _, p in fits]).reshape(-1, self.size))

    def jackknife_spreads(self, objective: Objective, contour: Contour, T: np.ndarray,
                          initial_damping: float, keep_sets: list[list[np.ndarray] | None]
                          ) -> tuple[np.ndarray, np.ndarray]:
        """((size, size), (6, 6)) the delete-one-group jackknife covariances of p and of the
        pose over `leave_outs` (`dream.refined_uncertainty.jackknife_spread`), summed over
        `keep_sets` (each the keeps of one way to split the points, as `frame_group_keeps`
        and `link_keeps` give them; None: skipped)."""
        spreads = [self.leave_outs(objective, contour, T, initial_damping, keeps)
                   for keeps in keep_sets if keeps is not None]
        return (sum((jackknife_spread(ps) for _, ps in spreads), np.zeros((self.size,) * 2)),
                sum((jackknife_spread(xis) for xis, _ in spreads), np.zeros((6, 6))))


class _Problem:
    """`dream.optim.lm`'s view of a `CameraFit` on fixed contour points over (T_free, p), the
    pose C(p) T_free (`CameraFit.turn_at`); `keep` (N,) weighs each point (0: left out)."""

    def __init__(self, fit: CameraFit, objective: Objective, contour: Contour,
                 keep: np.ndarray):
        self.fit, self.objective, self.contour, self.keep = fit, objective, contour, keep

    def _at(self, p: np.ndarray) -> Objective:
        return self.objective.with_camera(self.fit.camera_at(self.objective.camera, p))

    def _turn(self, p: np.ndarray) -> np.ndarray:
        return (np.eye(3) if self.fit.turn_at is None
                else self.fit.turn_at(self.objective.camera, p))

    def pose(self, T_free: np.ndarray, p: np.ndarray) -> np.ndarray:
        """(4, 4) C(p) T_free."""
        C = np.eye(4)
        C[:3, :3] = self._turn(p)
        return C @ T_free

    def evaluate(self, x: tuple[np.ndarray, np.ndarray]) -> tuple[float, Any]:
        T_free, p = x
        objective = self._at(p)
        out = objective.residuals(self.contour, self.pose(T_free, p), jacobian=False)
        return (float("inf") if out is None
                else float(np.sum(self.keep * objective.rho(out[0])))), None

    def normal_equations(self, x: tuple[np.ndarray, np.ndarray], state: Any
                         ) -> tuple[np.ndarray, np.ndarray]:
        T_free, p = x
        objective = self._at(p)
        r, J = objective.residuals(self.contour, self.pose(T_free, p), jacobian=True)
        # `apply_increment` on T_free is one on C T_free with xi's halves turned by C
        C = self._turn(p)
        J = np.concatenate([J[:, :3] @ C, J[:, 3:] @ C], axis=1)
        step = self.fit.derivative_step
        columns = []
        for axis in np.eye(self.fit.size) * step:
            plus = self._at(p + axis).residuals(self.contour, self.pose(T_free, p + axis),
                                                jacobian=False)
            minus = self._at(p - axis).residuals(self.contour, self.pose(T_free, p - axis),
                                                 jacobian=False)
            columns.append(np.zeros(len(r)) if plus is None or minus is None
                           else (plus[0] - minus[0]) / (2 * step))
        J = np.column_stack([J, *columns])
        w = self.keep * objective.weight(r)
        return J.T @ (w[:, None] * J), J.T @ (w * r)

    def retract(self, x: tuple[np.ndarray, np.ndarray], dx: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        return apply_increment(x[0], dx[:6]), x[1] + dx[6:]


WITHIN, REFUTED, BEYOND, ADOPTED = "within", "refuted", "beyond", "adopted"


@dataclass(frozen=True)
class ParameterSettings:
    """How one camera parameter is fitted with the pose (`fit_parameter`) and when it is
    adopted (`decide`): the fields `dream.coarse.focal.FocalSettings` and
    `dream.coarse.distortion.DistortionSettings` share, each with its own defaults and words.

    Attributes:
        fit: fit it at all (False keeps the given camera and reports nothing).
        rounds: finish / contour / joint-fit rounds at most; they stop after a step below
            `step_tolerance` or a value beyond twice `max_change`.
        lm_iterations: Levenberg-Marquardt linearisations per joint fit.
        jackknife_groups: frame groups of the 1-sigma.
        min_sigmas, min_change: adopted only beyond both (|value|).
        min_iou_gain: adopted only where the finish's IoU through the fitted camera beats the
            given one's by more than this (the overlap is a second cue).
        max_change: beyond this |value|, nothing is adopted and the verdict says why.
        derivative_step: the central difference's step in the value.
        sensitivity_step: the step of the pose's sensitivity to it (the finishes at +- this).
        sigma_floor: added in quadrature to the jackknife's 1-sigma where an adopted value's
            uncertainty enters the pose's.
    """

    fit: bool = True
    rounds: int = 6
    lm_iterations: int = 10
    step_tolerance: float = 1e-3
    jackknife_groups: int = 5
    min_sigmas: float = 3.0
    min_change: float = 0.002
    min_iou_gain: float = 0.001
    max_change: float = 0.15
    derivative_step: float = 1e-4
    sensitivity_step: float = 0.01
    sigma_floor: float = 0.005
    what: ClassVar[str] = "camera parameter fit"

    def __post_init__(self) -> None:
        check_fields(self, self.what, positive_ints=("rounds", "lm_iterations",
                                                     "jackknife_groups"),
                     positive=("step_tolerance", "max_change", "derivative_step",
                               "sensitivity_step", "sigma_floor"),
                     non_negative=("min_sigmas", "min_change", "min_iou_gain"))
        if self.min_change >= self.max_change:
            raise InputError(f"{self.what}: min_change must lie below max_change")

    def decide(self, value: float, sigma: float, iou_given: float, iou_fitted: float) -> str:
        """`ADOPTED`, or why not: `WITHIN` (|value| within `min_sigmas` 1-sigmas or
        `min_change`, or no 1-sigma), `REFUTED` (the overlap gains no more than
        `min_iou_gain`), `BEYOND` (both cues ask for more than `max_change`).

        >>> settings = ParameterSettings()
        >>> [settings.decide(0.04, 0.003, 0.5, iou) for iou in (0.51, 0.5)]
        ['adopted', 'refuted']
        >>> settings.decide(0.04, 0.02, 0.5, 0.6), settings.decide(0.3, 0.003, 0.5, 0.6)
        ('within', 'beyond')
        """
        if not np.isfinite(sigma) or abs(value) <= max(self.min_change,
                                                       self.min_sigmas * sigma):
            return WITHIN
        if not overlap_agrees(iou_given, iou_fitted, self.min_iou_gain):
            return REFUTED
        return BEYOND if abs(value) > self.max_change else ADOPTED

    def covariance_used(self, covariance: np.ndarray) -> np.ndarray:
        """(k, k) the covariance adopted values' uncertainty enters the pose's with: `covariance`
        (0 where NaN) with `sigma_floor` squared added to each variance.

        >>> ParameterSettings(sigma_floor=0.004).covariance_used([[np.nan]]).tolist()
        [[1.6e-05]]
        """
        covariance = np.nan_to_num(np.atleast_2d(np.asarray(covariance, float)))
        return covariance + self.sigma_floor ** 2 * np.eye(len(covariance))

    @property
    def how(self) -> ParameterRounds:
        """How `fit_parameter` runs under these settings."""
        return ParameterRounds(self.rounds, self.step_tolerance, 2 * self.max_change,
                               self.jackknife_groups, self.sensitivity_step)


def overlap_agrees(iou_given: float, iou_asked: float, min_gain: float) -> bool:
    """Whether the finish's IoU through the camera the outlines ask for beats the IoU through
    the given one by more than `min_gain` (the second cue every intrinsics fit needs; NaN:
    no).

    >>> overlap_agrees(0.50, 0.52, 0.001), overlap_agrees(0.50, 0.5005, 0.001)
    (True, False)
    """
    return bool(iou_asked > iou_given + min_gain)


def adopted_pose_covariance(adopted: bool, covariance_used: np.ndarray | float,
                            xi_per_unit: np.ndarray) -> np.ndarray:
    """(6, 6) what adopted camera parameters' covariance `covariance_used` (k, k), a variance
    where k is 1, adds to the pose's covariance through the pose's move per unit of each,
    `xi_per_unit` (6, k); zero where they were not adopted (the given camera is then taken as
    it is).

    >>> float(adopted_pose_covariance(True, 0.04, np.array([0.5, 0, 0, 0, 0, 0]))[0, 0])
    0.01
    """
    if not adopted:
        return np.zeros((6, 6))
    X = np.asarray(xi_per_unit, float).reshape(6, -1)
    return X @ np.atleast_2d(covariance_used) @ X.T


@dataclass(frozen=True)
class ParameterRounds:
    """How `fit_parameter` runs: at most `rounds` rounds, stopping after a step below
    `step_tolerance` or a value beyond `stop_beyond`; the 1-sigma over `jackknife_groups`
    frame groups; the pose's sensitivity by the finishes at the value +- `sensitivity_step`."""

    rounds: int
    step_tolerance: float
    stop_beyond: float
    jackknife_groups: int
    sensitivity_step: float


@dataclass(frozen=True)
class ParameterFit:
    """Camera parameters fitted with the pose from the search's winner (`fit_parameter`).

    Attributes:
        value: (size,) the parameters where the outlines fit best (0: the camera as given).
        covariance: (size, size) their covariance (`parameter_covariance`; NaN without enough
            frame groups).
        iou_given, iou_fitted: the finish's IoU at 0 and at `value` (the pose refined there).
        rounds: the rounds run. T_cam_base: (4, 4) the finish at `value`.
        sensitivity: () -> (6, size) how the finish's pose moves (xi of `dream.pnp`) per unit
            of each: the finishes at `value` plus and minus a step, two per parameter, made
            only when called (only an adopted value's enters a covariance).
    """

    value: np.ndarray
    covariance: np.ndarray
    iou_given: float
    iou_fitted: float
    rounds: int
    T_cam_base: np.ndarray
    sensitivity: Callable[[], np.ndarray] = field(repr=False, compare=False)

    @property
    def sigma(self) -> np.ndarray:
        """(size,) the parameters' 1-sigmas."""
        return np.sqrt(np.diag(self.covariance))

    def xi_per_unit(self, wanted: bool) -> np.ndarray:
        """`sensitivity()` where `wanted`, else (6, size) NaN (written as null)."""
        return self.sensitivity() if wanted else np.full((6, len(self.value)), np.nan)


def fit_parameter(P: np.ndarray, meshes: RobotMeshes, masks: np.ndarray,
                  camera_of: Callable[[np.ndarray], CameraIntrinsics], T_cam_base: np.ndarray,
                  search: SearchSettings, fit: CameraFit, how: ParameterRounds,
                  held: bool = False, region: CarriedRegion | None = None) -> ParameterFit:
    """The `fit.size` parameters the outlines of the frames P (F, V, 3) in `masks` (F, H, W)
    ask for, from `T_cam_base` through `camera_of(0)`: rounds of the finish at the current
    values (`dream.coarse.scales.finish_scale` through `camera_of(values)`), its contour points
    and the joint fit over (pose, step) on them; `held`, `region`: as the search's `Scales`.
    With something carried (`region`) the covariance also spans the links."""
    def scales_at(value: np.ndarray) -> Scales:
        return finish_scale(P, meshes, masks, camera_of(value), search, None, held, region)

    value, T, iou_given, done = np.zeros(fit.size), np.asarray(T_cam_base, float), np.nan, 0
    objective: Objective | None = None
    for done in range(1, how.rounds + 1):
        scales = scales_at(value)
        T = scales.refine(T)
        if done == 1:
            iou_given = scales.iou(T)
        # the finest level's masks, so their distance fields, are the same at every value
        objective = (finest_objective(scales) if objective is None
                     else objective.with_camera(scales.levels[-1][0]))
        contour = scales.contour(T)
        T, p = fit.fit(objective, contour, T, scales.params.initial_damping)
        value = value + p
        log.debug("camera parameters round %d: %s (step %s)", done, np.round(value, 4),
                  np.round(p, 4))
        if np.max(np.abs(p)) < how.step_tolerance or np.max(np.abs(value)) > how.stop_beyond:
            break
    covariance = parameter_covariance(fit, objective, contour, T, scales.params.initial_damping,
                                      len(P), how.jackknife_groups, meshes,
                                      by_links=region is not None)
    final = scales_at(value)
    T = final.refine(T)

    def sensitivity() -> np.ndarray:
        h, xi = how.sensitivity_step, np.zeros((6, fit.size))
        for i, axis in enumerate(np.eye(fit.size) * h):
            ends = [scales_at(value + d).refine(T) for d in (axis, -axis)]
            xi[:, i] = (increment_between(T, ends[0]) - increment_between(T, ends[1])) / (2 * h)
        return xi

    return ParameterFit(value, covariance, iou_given, final.iou(T), done, T, sensitivity)


def parameter_covariance(fit: CameraFit, objective: Objective, contour: Contour,
                         T: np.ndarray, initial_damping: float, frames: int, groups: int,
                         meshes: RobotMeshes, by_links: bool) -> np.ndarray:
    """(size, size) the covariance of a fit's parameters: the delete-one-group jackknife over
    `groups` frame groups of the contour points, with `by_links` that over the links
    (`link_keeps`) added; NaN with fewer than `MIN_GROUPS` frame groups."""
    keeps = frame_group_keeps(contour, frames, groups)
    if keeps is None:
        return np.full((fit.size, fit.size), np.nan)
    by_link = link_keeps(contour, meshes) if by_links else None
    return fit.jackknife_spreads(objective, contour, T, initial_damping, [keeps, by_link])[0]
