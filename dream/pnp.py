"""Perspective-n-point: initial pose by SQPnP, then robust Levenberg-Marquardt on SE(3).

All functions take base-frame points `P_base` (N, 3) and observed pixels `uv` (N, 2) and return
`T_cam_base`. A pose update is `P_cam = exp(delta_rot) R P_base + t + delta_t`, so the
6-vector `xi = (delta_rot, delta_t)` lives in the camera frame: rotation in rad about the camera
axes, translation in m along them. Covariances and sigmas use this order and these frames.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np

from dream.camera import CameraIntrinsics, pixels_to_normalized
from dream.errors import InputError
from dream.transforms import R_from_rotvec, T_from_rotvec_t

log = logging.getLogger(__name__)

MIN_KEYPOINTS = 4
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))  # median of |e| / sigma for 2D Gaussian e
_DAMPING_FACTOR = 10.0   # LM lambda is multiplied / divided by this on a rejected / kept step
_MIN_DAMPING = 1e-12
_MAX_DAMPING = 1e12      # a step is given up when lambda exceeds this (converged)
_TINY = 1e-300           # keeps the damping positive for a zero diagonal entry
_ZERO_ROTVEC = np.zeros(3)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


@dataclass(frozen=True)
class RobustLoss:
    """Robust loss on the pixel distance |e| of each keypoint.

    kind: "huber" (quadratic up to `scale_px`, then linear), "cauchy" or "l2".
    """

    kind: str = "huber"
    scale_px: float = 3.0

    def __post_init__(self) -> None:
        if self.kind not in ("huber", "cauchy", "l2"):
            raise InputError(f"unknown robust loss '{self.kind}'", fix="use huber, cauchy or l2")
        if not (np.isfinite(self.scale_px) and self.scale_px > 0):
            raise InputError(f"robust loss scale must be a positive number of pixels, got "
                             f"{self.scale_px}")

    def rho(self, r: np.ndarray) -> np.ndarray:
        """Cost of distances r >= 0 (equals r^2 / 2 near zero)."""
        k = self.scale_px
        if self.kind == "l2":
            return 0.5 * r * r
        if self.kind == "huber":
            return np.where(r <= k, 0.5 * r * r, k * (r - 0.5 * k))
        return 0.5 * k * k * np.log1p((r / k) ** 2)

    def weight(self, r: np.ndarray) -> np.ndarray:
        """IRLS weight rho'(r) / r."""
        k = self.scale_px
        if self.kind == "l2":
            return np.ones_like(r)
        if self.kind == "huber":
            return np.where(r <= k, 1.0, k / np.maximum(r, 1e-300))
        return 1.0 / (1.0 + (r / k) ** 2)


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
    usable = np.all(np.isfinite(P_base), 1) & np.all(np.isfinite(uv), 1) & \
        np.isfinite(confidence) & (confidence > 0)
    return P_base, uv, confidence, usable


def degeneracy(P_base: np.ndarray, settings: SolverSettings) -> str | None:
    """Why these 3D points cannot fix a pose, or None when they can."""
    if len(P_base) < settings.min_keypoints:
        return (f"only {len(P_base)} usable keypoints, at least {settings.min_keypoints} "
                f"are needed")
    s = np.linalg.svd(P_base - P_base.mean(0), compute_uv=False)
    if s[0] <= 0 or s[1] / s[0] < settings.collinear_ratio:
        return "the keypoints are (nearly) collinear or coincident"
    return None


def initial_pose(P_base: np.ndarray, uv: np.ndarray,
                 camera: CameraIntrinsics) -> np.ndarray | NoSolution:
    """T_cam_base from SQPnP on undistorted normalised points (no refinement)."""
    xy = pixels_to_normalized(camera, uv)
    try:
        ok, rvec, tvec = cv2.solvePnP(P_base.reshape(-1, 1, 3), xy.reshape(-1, 1, 2), np.eye(3),
                                      None, flags=cv2.SOLVEPNP_SQPNP)
    except cv2.error as exc:
        return NoSolution(f"SQPnP failed ({str(exc).splitlines()[0]})")
    if not ok or not np.all(np.isfinite(rvec)) or not np.all(np.isfinite(tvec)):
        return NoSolution("SQPnP found no pose")
    return T_from_rotvec_t(rvec.ravel(), tvec.ravel())


