"""A joint Gauss-Newton fit of the pose and a few camera parameters to keypoints (pure): the
fit the keypoint path's intrinsics checks share (`dream.focal_check`: a focal-length scale,
`dream.principal_check`: a principal-point shift).

The parameters p enter through `camera_at(camera, p)`, and their Jacobian columns are exact
(`columns`: d uv / d p at the projected points), beside the pose's from `dream.pnp`. The fit's
covariance of p is the Gauss-Newton one scaled by the residual's variance; `jackknife` leaves
out one keypoint name at a time (a detector's bias on one keypoint moves p more than its
pixel noise says).

    >>> from dream.camera import project
    >>> from dream.coarse.principal import with_principal_shift
    >>> from dream.transforms import look_at, transform_points
    >>> camera = CameraIntrinsics(500.0, 500.0, 319.5, 239.5, 640, 480)
    >>> T = look_at(np.array([1.5, 0.2, 0.8]), np.array([0.0, 0.0, 0.4]))
    >>> P = np.random.default_rng(0).uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (60, 3))
    >>> uv = project(with_principal_shift(camera, [6.0, -4.0]), transform_points(T, P))
    >>> shift_fit = KeypointCameraFit(with_principal_shift, 2, principal_columns, 320.0)
    >>> p, covariance, _ = shift_fit.fit(P, uv, camera, T)
    >>> np.round(p, 3).tolist()
    [6.0, -4.0]
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.pnp.reprojection import apply_increment, linearise
from dream.refined_uncertainty import jackknife_spread

POSE = 6                      # unknowns of the pose increment

Fitted = tuple[np.ndarray, np.ndarray, np.ndarray]


class Estimate(NamedTuple):
    """A joint fit's parameters p (k,), the fit's 1-sigma of each (k,), the delete-one-name
    jackknife's (k,; None with too few names), and the pose fitted with them (4, 4)."""

    p: np.ndarray
    sigma_fit: np.ndarray
    sigma_jackknife: np.ndarray | None
    T_cam_base: np.ndarray


@dataclass(frozen=True)
class KeypointCameraFit:
    """A joint fit of (pose, p) to keypoints.

    Attributes:
        camera_at: the camera with parameters p (k,) applied to the given one.
        size: k, the number of camera parameters.
        columns: (projected uv (N, 2), the camera at p) -> d uv / d p (N, 2, k).
        max_step: a Gauss-Newton step of any parameter beyond this: no answer (it runs away).
        iterations: Gauss-Newton steps.
    """

    camera_at: Callable[[CameraIntrinsics, np.ndarray], CameraIntrinsics]
    size: int
    columns: Callable[[np.ndarray, CameraIntrinsics], np.ndarray]
    max_step: float
    iterations: int = 20

    def __post_init__(self) -> None:
        if not (self.size >= 1 and self.max_step > 0 and self.iterations >= 1):
            raise InputError(f"invalid KeypointCameraFit (size {self.size}, max_step "
                             f"{self.max_step}, iterations {self.iterations})")

    def fit(self, P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
            T_cam_base: np.ndarray) -> Fitted | None:
        """(p (k,), its covariance (k, k), the pose) that fit `uv` (N, 2) best from p = 0 and
        `T_cam_base`; None where a point falls behind the camera, the points fix fewer
        directions than there are unknowns (the same few detections in every frame), a step
        runs away, or the fit leaves no residual to measure p's 1-sigma by."""
        P_base, uv = np.asarray(P_base, float), np.asarray(uv, float)
        if P_base.shape != (len(uv), 3) or uv.shape[-1:] != (2,):
            raise InputError(f"P_base {P_base.shape} and uv {uv.shape} must be (N, 3) and "
                             "(N, 2)")
        T, p = np.asarray(T_cam_base, float), np.zeros(self.size)
        covariance = np.full((self.size, self.size), np.inf)
        for _ in range(self.iterations):
            at = self.camera_at(camera, p)
            lin = linearise(P_base, uv, at, T)
            if lin is None:
                return None
            e, J = lin
            A = np.concatenate([J.reshape(-1, POSE),
                                self.columns(e + uv, at).reshape(-1, self.size)], axis=1)
            if np.linalg.matrix_rank(A) < POSE + self.size:
                return None           # too few distinct points for the unknowns
            H = A.T @ A
            try:
                step = np.linalg.solve(H, -A.T @ e.reshape(-1))
            except np.linalg.LinAlgError:
                return None
            if not (np.all(np.isfinite(step)) and np.max(np.abs(step[POSE:])) < self.max_step):
                return None
            T, p = apply_increment(T, step[:POSE]), p + step[POSE:]
            dof = max(A.shape[0] - POSE - self.size, 1)
            variance = float(e.reshape(-1) @ e.reshape(-1)) / dof
            covariance = variance * np.linalg.pinv(H)[POSE:, POSE:]
        if not (np.all(np.isfinite(covariance)) and np.all(np.diag(covariance) > 0)):
            return None               # the points fix nothing beyond the pose: no 1-sigma
        return p, covariance, T

    def estimate(self, P_base: np.ndarray, uv: np.ndarray, names: np.ndarray,
                 camera: CameraIntrinsics, T_cam_base: np.ndarray, min_groups: int
                 ) -> Estimate | None:
        """The fit's `Estimate` (its jackknife None with fewer than `min_groups` names); None
        where the fit or one of its leave-one-name-out fits has no answer (the fit's own
        1-sigma alone would flag a detector's bias on one keypoint)."""
        fitted = self.fit(P_base, uv, camera, T_cam_base)
        if fitted is None:
            return None
        p, covariance, T = fitted
        sigma_fit = np.sqrt(np.diag(covariance))
        if len(np.unique(names)) < min_groups:
            return Estimate(p, sigma_fit, None, T)
        spread = self.jackknife(P_base, uv, names, camera, T_cam_base, min_groups)
        if spread is None:
            return None
        return Estimate(p, sigma_fit, np.sqrt(np.clip(np.diag(spread), 0.0, None)), T)

    def jackknife(self, P_base: np.ndarray, uv: np.ndarray, names: np.ndarray,
                  camera: CameraIntrinsics, T_cam_base: np.ndarray,
                  min_groups: int) -> np.ndarray | None:
        """(k, k) the delete-one-name jackknife covariance of p (`names` (N,): each keypoint's
        name); None with fewer than `min_groups` names or where a fit without one fails."""
        groups = np.unique(names)
        if len(groups) < min_groups:
            return None
        values = []
        for g in groups:
            fitted = self.fit(P_base[names != g], uv[names != g], camera, T_cam_base)
            if fitted is None:
                return None
            values.append(fitted[0])
        return jackknife_spread(np.array(values))


def inlier_keypoints(result, obs, min_keypoints: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(P_base (N, 3), uv (N, 2), each one's keypoint index (N,)) of an all-frames
    `CalibrationResult`'s inlier detections in `Observations`; None in another mode or with
    fewer than `min_keypoints`."""
    if result.mode != "all":
        return None
    inlier = result.inlier & obs.found
    if inlier.sum() < min_keypoints:
        return None
    names = np.broadcast_to(np.arange(obs.uv.shape[1]), inlier.shape)[inlier]
    return obs.P_base[inlier], obs.uv[inlier], names


def principal_columns(uv: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
    """d uv / d (du, dv) of a principal point moved by (du, dv) pixels: the identity."""
    return np.broadcast_to(np.eye(2), (*uv.shape[:-1], 2, 2))


def focal_columns(uv: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
    """d uv / d log s of fx, fy times s: uv - (cx, cy)."""
    return (uv - np.array([camera.cx, camera.cy]))[..., None]
