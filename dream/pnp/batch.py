"""Many frames' poses at once: `solve_pnp_batch`, a fast path of `solve_pnp` frame by frame.

`solve_pnp_batch` solves each of F frames alone, with the same steps and results as
`dream.pnp.solve_pnp`, but runs the frames' refinements together in numpy so that the fixed
cost of a step is paid once per batch. Its damped iteration (`_levenberg_marquardt_batch`) is a
documented fast path of the same iteration as `dream.optim.lm.levenberg_marquardt` (Marquardt's
scaling lambda diag(H), the same constants via `dream.pnp.settings`, the same stopping rules),
run on all frames in lockstep; the tests hold it equal to the single-frame solver frame by
frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.optim.robust import TINY
from dream.pnp.reprojection import apply_increment, linearise_rows, pixel_distances, weighted_rows
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
from dream.pnp.single import check_correspondences, degeneracy, initial_pose, leave_one_out_start

_EYE6 = np.eye(6)


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
    settings = settings or DEFAULT_SETTINGS
    P_base, uv, confidence, usable = _check_batch(P_base, uv, cameras, confidence)
    if len(P_base) == 0:
        return []
    P_finite, uv_finite = _finite(P_base, usable), _finite(uv, usable)
    all_cameras = _Cameras.of(cameras)
    out, starts = _starts(P_base, uv, P_finite, uv_finite, all_cameras, usable, settings)
    if starts:
        frames = np.array(list(starts))
        fits = _fit_batch(P_finite[frames], uv_finite[frames], all_cameras.take(frames),
                          np.array([starts[f][0] for f in frames]), confidence[frames],
                          usable[frames], np.array([starts[f][1] for f in frames]), settings)
        for f, fit in zip(frames.tolist(), fits, strict=True):
            out[f] = fit
    return out


def _check_batch(P_base: np.ndarray, uv: np.ndarray, cameras: Sequence[CameraIntrinsics],
                 confidence: np.ndarray | None) -> tuple[np.ndarray, ...]:
    """`check_correspondences` of F frames: P_base (F, N, 3), uv (F, N, 2) and confidence
    (F, N) as float arrays and (F, N) True where a keypoint is usable."""
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
    _, _, conf_flat, usable_flat = check_correspondences(
        P_base.reshape(-1, 3), uv.reshape(-1, 2),
        None if confidence is None else np.asarray(confidence, dtype=float).reshape(-1))
    return P_base, uv, conf_flat.reshape(F, N), usable_flat.reshape(F, N)


def _starts(P_base: np.ndarray, uv: np.ndarray, P_finite: np.ndarray, uv_finite: np.ndarray,
            cameras: _Cameras, usable: np.ndarray, settings: SolverSettings
            ) -> tuple[list[PoseFit | NoSolution | None], dict[int, tuple[np.ndarray, np.ndarray]]]:
    """Each frame's start as `solve_pnp` finds it: (F,) the `NoSolution` of a frame without
    one (else None), and the start (pose, keypoints to fit) of each other frame by index."""
    F, N = usable.shape
    out: list[PoseFit | NoSolution | None] = [None] * F
    degenerate = _degenerate(P_finite, usable, settings)
    firsts: dict[int, np.ndarray] = {}
    for f in range(F):
        idx = np.flatnonzero(usable[f])
        if degenerate[f]:
            out[f] = NoSolution(degeneracy(P_base[f, idx], settings) or "degenerate keypoints")
            continue
        first = initial_pose(P_base[f, idx], uv[f, idx], cameras.cameras[f])
        if not isinstance(first, NoSolution):
            firsts[f] = first
    # every keypoint agrees with the first pose (all are MSAC inliers): no subset does better
    first_distance = np.full((F, N), np.inf)          # inf behind the camera
    if firsts:
        frames = np.array(list(firsts))
        e, _, front = _linearise_batch(P_finite[frames], uv_finite[frames],
                                       cameras.take(frames), np.array(list(firsts.values())))
        first_distance[frames] = np.where(front, pixel_distances(e), np.inf)
    agree = np.all((first_distance ** 2 <= settings.ransac_threshold_px ** 2) | ~usable, axis=1)
    starts: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for f in range(F):
        if out[f] is not None:
            continue
        if agree[f]:
            starts[f] = (firsts[f], usable[f])
            continue
        first = firsts.get(f)
        start = leave_one_out_start(P_base[f], uv[f], cameras.cameras[f], usable[f], first,
                                    None if first is None else first_distance[f, usable[f]],
                                    settings)
        if isinstance(start, NoSolution):
            out[f] = start
        else:
            starts[f] = start
    return out, starts


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
        rows = [linearise_rows(P_base[f], uv[f], camera, T[f])
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
    distance = pixel_distances(e)
    cost = np.sum(weights * loss.rho(distance), axis=1)
    dof = np.maximum(2 * fitted.sum(axis=1) - 6, 1)
    F = len(T)
    lam = np.full(F, settings.initial_damping)
    iterations = np.zeros(F, int)
    H, g, damping = np.zeros((F, 6, 6)), np.zeros((F, 6)), np.zeros((F, 6))
    active, new_iteration = started.copy(), started.copy()
    while active.any():
        # an iteration starts: its limit, or a damping beyond which no step is tried, ends it
        ended = new_iteration & ((iterations >= settings.max_iterations) | (lam >= MAX_DAMPING))
        active &= ~ended
        start = new_iteration & active
        if start.any():
            iterations += start
            WJ = weighted_rows(J, weights * loss.weight(distance))
            H[start] = (WJ.transpose(0, 2, 1) @ J.reshape(F, -1, 6))[start]
            g[start] = (WJ.transpose(0, 2, 1) @ e.reshape(F, -1, 1))[start, :, 0]
            damping[start] = np.diagonal(H[start], axis1=1, axis2=2) + TINY
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
        distance_new = pixel_distances(e_new)
        cost_new = np.sum(weights * loss.rho(distance_new), axis=1)
        accept = active & np.all(front_new | ~fitted, axis=1) & (cost_new <= cost)
        T[accept], e[accept], J[accept] = T_new[accept], e_new[accept], J_new[accept]
        front[accept], distance[accept], cost[accept] = \
            front_new[accept], distance_new[accept], cost_new[accept]
        lam = np.where(accept, np.maximum(lam / DAMPING_FACTOR, MIN_DAMPING),
                       np.where(active, lam * DAMPING_FACTOR, lam))
        # a kept step below the tolerance ends; a refused one is retried with more damping
        # unless that passes the limit (then no step improves: converged)
        active &= ~(accept & (np.sum(xi * xi, axis=1) < settings.step_tolerance ** 2))
        active &= accept | (lam < MAX_DAMPING)
        new_iteration = accept
    return _LMState(T, iterations, e, J, front, started)


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
        dist[frames] = np.where(usable[frames], pixel_distances(lm.e), np.inf)
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


def _finite(a: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """a (F, N, D) with the rows of unusable keypoints set to 0 (finite for the batch maths)."""
    return np.where(usable[..., None], a, 0.0)


def _covariance(e: np.ndarray, J: np.ndarray,
                weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual-scaled covariances (..., 6, 6) of xi and condition numbers (...) of J^T W J,
    from the residuals (..., N, 2), Jacobians (..., N, 2, 6) and weights (..., N) at the poses
    (NaN covariance without redundancy, infinite condition number when singular)."""
    H = np.swapaxes(weighted_rows(J, weights), -1, -2) @ J.reshape(*J.shape[:-3], -1, 6)
    dof = 2 * np.count_nonzero(weights, axis=-1) - 6
    s2 = np.sum(weights * np.sum(e * e, axis=-1), axis=-1) / np.where(dof > 0, dof, np.nan)
    # H is symmetric positive semi-definite: its singular values are its eigenvalues
    eigenvalues, V = np.linalg.eigh(H)
    positive = np.where(eigenvalues[..., :1] > 0, eigenvalues, np.nan)
    covariance = s2[..., None, None] * (V / positive[..., None, :]) @ np.swapaxes(V, -1, -2)
    condition = positive[..., -1] / positive[..., 0]
    return covariance, np.where(np.isnan(condition), np.inf, condition)


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
