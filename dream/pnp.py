"""Perspective-n-point: initial pose by SQPnP, then robust Levenberg-Marquardt on SE(3).

All functions take base-frame points `P_base` (N, 3) and observed pixels `uv` (N, 2) and return
`T_cam_base`. A pose update is `P_cam = exp(delta_rot) R P_base + t + delta_t`, so the
6-vector `xi = (delta_rot, delta_t)` lives in the camera frame: rotation in rad about the camera
axes, translation in m along them. Covariances and sigmas use this order and these frames.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from dream.camera import CameraIntrinsics, pixels_to_normalized
from dream import optim
from dream.errors import InputError
from dream.optim import LMSettings, RobustLoss
from dream.transforms import R_from_rotvec, T_from_rotvec_t, check_pose, rotvec_from_R

log = logging.getLogger(__name__)

MIN_KEYPOINTS = 4
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))  # median of |e| / sigma for 2D Gaussian e
_DAMPING_FACTOR = 10.0   # LM lambda is multiplied / divided by this on a rejected / kept step
_MIN_DAMPING = 1e-12
_MAX_DAMPING = 1e12      # a step is given up when lambda exceeds this (converged)
_TINY = 1e-300           # keeps the damping positive for a zero diagonal entry
_ZERO_ROTVEC = np.zeros(3)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_EYE3 = np.eye(3)
_EYE6 = np.eye(6)
_IN_FRONT = np.array([0.0, 0.0, 1.0])  # stands in for a point behind the camera (whose rows
                                      # `_linearise_batch` flags as meaningless)


@dataclass(frozen=True)
class SolverSettings:
    """Parameters of the pose solvers. Pixels unless named otherwise."""

    loss: RobustLoss = field(default_factory=RobustLoss)
    min_keypoints: int = MIN_KEYPOINTS
    max_iterations: int = 100
    step_tolerance: float = 1e-10       # stop when |xi| falls below (rad, m)
    convergence_sigma: float = 0.1      # stop when the pose is predicted to lie within this
                                        # many of its standard deviations of the optimum (0.1
                                        # adds at most 1 % to the error variance)
    initial_damping: float = 1e-3       # Levenberg-Marquardt lambda, relative to diag(H)
    collinear_ratio: float = 1e-3       # degenerate below: 2nd / 1st singular value of points
    max_condition: float = 1e12         # degenerate above: condition number of J^T W J
    ransac_hypotheses: int = 200        # random samples across frames (multi-frame solve)
    ransac_sample_size: int = 6
    ransac_threshold_px: float = 10.0   # MSAC truncation when ranking hypotheses
    inlier_sigma_factor: float = 4.0    # keypoints beyond this many robust sigmas are outliers
    min_inlier_threshold_px: float = 2.0
    outlier_rounds: int = 3             # reject -> refit rounds
    seed: int = 0

    def __post_init__(self) -> None:
        if self.min_keypoints < MIN_KEYPOINTS:
            raise InputError(f"min_keypoints must be >= {MIN_KEYPOINTS}")
        if self.ransac_sample_size < MIN_KEYPOINTS:
            raise InputError(f"ransac_sample_size must be >= {MIN_KEYPOINTS}")
        for name in ("ransac_threshold_px", "inlier_sigma_factor", "min_inlier_threshold_px"):
            if not getattr(self, name) > 0:
                raise InputError(f"{name} must be positive")
        if not self.convergence_sigma >= 0:
            raise InputError(f"convergence_sigma must be >= 0, got {self.convergence_sigma}")
        for name in ("initial_damping", "step_tolerance", "collinear_ratio", "max_condition"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"{name} must be positive and finite, got {value}",
                                 fix=f"use the default {self.__dataclass_fields__[name].default}")
        for name, least in (("max_iterations", 1), ("ransac_hypotheses", 0),
                            ("outlier_rounds", 0), ("seed", 0)):
            if getattr(self, name) < least:
                raise InputError(f"{name} must be >= {least}, got {getattr(self, name)}")


_DEFAULT_SETTINGS = SolverSettings()


@dataclass(frozen=True)
class NoSolution:
    """A structured failure: why this set of observations gives no pose."""

    reason: str


@dataclass(frozen=True)
class PoseFit:
    """A refined pose and its fit.

    Attributes:
        T_cam_base: (4, 4) extrinsic.
        residuals_px: (N, 2) projected minus observed pixels, NaN for unused (non-finite) input.
        inlier: (N,) True for keypoints kept in the final fit.
        weights: (N,) final weights (confidence x robust weight), 0 for outliers.
        covariance: (6, 6) covariance of xi = (delta_rot rad, delta_t m), camera frame, scaled by
            the residual variance.
        rmse_px: RMS pixel distance over inliers.
        iterations: LM iterations of the last refit.
    """

    T_cam_base: np.ndarray
    residuals_px: np.ndarray
    inlier: np.ndarray
    weights: np.ndarray
    covariance: np.ndarray
    rmse_px: float
    iterations: int

    @property
    def sigma_rotation_rad(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance)[:3])

    @property
    def sigma_translation_m(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance)[3:])

    @property
    def num_inliers(self) -> int:
        return int(self.inlier.sum())


def check_correspondences(P_base: np.ndarray, uv: np.ndarray,
                           confidence: np.ndarray | None) -> tuple[np.ndarray, ...]:
    P_base = np.asarray(P_base, dtype=float)
    uv = np.asarray(uv, dtype=float)
    if P_base.ndim != 2 or P_base.shape[1] != 3:
        raise InputError(f"P_base has shape {P_base.shape}, expected (N, 3)")
    if uv.shape != (len(P_base), 2):
        raise InputError(f"uv has shape {uv.shape}, expected ({len(P_base)}, 2)")
    if confidence is None:
        confidence = np.ones(len(P_base))
    confidence = np.asarray(confidence, dtype=float)
    if confidence.shape != (len(P_base),):
        raise InputError(f"confidence has shape {confidence.shape}, expected ({len(P_base)},)")
    usable = np.isfinite(P_base).all(1) & np.isfinite(uv).all(1) & \
        np.isfinite(confidence) & (confidence > 0)
    return P_base, uv, confidence, usable


def degeneracy(P_base: np.ndarray, settings: SolverSettings) -> str | None:
    """Why these 3D points cannot fix a pose, or None when they can."""
    if len(P_base) < settings.min_keypoints:
        return (f"only {len(P_base)} usable keypoints, at least {settings.min_keypoints} "
                f"are needed")
    # the squared singular values of the centred points are the eigenvalues of their scatter
    # matrix (OpenCV's symmetric eigensolver: a fraction of numpy's per-call cost on 3 x 3)
    centred = P_base - P_base.sum(0) / len(P_base)   # the mean, without np.mean's overhead
    _, s2 = cv2.eigen(centred.T @ centred)[:2]
    if not s2[0, 0] > 0 or s2[1, 0] < settings.collinear_ratio ** 2 * s2[0, 0]:
        return "the keypoints are (nearly) collinear or coincident"
    return None


def initial_pose(P_base: np.ndarray, uv: np.ndarray,
                 camera: CameraIntrinsics) -> np.ndarray | NoSolution:
    """T_cam_base from SQPnP on undistorted normalised points (no refinement)."""
    xy = pixels_to_normalized(camera, uv)
    try:
        ok, rvec, tvec = cv2.solvePnP(P_base.reshape(-1, 1, 3), xy.reshape(-1, 1, 2), _EYE3,
                                      None, flags=cv2.SOLVEPNP_SQPNP)
    except cv2.error as exc:
        return NoSolution(f"SQPnP failed ({str(exc).splitlines()[0]})")
    # a sum of a few finite terms is finite; NaN and infinities propagate
    if not ok or not (math.isfinite(rvec.sum()) and math.isfinite(tvec.sum())):
        return NoSolution("SQPnP found no pose")
    return T_from_rotvec_t(rvec.ravel(), tvec.ravel())


def linearise(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
              T: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Residuals (N, 2) and d residual / d xi (N, 2, 6); None if a point is behind the camera.

    One compiled call: OpenCV's `projectPoints` of the rotated points R P_base with rotation
    vector 0 and translation t, whose derivatives by that rotation vector and by t are exactly
    those by xi = (delta_rot, delta_t).
    """
    if len(P_base) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2, 6))
    RP = P_base @ T[:3, :3].T
    if not (RP[:, 2] + T[2, 3] > 0).all():
        return None
    return _residuals(RP, T, uv, camera)