def linearise(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
              T: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Residuals (N, 2) and d residual / d xi (N, 2, 6); None if a point is behind the camera.

    One compiled call (the solvers' inner loop): OpenCV's `projectPoints` of the rotated points
    R P_base with rotation vector 0 and translation t, whose derivatives by that rotation vector
    and by t are exactly those by xi = (delta_rot, delta_t).
    """
    n = len(P_base)
    RP = P_base @ T[:3, :3].T
    if n == 0 or (RP[:, 2] + T[2, 3]).min() <= 0:
        return None if n else (np.zeros((0, 2)), np.zeros((0, 2, 6)))
    uv_hat, jac = _project(RP, T[:3, 3], camera)
    return uv_hat - uv, jac[:, :6].reshape(n, 2, 6)


def _project(P_rotated: np.ndarray, t: np.ndarray,
             camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of the points P_rotated + t (camera frame) and OpenCV's Jacobian (2N, 15):
    columns 0-2 by a rotation vector applied to P_rotated (at 0), 3-5 by t."""
    uv_hat, jac = cv2.projectPoints(P_rotated, _ZERO_ROTVEC, t, camera.K,
                                    None if camera.distortion is None else camera.dist_coeffs)
    return uv_hat.reshape(-1, 2), jac


def _distances(e: np.ndarray) -> np.ndarray:
    """(N,) pixel distances |e| of residuals (N, 2)."""
    return np.hypot(e[:, 0], e[:, 1])


def _cost(distance: np.ndarray, confidence: np.ndarray, loss: RobustLoss) -> float:
    return float(confidence @ loss.rho(distance))


class _BehindCamera(Exception):
    """Internal: the starting pose puts keypoints behind the camera."""


def apply_increment(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """The update matching the Jacobians: P_cam = exp(xi_rot) R P_base + t + xi_t."""
    T_new = np.empty((4, 4))
    T_new[:3, :3] = R_from_rotvec(xi[:3]) @ T[:3, :3]
    T_new[:3, 3] = T[:3, 3] + xi[3:]
    T_new[3] = _LAST_ROW
    return T_new


def levenberg_marquardt(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                        T_init: np.ndarray, confidence: np.ndarray,
                        settings: SolverSettings
                        ) -> tuple[np.ndarray, int, tuple[np.ndarray, np.ndarray]]:
    """Minimise sum_i c_i rho(|project(T P_i) - uv_i|) over T (IRLS inside LM).

    Returns the optimum, the number of iterations and `linearise` at the optimum. Inputs must
    be finite.
    """
    loss = settings.loss
    T = T_init.copy()
    lin = linearise(P_base, uv, camera, T)
    if lin is None:
        raise _BehindCamera()
    e, J = lin
    distance = _distances(e)
    cost = _cost(distance, confidence, loss)
    lam = settings.initial_damping
    dof = max(2 * int(np.count_nonzero(confidence)) - 6, 1)
    iterations = 0
    while iterations < settings.max_iterations:
        iterations += 1
        w = confidence * loss.weight(distance)
        WJ = _weighted_rows(J, w)
        H = WJ.T @ J.reshape(-1, 6)
        g = WJ.T @ e.reshape(-1)
        damping = H.diagonal() + _TINY
        improved = False
        while lam < _MAX_DAMPING:
            xi = np.linalg.solve(H + np.diag(lam * damping), -g)
            # the decrease the reweighted quadratic model predicts is, in squared standard
            # deviations of the pose (covariance s^2 H^-1, s^2 = 2 cost / dof), the remaining
            # distance to the optimum: d^2 = 2 predicted / s^2 = predicted dof / cost
            predicted = -(g @ xi) - 0.5 * (xi @ H @ xi)
            if predicted * dof <= settings.convergence_sigma ** 2 * cost:
                return T, iterations, (e, J)
            T_new = apply_increment(T, xi)
            lin_new = linearise(P_base, uv, camera, T_new)
            if lin_new is not None:
                distance_new = _distances(lin_new[0])
                new_cost = _cost(distance_new, confidence, loss)
                if new_cost <= cost:
                    T, (e, J), distance, cost = T_new, lin_new, distance_new, new_cost
                    lam = max(lam / _DAMPING_FACTOR, _MIN_DAMPING)
                    improved = True
                    break
            lam *= _DAMPING_FACTOR
        if not improved or xi @ xi < settings.step_tolerance ** 2:
            break
    return T, iterations, (e, J)


def _weighted_rows(J: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(2N, 6) rows of the Jacobians (N, 2, 6) scaled by their keypoint's weight (N,): with
    them, J^T W J = `_weighted_rows(J, w).T @ J.reshape(-1, 6)`."""
    return (J * weights[:, None, None]).reshape(-1, 6)


def _covariance(e: np.ndarray, J: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, float]:
    """Residual-scaled covariance (6, 6) of xi and the condition number of J^T W J, from the
    residuals (N, 2), Jacobians (N, 2, 6) and weights (N,) at the pose."""
    H = _weighted_rows(J, weights).T @ J.reshape(-1, 6)
    dof = 2 * int(np.count_nonzero(weights)) - 6
    s2 = float(weights @ np.sum(e * e, 1) / dof) if dof > 0 else np.nan
    # H is symmetric positive semi-definite: its singular values are its eigenvalues
    eigenvalues, V = np.linalg.eigh(H)
    if not eigenvalues[0] > 0:
        return np.full((6, 6), np.nan), np.inf
    return s2 * (V / eigenvalues) @ V.T, float(eigenvalues[-1] / eigenvalues[0])


def fit_pose(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics, T_init: np.ndarray,
             *, confidence: np.ndarray | None = None, inlier: np.ndarray | None = None,
             settings: SolverSettings | None = None) -> PoseFit | NoSolution:
    """Robust refinement from T_init with rounds of outlier rejection.

    `inlier` (N,) optionally restricts the first round to a subset (e.g. RANSAC inliers).
    Non-finite rows of P_base / uv and zero confidences are ignored.
    """
    settings = settings or _DEFAULT_SETTINGS
    P_base, uv, confidence, usable = check_correspondences(P_base, uv, confidence)
    keep = usable if inlier is None else usable & np.asarray(inlier, bool)
    reason = degeneracy(P_base[keep], settings)
    if reason is not None:
        return NoSolution(reason)
    return _fit_checked(P_base, uv, camera, np.asarray(T_init, dtype=float), confidence, usable,
                        keep, settings)


def _fit_checked(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics, T: np.ndarray,
                 confidence: np.ndarray, usable: np.ndarray, keep: np.ndarray,
                 settings: SolverSettings) -> PoseFit | NoSolution:
    """`fit_pose` on checked correspondences (`check_correspondences`), starting from the
    keypoints `keep` (a subset of `usable`, not degenerate: `degeneracy`)."""
    P_usable, uv_usable = P_base[usable], uv[usable]
    iterations = 0
    for _ in range(settings.outlier_rounds + 1):
        try:
            T, iterations, lin = levenberg_marquardt(P_base[keep], uv[keep], camera, T,
                                                     confidence[keep], settings)
        except _BehindCamera:
            return NoSolution("the initial pose puts keypoints behind the camera")
        if not np.array_equal(keep, usable):  # else `lin` is already that of every usable one
            lin = linearise(P_usable, uv_usable, camera, T)
            if lin is None:
                return NoSolution("the solution puts keypoints behind the camera")
        dist = np.full(len(P_base), np.inf)
        dist[usable] = _distances(lin[0])
        sigma = _median(dist[keep]) / RAYLEIGH_MEDIAN
        threshold = max(settings.min_inlier_threshold_px, settings.inlier_sigma_factor * sigma)
        new_keep = usable & (dist <= threshold)
        # a round that would leave too few or degenerate keypoints ends the rejection: the fit
        # of the last usable set stands (so `keep` is never degenerate)
        if np.array_equal(new_keep, keep) or degeneracy(P_base[new_keep], settings) is not None:
            break
        keep = new_keep
    weights = np.zeros(len(P_base))
    weights[keep] = confidence[keep] * settings.loss.weight(dist[keep])
    # `lin` holds the residuals and Jacobians of the usable keypoints at the final T
    residuals = np.full((len(P_base), 2), np.nan)
    residuals[usable] = lin[0]
    kept = keep[usable]                     # keep is a subset of usable
    covariance, cond = _covariance(lin[0][kept], lin[1][kept], weights[keep])
    if cond > settings.max_condition:
        return NoSolution(f"the pose is not determined by these keypoints (condition number "
                          f"{cond:.1e})")
    rmse = float(np.sqrt(np.mean(np.square(dist[keep]))))
    return PoseFit(T, residuals, keep, weights, covariance, rmse, iterations)


def _median(x: np.ndarray) -> float:
    """np.median of a short 1D array without its overhead."""
    x = np.sort(x)
    n = len(x)
    return float(0.5 * (x[(n - 1) // 2] + x[n // 2]))


def solve_pnp(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics, *,
              confidence: np.ndarray | None = None,
              settings: SolverSettings | None = None) -> PoseFit | NoSolution:
    """Pose of one frame: SQPnP on all usable keypoints; when that leaves a keypoint outside the
    MSAC threshold, also on leave-one-out subsets (to survive a wrong detection); the hypothesis
    with the lowest truncated cost refined robustly."""
    settings = settings or _DEFAULT_SETTINGS
    P_base, uv, confidence, usable = check_correspondences(P_base, uv, confidence)
    reason = degeneracy(P_base[usable], settings)
    if reason is not None:
        return NoSolution(reason)
    idx = np.flatnonzero(usable)
    first = initial_pose(P_base[idx], uv[idx], camera)
    # leave-one-out order: the keypoint worst explained by the first pose is left out first
    order = np.arange(len(idx))
    if not isinstance(first, NoSolution):
        distance = _reprojection_distance(P_base[idx], uv[idx], camera, first)
        if np.all(distance ** 2 <= settings.ransac_threshold_px ** 2):
            # every keypoint agrees (all are MSAC inliers): no subset can do better
            return _fit_checked(P_base, uv, camera, first, confidence, usable, usable, settings)
        order = np.argsort(-distance)
    hypotheses = [] if isinstance(first, NoSolution) else [first]
    if len(idx) > settings.min_keypoints:
        for i in order:
            subset = np.delete(idx, i)
            if degeneracy(P_base[subset], settings) is not None:
                continue
            T = initial_pose(P_base[subset], uv[subset], camera)
            if isinstance(T, NoSolution):
                continue
            hypotheses.append(T)
            _, inlier = msac_score(P_base[subset], uv[subset], camera, T,
                                   settings.ransac_threshold_px)
            if inlier.all():  # all but the left-out keypoint agree: no other subset does better
                break
    return refine_best(P_base, uv, camera, hypotheses, confidence, usable, settings)


def _reprojection_distance(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                           T: np.ndarray) -> np.ndarray:
    """(N,) pixel distance between projected and observed keypoints (inf behind the camera)."""
    RP = P_base @ T[:3, :3].T
    front = RP[:, 2] + T[2, 3] > 0
    distance = np.full(len(P_base), np.inf)
    if np.any(front):
        distance[front] = _distances(_project(RP[front], T[:3, 3], camera)[0] - uv[front])
    return distance


def msac_score(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics, T: np.ndarray,
               threshold_px: float) -> tuple[float, np.ndarray]:
    """Truncated squared error (lower is better) and the inlier mask of a hypothesis."""
    d2 = _reprojection_distance(P_base, uv, camera, T) ** 2
    inlier = d2 <= threshold_px ** 2
    return float(np.sum(np.minimum(d2, threshold_px ** 2))), inlier


def refine_best(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                hypotheses: list[np.ndarray], confidence: np.ndarray, usable: np.ndarray,
                settings: SolverSettings) -> PoseFit | NoSolution:
    """Rank hypotheses by MSAC score over the usable keypoints and refine the best one."""
    if not hypotheses:
        return NoSolution("no initial pose could be found")
    scored = [(msac_score(P_base[usable], uv[usable], camera, T, settings.ransac_threshold_px), i)
              for i, T in enumerate(hypotheses)]
    (_, inlier_usable), best = min(scored, key=lambda s: s[0][0])
    inlier = np.zeros(len(P_base), bool)
    inlier[np.flatnonzero(usable)[inlier_usable]] = True
    if inlier.sum() < settings.min_keypoints:
        inlier = usable
    return fit_pose(P_base, uv, camera, hypotheses[best], confidence=confidence, inlier=inlier,
                    settings=settings)
