"""One frame's pose: SQPnP start, leave-one-out hypotheses, and robust Levenberg-Marquardt.

`solve_pnp` solves a frame from its keypoints alone; `fit_pose` refines a given pose with
rounds of outlier rejection. The damped iteration is `dream.optim.levenberg_marquardt` on the
frame's robust reprojection error over T_cam_base (`_PoseProblem`), stepping in xi
(`dream.pnp.reprojection`).
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from dream import optim
from dream.camera import CameraIntrinsics, pixels_to_normalized
from dream.errors import InputError
from dream.optim import LMSettings, RobustLoss
from dream.pnp.reprojection import (
    apply_increment,
    linearise,
    linearise_rows,
    pixel_distances,
    reprojection_distance,
    weighted_rows,
)
from dream.pnp.settings import (
    DAMPING_FACTOR,
    DEFAULT_SETTINGS,
    MAX_DAMPING,
    MIN_DAMPING,
    RAYLEIGH_MEDIAN,
    NoSolution,
    PoseFit,
    SolverSettings,
)
from dream.transforms import T_from_rotvec_t, check_pose

_EYE3 = np.eye(3)


def check_correspondences(P_base: np.ndarray, uv: np.ndarray,
                           confidence: np.ndarray | None) -> tuple[np.ndarray, ...]:
    """P_base (N, 3), uv (N, 2) and confidence (N,) (all 1 when None) as float arrays, and (N,)
    True where a keypoint is usable (finite, with a positive confidence)."""
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
        distance = pixel_distances(lin[0])
        return _cost(distance, self.confidence, self.loss), (lin, distance)

    def evaluate(self, T: np.ndarray) -> tuple[float, Any]:
        lin = linearise(self.P_base, self.uv, self.camera, T)
        return (math.inf, None) if lin is None else self.state_of(lin)

    def normal_equations(self, T: np.ndarray, state: Any) -> tuple[np.ndarray, np.ndarray]:
        (e, J), distance = state
        WJ = weighted_rows(J, self.confidence * self.loss.weight(distance))
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
    return LMSettings(initial_damping=settings.initial_damping, damping_up=DAMPING_FACTOR,
                      damping_down=DAMPING_FACTOR, min_damping=MIN_DAMPING,
                      max_damping=MAX_DAMPING, max_iterations=settings.max_iterations,
                      step_tolerance=settings.step_tolerance,
                      predicted_tolerance=settings.convergence_sigma ** 2 / dof)


def refine_pose(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
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


def fit_pose(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics, T_init: np.ndarray,
             *, confidence: np.ndarray | None = None, inlier: np.ndarray | None = None,
             settings: SolverSettings | None = None) -> PoseFit | NoSolution:
    """Robust refinement from T_init with rounds of outlier rejection.

    `inlier` (N,) optionally restricts the first round to a subset (e.g. RANSAC inliers).
    Non-finite rows of P_base / uv and zero confidences are ignored.
    """
    settings = settings or DEFAULT_SETTINGS
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
            T, iterations, lin = refine_pose(P_base[keep], uv[keep], camera, T,
                                             confidence[keep], settings, lin_init)
            lin_init = None
        except _BehindCamera:
            return NoSolution("the initial pose puts keypoints behind the camera")
        if not (keep == usable).all():  # else `lin` is already that of every usable one
            lin = linearise(P_usable, uv_usable, camera, T)
            if lin is None:
                return NoSolution("the solution puts keypoints behind the camera")
        dist = np.full(len(P_base), np.inf)
        dist[usable] = pixel_distances(lin[0])
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


def _covariance_one(e: np.ndarray, J: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float]:
    """`dream.pnp.batch._covariance` of one frame (e (N, 2), J (N, 2, 6), weights (N,)) with
    scalar bookkeeping and OpenCV's eigensolver (a fraction of numpy's per-call cost on 6 x 6)."""
    WJ = weighted_rows(J, weights)
    H = WJ.T @ J.reshape(-1, 6)
    dof = 2 * np.count_nonzero(weights) - 6
    s2 = float((weights * (e * e).sum(axis=-1)).sum()) / dof if dof > 0 else math.nan
    _, eigenvalues, V = cv2.eigen(H)               # descending, eigenvectors as rows
    eigenvalues, V = eigenvalues[::-1, 0], V[::-1].T
    if not eigenvalues[0] > 0:
        return np.full((6, 6), np.nan), math.inf
    return (s2 * (V / eigenvalues)) @ V.T, float(eigenvalues[-1] / eigenvalues[0])


def solve_pnp(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics, *,
              confidence: np.ndarray | None = None,
              settings: SolverSettings | None = None) -> PoseFit | NoSolution:
    """Pose of one frame: SQPnP on all usable keypoints; when that leaves a keypoint outside the
    MSAC threshold, also on leave-one-out subsets (to survive a wrong detection); the hypothesis
    with the lowest truncated cost refined robustly. (`solve_pnp_batch`: many frames at once,
    the same results.)"""
    settings = settings or DEFAULT_SETTINGS
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
        e, J, front = linearise_rows(P_base[idx], uv[idx], camera, first)
        distance = np.where(front, pixel_distances(e), np.inf)
        if front.all() and (distance ** 2 <= settings.ransac_threshold_px ** 2).all():
            # every keypoint agrees (all are MSAC inliers): no subset can do better
            return _fit_checked(P_base, uv, camera, first, confidence, usable, usable, settings,
                                (e, J))
    start = leave_one_out_start(P_base, uv, camera, usable, first, distance, settings)
    if isinstance(start, NoSolution):
        return start
    return _fit_checked(P_base, uv, camera, start[0], confidence, usable, start[1], settings)


def leave_one_out_start(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
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
    d2s = [reprojection_distance(P_usable, uv_usable, camera, T) ** 2 for T in hypotheses]
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
            d2s.append(reprojection_distance(P_usable, uv_usable, camera, T) ** 2)
            if (np.delete(d2s[-1], i) <= threshold2).all():
                break   # all but the left-out keypoint agree: no other subset does better
    if not hypotheses:
        return NoSolution("no initial pose could be found")
    start = best_scored(d2s, hypotheses, usable, settings)
    T, keep = start
    reason = degeneracy(P_base[keep], settings)
    return NoSolution(reason) if reason is not None else (T, keep)


def best_scored(d2s: list[np.ndarray], hypotheses: list[np.ndarray], usable: np.ndarray,
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