def _linearise_rows(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                    T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`linearise` with (N,) True where the keypoint lies in front of the camera (the rows of
    the others are finite but meaningless)."""
    RP = P_base @ T[:3, :3].T
    front = RP[:, 2] + T[2, 3] > 0
    if not front.all():
        RP = np.where(front[:, None], RP, _IN_FRONT - T[:3, 3])
    return *_residuals(RP, T, uv, camera), front


def _residuals(P_rotated: np.ndarray, T: np.ndarray, uv: np.ndarray,
               camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (N, 2) and d residual / d xi (N, 2, 6) of the rotated points R P_base (in
    front of the camera) with T's translation (`linearise`)."""
    uv_hat, jac = _project(P_rotated, T[:3, 3], camera)
    return uv_hat - uv, jac[:, :6].reshape(len(P_rotated), 2, 6)


def _project(P_rotated: np.ndarray, t: np.ndarray,
             camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of the points P_rotated + t (camera frame) and OpenCV's Jacobian (2N, 15):
    columns 0-2 by a rotation vector applied to P_rotated (at 0), 3-5 by t."""
    uv_hat, jac = cv2.projectPoints(P_rotated, _ZERO_ROTVEC, t, camera.K,
                                    None if camera.distortion is None else camera.dist_coeffs)
    return uv_hat.reshape(-1, 2), jac


@dataclass(frozen=True)
class _Cameras:
    """The intrinsics of F frames (`CameraIntrinsics` each), with their focal lengths and
    principal points as (F, 1, 2) arrays that broadcast against (F, N, 2) pixels."""

    cameras: tuple[CameraIntrinsics, ...]
    focal: np.ndarray
    centre: np.ndarray
    distorted: bool                      # some frame's camera has a distortion

    @classmethod
    def of(cls, cameras: Sequence[CameraIntrinsics]) -> _Cameras:
        cameras = tuple(cameras)
        values = np.array([(c.fx, c.fy, c.cx, c.cy) for c in cameras], float).reshape(-1, 1, 4)
        return cls(cameras, values[..., :2], values[..., 2:],
                   any(c.distortion is not None for c in cameras))

    def take(self, frames: np.ndarray) -> _Cameras:
        cameras = tuple(self.cameras[f] for f in frames)
        return _Cameras(cameras, self.focal[frames], self.centre[frames],
                        self.distorted and any(c.distortion is not None for c in cameras))


def _linearise_batch(P_base: np.ndarray, uv: np.ndarray, cameras: _Cameras,
                    T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`linearise` of F frames at once: residuals (F, N, 2), d residual / d xi (F, N, 2, 6)
    and (F, N) True where the keypoint lies in front of the camera (the rows of the others are
    finite but meaningless). Inputs must be finite: P_base (F, N, 3), uv (F, N, 2), T (F, 4, 4).
    """
    F, n = P_base.shape[:2]
    if F == 1 or cameras.distorted:     # `linearise`'s OpenCV call, frame by frame
        rows = [_linearise_rows(P_base[f], uv[f], camera, T[f])
                for f, camera in enumerate(cameras.cameras)]
        return tuple(np.stack(a) for a in zip(*rows, strict=True))
    # pinhole in closed form: with p = R P, (X, Y, Z) = p + t, x = X / Z, y = Y / Z,
    # d(u, v) / dt = (fx, fy) / Z [[1, 0, -x], [0, 1, -y]] and d/d delta_rot = p x (that row)
    RP = P_base @ T[:, :3, :3].transpose(0, 2, 1)
    P_cam = RP + T[:, None, :3, 3]
    front = P_cam[..., 2] > 0
    inv_z = 1.0 / np.where(front, P_cam[..., 2], 1.0)
    x, y = P_cam[..., 0] * inv_z, P_cam[..., 1] * inv_z
    p0, p1, p2 = RP[..., 0], RP[..., 1], RP[..., 2]
    zero, one = np.zeros_like(x), np.ones_like(x)
    J = np.stack([np.stack([-x * p1, p2 + x * p0, -p1, one, zero, -x], -1),
                  np.stack([-y * p1 - p2, y * p0, p0, zero, one, -y], -1)], -2)
    J *= (cameras.focal * inv_z[..., None])[..., None]
    return cameras.focal * np.stack([x, y], -1) + cameras.centre - uv, J, front


def _distances(e: np.ndarray) -> np.ndarray:
    """(...,) pixel distances |e| of residuals (..., 2)."""
    return np.hypot(e[..., 0], e[..., 1])


def apply_increment(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """The update matching the Jacobians: P_cam = exp(xi_rot) R P_base + t + xi_t, for one pose
    (4, 4) and xi (6,) or F of them (F, 4, 4), (F, 6)."""
    T_new = np.empty(T.shape)
    T_new[..., :3, :3] = R_from_rotvec(xi[..., :3]) @ T[..., :3, :3]
    T_new[..., :3, 3] = T[..., :3, 3] + xi[..., 3:]
    T_new[..., 3, :] = _LAST_ROW
    return T_new


def increment_between(T_ref: np.ndarray, T: np.ndarray) -> np.ndarray:
    """xi (6,) with `apply_increment(T_ref, xi) == T`: the rotation vector of R R_ref^T and
    t - t_ref."""
    return np.concatenate([rotvec_from_R(T[:3, :3] @ T_ref[:3, :3].T), T[:3, 3] - T_ref[:3, 3]])


def _cost(distance: np.ndarray, confidence: np.ndarray, loss: RobustLoss) -> float:
    return float(confidence @ loss.rho(distance))


class _BehindCamera(Exception):
    """Internal: the starting pose puts keypoints behind the camera."""


class _PoseProblem:
    """`dream.optim.lm`'s view of one frame's robust reprojection error over T_cam_base."""

    def __init__(self, P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                 confidence: np.ndarray, loss: RobustLoss):
        self.P_base, self.uv, self.camera = P_base, uv, camera
        self.confidence, self.loss = confidence, loss

    def state_of(self, lin: tuple[np.ndarray, np.ndarray]) -> tuple[float, Any]:
        distance = _distances(lin[0])
        return _cost(distance, self.confidence, self.loss), (lin, distance)

    def evaluate(self, T: np.ndarray) -> tuple[float, Any]:
        lin = linearise(self.P_base, self.uv, self.camera, T)
        return (math.inf, None) if lin is None else self.state_of(lin)

    def normal_equations(self, T: np.ndarray, state: Any) -> tuple[np.ndarray, np.ndarray]:
        (e, J), distance = state
        WJ = _weighted_rows(J, self.confidence * self.loss.weight(distance))
        return WJ.T @ J.reshape(-1, 6), WJ.T @ e.reshape(-1)

    def retract(self, T: np.ndarray, xi: np.ndarray) -> np.ndarray:
        return apply_increment(T, xi)


def lm_settings(settings: SolverSettings, dof: int) -> LMSettings:
    """The LM constants of the pose solver; `dof` = residual degrees of freedom.

    The iteration stops before a step whose predicted decrease puts the pose within
    `convergence_sigma` standard deviations of the optimum: in squared standard deviations
    (covariance s^2 H^-1, s^2 = 2 cost / dof) the remaining distance is 2 predicted / s^2 =
    predicted dof / cost.
    """
    return LMSettings(initial_damping=settings.initial_damping, damping_up=_DAMPING_FACTOR,
                      damping_down=_DAMPING_FACTOR, min_damping=_MIN_DAMPING,
                      max_damping=_MAX_DAMPING, max_iterations=settings.max_iterations,
                      step_tolerance=settings.step_tolerance,
                      predicted_tolerance=settings.convergence_sigma ** 2 / dof)


def levenberg_marquardt(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                        T_init: np.ndarray, confidence: np.ndarray,
                        settings: SolverSettings,
                        lin_init: tuple[np.ndarray, np.ndarray] | None = None
                        ) -> tuple[np.ndarray, int, tuple[np.ndarray, np.ndarray]]:
    """Minimise sum_i c_i rho(|project(T P_i) - uv_i|) over T (IRLS inside LM).

    Returns the optimum, the number of iterations and `linearise` at the optimum. Inputs must
    be finite. `lin_init`: `linearise` at T_init when the caller has it.
    """
    problem = _PoseProblem(P_base, uv, camera, confidence, settings.loss)
    lin = linearise(P_base, uv, camera, T_init) if lin_init is None else lin_init
    if lin is None:
        raise _BehindCamera()
    dof = max(2 * int(np.count_nonzero(confidence)) - 6, 1)
    out = optim.levenberg_marquardt(problem, T_init.copy(), lm_settings(settings, dof),
                                    start=problem.state_of(lin))
    return out.x, out.iterations, out.state[0]


def _levenberg_marquardt_batch(P_base: np.ndarray, uv: np.ndarray, cameras: _Cameras,
                              T_init: np.ndarray, weights: np.ndarray,
                              settings: SolverSettings) -> _LMState:
    """For each of F frames, minimise sum_i w_i rho(|project(T P_i) - uv_i|) over T (IRLS inside
    LM), all frames in lockstep (each takes the steps it would take alone).

    `weights` (F, N): the confidence of the keypoints fitted, 0 for the others (which are
    linearised too, so the result holds residuals and Jacobians of every keypoint at the
    optimum). A frame whose start puts a fitted keypoint behind the camera is not iterated
    (`started` False). Inputs must be finite.
    """
    loss = settings.loss
    fitted = weights > 0
    T = T_init.copy()
    e, J, front = _linearise_batch(P_base, uv, cameras, T)
    started = np.all(front | ~fitted, axis=1)
    distance = _distances(e)
    cost = np.sum(weights * loss.rho(distance), axis=1)
    dof = np.maximum(2 * fitted.sum(axis=1) - 6, 1)
    F = len(T)
    lam = np.full(F, settings.initial_damping)
    iterations = np.zeros(F, int)
    H, g, damping = np.zeros((F, 6, 6)), np.zeros((F, 6)), np.zeros((F, 6))
    active, new_iteration = started.copy(), started.copy()
    while active.any():
        # an iteration starts: its limit, or a damping beyond which no step is tried, ends it
        ended = new_iteration & ((iterations >= settings.max_iterations) | (lam >= _MAX_DAMPING))
        active &= ~ended
        start = new_iteration & active
        if start.any():
            iterations += start
            WJ = _weighted_rows(J, weights * loss.weight(distance))
            H[start] = (WJ.transpose(0, 2, 1) @ J.reshape(F, -1, 6))[start]
            g[start] = (WJ.transpose(0, 2, 1) @ e.reshape(F, -1, 1))[start, :, 0]
            damping[start] = np.diagonal(H[start], axis1=1, axis2=2) + _TINY
        A = H + (lam[:, None] * damping)[:, :, None] * _EYE6
        A[~active] = _EYE6
        xi = np.linalg.solve(A, -g[..., None])[..., 0]
        # the decrease the reweighted quadratic model predicts is, in squared standard
        # deviations of the pose (covariance s^2 H^-1, s^2 = 2 cost / dof), the remaining
        # distance to the optimum: d^2 = 2 predicted / s^2 = predicted dof / cost
        predicted = -np.sum(g * xi, axis=1) - 0.5 * np.einsum("fi,fij,fj->f", xi, H, xi)
        active &= predicted * dof > settings.convergence_sigma ** 2 * cost
        if not active.any():
            break
        T_new = apply_increment(T, xi)
        e_new, J_new, front_new = _linearise_batch(P_base, uv, cameras, T_new)
        distance_new = _distances(e_new)
        cost_new = np.sum(weights * loss.rho(distance_new), axis=1)
        accept = active & np.all(front_new | ~fitted, axis=1) & (cost_new <= cost)
        T[accept], e[accept], J[accept] = T_new[accept], e_new[accept], J_new[accept]
        front[accept], distance[accept], cost[accept] = \
            front_new[accept], distance_new[accept], cost_new[accept]
        lam = np.where(accept, np.maximum(lam / _DAMPING_FACTOR, _MIN_DAMPING),
                       np.where(active, lam * _DAMPING_FACTOR, lam))
        # a kept step below the tolerance ends; a refused one is retried with more damping
        # unless that passes the limit (then no step improves: converged)
        active &= ~(accept & (np.sum(xi * xi, axis=1) < settings.step_tolerance ** 2))
        active &= accept | (lam < _MAX_DAMPING)
        new_iteration = accept
    return _LMState(T, iterations, e, J, front, started)


@dataclass(frozen=True)
class _LMState:
    """`_levenberg_marquardt_batch`'s result: the poses (F, 4, 4), iterations (F,), residuals
    (F, N, 2), Jacobians (F, N, 2, 6) and in-front mask (F, N) of every keypoint there, and
    (F,) whether the frame could start."""

    T: np.ndarray
    iterations: np.ndarray
    e: np.ndarray
    J: np.ndarray
    front: np.ndarray
    started: np.ndarray


def _weighted_rows(J: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(..., 2N, 6) rows of the Jacobians (..., N, 2, 6) scaled by their keypoint's weight
    (..., N): with them, J^T W J = `_weighted_rows(J, w).T @ J.reshape(-1, 6)`."""
    return (J * weights[..., None, None]).reshape(*J.shape[:-3], -1, 6)


def _covariance(e: np.ndarray, J: np.ndarray,
                weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual-scaled covariances (..., 6, 6) of xi and condition numbers (...) of J^T W J,
    from the residuals (..., N, 2), Jacobians (..., N, 2, 6) and weights (..., N) at the poses
    (NaN covariance without redundancy, infinite condition number when singular)."""
    H = np.swapaxes(_weighted_rows(J, weights), -1, -2) @ J.reshape(*J.shape[:-3], -1, 6)
    dof = 2 * np.count_nonzero(weights, axis=-1) - 6
    s2 = np.sum(weights * np.sum(e * e, axis=-1), axis=-1) / np.where(dof > 0, dof, np.nan)
    # H is symmetric positive semi-definite: its singular values are its eigenvalues
    eigenvalues, V = np.linalg.eigh(H)
    positive = np.where(eigenvalues[..., :1] > 0, eigenvalues, np.nan)
    covariance = s2[..., None, None] * (V / positive[..., None, :]) @ np.swapaxes(V, -1, -2)
    condition = positive[..., -1] / positive[..., 0]
    return covariance, np.where(np.isnan(condition), np.inf, condition)


def _covariance_one(e: np.ndarray, J: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float]:
    """`_covariance` of one frame (e (N, 2), J (N, 2, 6), weights (N,)) with scalar bookkeeping
    and OpenCV's eigensolver (a fraction of numpy's per-call cost on 6 x 6)."""
    WJ = _weighted_rows(J, weights)
    H = WJ.T @ J.reshape(-1, 6)
    dof = 2 * np.count_nonzero(weights) - 6
    s2 = float((weights * (e * e).sum(axis=-1)).sum()) / dof if dof > 0 else math.nan
    _, eigenvalues, V = cv2.eigen(H)               # descending, eigenvectors as rows
    eigenvalues, V = eigenvalues[::-1, 0], V[::-1].T
    if not eigenvalues[0] > 0:
        return np.full((6, 6), np.nan), math.inf
    return (s2 * (V / eigenvalues)) @ V.T, float(eigenvalues[-1] / eigenvalues[0])


def _degenerate(P_base: np.ndarray, mask: np.ndarray, settings: SolverSettings) -> np.ndarray:
    """(F,) True where the points P_base (F, N, 3) selected by mask (F, N) cannot fix a pose
    (`degeneracy` of each frame: zero rows leave the singular values unchanged)."""
    count = mask.sum(axis=1)
    mean = np.sum(np.where(mask[..., None], P_base, 0.0), axis=1) / np.maximum(count, 1)[:, None]
    s = np.linalg.svd(np.where(mask[..., None], P_base - mean[:, None], 0.0), compute_uv=False)
    return (count < settings.min_keypoints) | ~(s[:, 0] > 0) | \
        (s[:, 1] < settings.collinear_ratio * s[:, 0])


def _masked_median(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(F,) median of each row of x (F, N) over its mask (at least one True per row)."""
    x = np.sort(np.where(mask, x, np.inf), axis=1)
    n = mask.sum(axis=1)
    rows = np.arange(len(x))
    return 0.5 * (x[rows, (n - 1) // 2] + x[rows, n // 2])


def fit_pose(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics, T_init: np.ndarray,
             *, confidence: np.ndarray | None = None, inlier: np.ndarray | None = None,
             settings: SolverSettings | None = None) -> PoseFit | NoSolution:
    """Robust refinement from T_init with rounds of outlier rejection.

    `inlier` (N,) optionally restricts the first round to a subset (e.g. RANSAC inliers).
    Non-finite rows of P_base / uv and zero confidences are ignored.
    """
    settings = settings or _DEFAULT_SETTINGS
    T_init = check_pose(T_init, "T_init")
    P_base, uv, confidence, usable = check_correspondences(P_base, uv, confidence)
    keep = usable if inlier is None else usable & np.asarray(inlier, bool)
    reason = degeneracy(P_base[keep], settings)
    if reason is not None:
        return NoSolution(reason)
    return _fit_checked(P_base, uv, camera, T_init, confidence, usable, keep, settings)


def _fit_checked(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics, T: np.ndarray,
                 confidence: np.ndarray, usable: np.ndarray, keep: np.ndarray,
                 settings: SolverSettings,
                 lin_init: tuple[np.ndarray, np.ndarray] | None = None) -> PoseFit | NoSolution:
    """`fit_pose` on checked correspondences (`check_correspondences`), starting from the
    keypoints `keep` (a subset of `usable`, not degenerate: `degeneracy`). `lin_init`:
    `linearise` of the keypoints `keep` at T when the caller has it."""
    P_usable, uv_usable = P_base[usable], uv[usable]
    iterations = 0
    for round_ in range(settings.outlier_rounds + 1):
        try:
            T, iterations, lin = levenberg_marquardt(P_base[keep], uv[keep], camera, T,
                                                     confidence[keep], settings, lin_init)
            lin_init = None
        except _BehindCamera:
            return NoSolution("the initial pose puts keypoints behind the camera")
        if not (keep == usable).all():  # else `lin` is already that of every usable one
            lin = linearise(P_usable, uv_usable, camera, T)
            if lin is None:
                return NoSolution("the solution puts keypoints behind the camera")
        dist = np.full(len(P_base), np.inf)
        dist[usable] = _distances(lin[0])
        sigma = _median(dist[keep]) / RAYLEIGH_MEDIAN
        if round_ == settings.outlier_rounds:
            break                           # no refit follows: `keep` stays the fitted set
        threshold = max(settings.min_inlier_threshold_px, settings.inlier_sigma_factor * sigma)
        new_keep = usable & (dist <= threshold)
        # a round that would leave too few or degenerate keypoints ends the rejection: the fit
        # of the last usable set stands (so `keep` is never degenerate)
        if (new_keep == keep).all() or degeneracy(P_base[new_keep], settings) is not None:
            break
        keep = new_keep
    weights = np.zeros(len(P_base))
    weights[keep] = confidence[keep] * settings.loss.weight(dist[keep])
    # `lin` holds the residuals and Jacobians of the usable keypoints at the final T
    residuals = np.full((len(P_base), 2), np.nan)
    residuals[usable] = lin[0]
    kept = keep[usable]                     # keep is a subset of usable
    covariance, cond = _covariance_one(lin[0][kept], lin[1][kept], weights[keep])
    if cond > settings.max_condition:
        return NoSolution(f"the pose is not determined by these keypoints (condition number "
                          f"{cond:.1e})")
    kept_dist = dist[keep]
    rmse = math.sqrt(float((kept_dist * kept_dist).sum()) / len(kept_dist))
    return PoseFit(T, residuals, keep, weights, covariance, rmse, iterations)


def _median(x: np.ndarray) -> float:
    """np.median of a short 1D array without its overhead."""
    x = np.sort(x)
    n = len(x)
    return float(0.5 * (x[(n - 1) // 2] + x[n // 2]))


def _finite(a: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """a (F, N, D) with the rows of unusable keypoints set to 0 (finite for the batch maths)."""
    return np.where(usable[..., None], a, 0.0)


def _fit_batch(P_base: np.ndarray, uv: np.ndarray, cameras: _Cameras, T: np.ndarray,
               confidence: np.ndarray, usable: np.ndarray, keep: np.ndarray,
               settings: SolverSettings) -> list[PoseFit | NoSolution]:
    """`fit_pose` of F frames on checked correspondences (`check_correspondences`, the rows of
    unusable keypoints made finite by `_finite`), each starting from its keypoints `keep` (F, N)
    (a subset of `usable`, not degenerate), all frames' rounds of outlier rejection in step."""
    F, N = usable.shape
    T, keep = T.copy(), keep.copy()
    iterations = np.zeros(F, int)
    e, J = np.zeros((F, N, 2)), np.zeros((F, N, 2, 6))
    dist = np.full((F, N), np.inf)
    failed: dict[int, NoSolution] = {}
    rounding = np.ones(F, bool)          # frames still in rounds of rejection
    for round_ in range(settings.outlier_rounds + 1):
        frames = np.flatnonzero(rounding)
        if not len(frames):
            break
        lm = _levenberg_marquardt_batch(P_base[frames], uv[frames], cameras.take(frames),
                                       T[frames], np.where(keep[frames], confidence[frames], 0.0),
                                       settings)
        T[frames], iterations[frames], e[frames], J[frames] = lm.T, lm.iterations, lm.e, lm.J
        behind = np.any(usable[frames] & ~lm.front, axis=1)
        for f, started, back in zip(frames.tolist(), lm.started.tolist(), behind.tolist(),
                                    strict=True):
            if not started:
                failed[f] = NoSolution("the initial pose puts keypoints behind the camera")
            elif back:
                failed[f] = NoSolution("the solution puts keypoints behind the camera")
        dist[frames] = np.where(usable[frames], _distances(lm.e), np.inf)
        sigma = _masked_median(dist[frames], keep[frames]) / RAYLEIGH_MEDIAN
        threshold = np.maximum(settings.min_inlier_threshold_px,
                               settings.inlier_sigma_factor * sigma)
        new_keep = usable[frames] & (dist[frames] <= threshold[:, None])
        # a round that would leave too few or degenerate keypoints ends the rejection: the fit
        # of the last usable set stands (so `keep` is never degenerate)
        ends = np.all(new_keep == keep[frames], axis=1) | \
            _degenerate(P_base[frames], new_keep, settings)
        ends |= ~lm.started | behind
        if round_ == settings.outlier_rounds:
            ends[:] = True                  # no refit follows: `keep` stays the fitted set
        keep[frames[~ends]] = new_keep[~ends]
        rounding[frames[ends]] = False
    weights = np.where(keep, confidence * settings.loss.weight(np.where(keep, dist, 0.0)), 0.0)
    covariance, condition = _covariance(e, J, weights)
    rmse = np.sqrt(np.sum(np.where(keep, dist, 0.0) ** 2, axis=1) / keep.sum(axis=1))
    residuals = np.where(usable[..., None], e, np.nan)
    out: list[PoseFit | NoSolution] = []
    for f in range(F):
        if f in failed:
            out.append(failed[f])
        elif condition[f] > settings.max_condition:
            out.append(NoSolution(f"the pose is not determined by these keypoints (condition "
                                  f"number {condition[f]:.1e})"))
        else:
            out.append(PoseFit(T[f], residuals[f], keep[f], weights[f], covariance[f],
                               float(rmse[f]), int(iterations[f])))
    return out


def solve_pnp(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics, *,
              confidence: np.ndarray | None = None,
              settings: SolverSettings | None = None) -> PoseFit | NoSolution:
    """Pose of one frame: SQPnP on all usable keypoints; when that leaves a keypoint outside the
    MSAC threshold, also on leave-one-out subsets (to survive a wrong detection); the hypothesis
    with the lowest truncated cost refined robustly. (`solve_pnp_batch`: many frames at once,
    the same results.)"""
    settings = settings or _DEFAULT_SETTINGS
    P_base, uv, confidence, usable = check_correspondences(P_base, uv, confidence)
    reason = degeneracy(P_base[usable], settings)
    if reason is not None:
        return NoSolution(reason)
    idx = usable.nonzero()[0]
    first, distance = initial_pose(P_base[idx], uv[idx], camera), None
    if isinstance(first, NoSolution):
        first = None
    else:
        # the residuals at the first pose: its MSAC test and the refinement's start
        e, J, front = _linearise_rows(P_base[idx], uv[idx], camera, first)
        distance = np.where(front, _distances(e), np.inf)
        if front.all() and (distance ** 2 <= settings.ransac_threshold_px ** 2).all():
            # every keypoint agrees (all are MSAC inliers): no subset can do better
            return _fit_checked(P_base, uv, camera, first, confidence, usable, usable, settings,
                                (e, J))
    start = _leave_one_out_start(P_base, uv, camera, usable, first, distance, settings)
    if isinstance(start, NoSolution):
        return start
    return _fit_checked(P_base, uv, camera, start[0], confidence, usable, start[1], settings)


def solve_pnp_batch(P_base: np.ndarray, uv: np.ndarray, cameras: Sequence[CameraIntrinsics], *,
                    confidence: np.ndarray | None = None,
                    settings: SolverSettings | None = None) -> list[PoseFit | NoSolution]:
    """`solve_pnp` of each of F frames (each solved alone, with its own camera), the frames'
    refinements run together so that the fixed cost of a step is paid once per batch.

    Args:
        P_base: (F, N, 3) keypoints in the base frame.
        uv: (F, N, 2) detections, NaN where not found.
        cameras: F intrinsics, one per frame.
        confidence: (F, N) or None (all 1).
    """
    settings = settings or _DEFAULT_SETTINGS
    P_base, uv = np.asarray(P_base, dtype=float), np.asarray(uv, dtype=float)
    if P_base.ndim != 3 or P_base.shape[2] != 3:
        raise InputError(f"P_base has shape {P_base.shape}, expected (F, N, 3)")
    F, N = P_base.shape[:2]
    if len(cameras) != F:
        raise InputError(f"{len(cameras)} cameras for {F} frames", fix="give one camera per frame")
    if confidence is not None and np.shape(confidence) != (F, N):
        raise InputError(f"confidence has shape {np.shape(confidence)}, expected ({F}, {N})")
    if uv.shape != (F, N, 2):
        raise InputError(f"uv has shape {uv.shape}, expected ({F}, {N}, 2)")
    P_flat, uv_flat, conf_flat, usable_flat = check_correspondences(
        P_base.reshape(-1, 3), uv.reshape(-1, 2),
        None if confidence is None else np.asarray(confidence, dtype=float).reshape(-1))
    usable, confidence = usable_flat.reshape(F, N), conf_flat.reshape(F, N)
    if F == 0:
        return []
    out: list[PoseFit | NoSolution | None] = [None] * F
    P_finite, uv_finite = _finite(P_base, usable), _finite(uv, usable)
    all_cameras = _Cameras.of(cameras)
    degenerate = _degenerate(P_finite, usable, settings)
    firsts: dict[int, np.ndarray] = {}
    for f in range(F):
        idx = np.flatnonzero(usable[f])
        if degenerate[f]:
            out[f] = NoSolution(degeneracy(P_base[f, idx], settings) or "degenerate keypoints")
            continue
        first = initial_pose(P_base[f, idx], uv[f, idx], cameras[f])
        if not isinstance(first, NoSolution):
            firsts[f] = first
    # every keypoint agrees with the first pose (all are MSAC inliers): no subset does better
    first_distance = np.full((F, N), np.inf)          # inf behind the camera
    if firsts:
        frames = np.array(list(firsts))
        e, _, front = _linearise_batch(P_finite[frames], uv_finite[frames],
                                       all_cameras.take(frames), np.array(list(firsts.values())))
        first_distance[frames] = np.where(front, _distances(e), np.inf)
    agree = np.all((first_distance ** 2 <= settings.ransac_threshold_px ** 2) | ~usable, axis=1)
    starts: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for f in range(F):
        if out[f] is not None:
            continue
        if agree[f]:
            starts[f] = (firsts[f], usable[f])
            continue
        first = firsts.get(f)
        start = _leave_one_out_start(P_base[f], uv[f], cameras[f], usable[f], first,
                                     None if first is None else first_distance[f, usable[f]],
                                     settings)
        if isinstance(start, NoSolution):
            out[f] = start
        else:
            starts[f] = start
    if starts:
        frames = np.array(list(starts))
        fits = _fit_batch(P_finite[frames], uv_finite[frames], all_cameras.take(frames),
                          np.array([starts[f][0] for f in frames]), confidence[frames],
                          usable[frames], np.array([starts[f][1] for f in frames]), settings)
        for f, fit in zip(frames.tolist(), fits, strict=True):
            out[f] = fit
    return out


def _leave_one_out_start(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                         usable: np.ndarray, first: np.ndarray | None,
                         first_distance: np.ndarray | None,
                         settings: SolverSettings) -> tuple[np.ndarray, np.ndarray] | NoSolution:
    """The start (pose, keypoints to fit) of a frame whose first pose (SQPnP on every usable
    keypoint, None if it failed) leaves a keypoint outside the MSAC threshold (its pixel
    distances over the usable keypoints: `first_distance`): SQPnP on leave-one-out subsets too,
    the keypoint worst explained by the first pose left out first, then the hypothesis with the
    lowest MSAC cost (`best_hypothesis`)."""
    idx = usable.nonzero()[0]
    P_usable, uv_usable = P_base[idx], uv[idx]
    hypotheses, order = [], np.arange(len(idx))
    if first is not None:
        hypotheses, order = [first], np.argsort(-first_distance)
    # each hypothesis' squared distances over the usable keypoints, computed once: its MSAC
    # score (`best_hypothesis`) and, without the left-out keypoint, its subset's agreement
    d2s = [_reprojection_distance(P_usable, uv_usable, camera, T) ** 2 for T in hypotheses]
    threshold2 = settings.ransac_threshold_px ** 2
    if len(idx) > settings.min_keypoints:
        for i in order:
            subset = np.delete(idx, i)
            if degeneracy(P_base[subset], settings) is not None:
                continue
            T = initial_pose(P_base[subset], uv[subset], camera)
            if isinstance(T, NoSolution):
                continue
            hypotheses.append(T)
            d2s.append(_reprojection_distance(P_usable, uv_usable, camera, T) ** 2)
            if (np.delete(d2s[-1], i) <= threshold2).all():
                break   # all but the left-out keypoint agree: no other subset does better
    if not hypotheses:
        return NoSolution("no initial pose could be found")
    start = _best_scored(d2s, hypotheses, usable, settings)
    T, keep = start
    reason = degeneracy(P_base[keep], settings)
    return NoSolution(reason) if reason is not None else (T, keep)


def _reprojection_distance(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                           T: np.ndarray) -> np.ndarray:
    """(N,) pixel distance between projected and observed keypoints (inf behind the camera)."""
    RP = P_base @ T[:3, :3].T
    front = RP[:, 2] + T[2, 3] > 0
    if front.all():
        return _distances(_project(RP, T[:3, 3], camera)[0] - uv)
    distance = np.full(len(P_base), np.inf)
    if np.any(front):
        distance[front] = _distances(_project(RP[front], T[:3, 3], camera)[0] - uv[front])
    return distance


def best_hypothesis(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                    hypotheses: list[np.ndarray], usable: np.ndarray,
                    settings: SolverSettings) -> tuple[np.ndarray, np.ndarray] | NoSolution:
    """The hypothesis with the lowest MSAC score over the usable keypoints and its inliers (N,)
    (every usable keypoint when fewer than `min_keypoints` are inliers)."""
    if not hypotheses:
        return NoSolution("no initial pose could be found")
    return _best_scored([_reprojection_distance(P_base[usable], uv[usable], camera, T) ** 2
                         for T in hypotheses], hypotheses, usable, settings)


def _best_scored(d2s: list[np.ndarray], hypotheses: list[np.ndarray], usable: np.ndarray,
                 settings: SolverSettings) -> tuple[np.ndarray, np.ndarray]:
    """`best_hypothesis` from each hypothesis' squared pixel distances over the usable keypoints
    (the MSAC cost: their sum truncated at the threshold; inliers: those within it)."""
    threshold2 = settings.ransac_threshold_px ** 2
    costs = [float(np.minimum(d2, threshold2).sum()) for d2 in d2s]
    best = min(range(len(costs)), key=costs.__getitem__)
    inlier = np.zeros(len(usable), bool)
    inlier[usable.nonzero()[0][d2s[best] <= threshold2]] = True
    if inlier.sum() < settings.min_keypoints:
        inlier = usable
    return hypotheses[best], inlier


def refine_best(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                hypotheses: list[np.ndarray], confidence: np.ndarray, usable: np.ndarray,
                settings: SolverSettings) -> PoseFit | NoSolution:
    """Rank hypotheses by MSAC score over the usable keypoints and refine the best one."""
    start = best_hypothesis(P_base, uv, camera, hypotheses, usable, settings)
    if isinstance(start, NoSolution):
        return start
    return fit_pose(P_base, uv, camera, start[0], confidence=confidence, inlier=start[1],
                    settings=settings)
