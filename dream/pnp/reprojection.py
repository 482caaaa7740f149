"""Reprojection residuals of a pose and their derivatives by the pose increment xi.

A pose update is `P_cam = exp(delta_rot) R P_base + t + delta_t`, so the 6-vector
`xi = (delta_rot, delta_t)` lives in the camera frame: rotation in rad about the camera axes,
translation in m along them (`apply_increment`, `increment_between`). Residuals are projected
minus observed pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from dream.camera import CameraIntrinsics, project, project_with_jacobian
from dream.transforms import R_from_rotvec, rotvec_from_R

COMPILED_BELOW_POINTS = 500   # fewer points: `projectPoints` beats numpy (measured, Zen 4)
_ZERO_ROTVEC = np.zeros(3)
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_IN_FRONT = np.array([0.0, 0.0, 1.0])  # stands in for a point behind the camera (whose rows
                                      # `linearise_rows` flags as meaningless)


def linearise(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
              T: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Residuals (N, 2) and d residual / d xi (N, 2, 6); None if a point is behind the camera.

    With the rotated points RP = R P_base, P_cam = exp(delta_rot) RP + t + delta_t, so
    d P_cam / d xi = [-[RP]x, I] at xi = 0, chained with d uv / d P_cam (plumb_bob
    distortion included; `_residuals`).
    """
    if len(P_base) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2, 6))
    RP = P_base @ T[:3, :3].T
    if not (RP[:, 2] + T[2, 3] > 0).all():
        return None
    return _residuals(RP, T, uv, camera)


def linearise_rows(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
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
    front of the camera) with T's translation (`linearise`): for a few points `_project`'s
    one compiled call; for many, numpy's chain rule (`projectPoints` also differentiates by the
    intrinsics and the distortion, most of its time there). Equal to rounding."""
    if len(P_rotated) < COMPILED_BELOW_POINTS:
        uv_hat, jac = _project(P_rotated, T[:3, 3], camera)
        return uv_hat - uv, jac[:, :6].reshape(len(P_rotated), 2, 6)
    uv_hat, J_uv_P = project_with_jacobian(camera, P_rotated + T[:3, 3])
    # a row a of d uv / d P_cam times -[RP]x is (RP x a): the rotation's three columns
    J_rot = np.cross(P_rotated[:, None, :], J_uv_P)
    return uv_hat - uv, np.concatenate([J_rot, J_uv_P], axis=2)


def _project(P_rotated: np.ndarray, t: np.ndarray,
             camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of the points P_rotated + t (camera frame) and OpenCV's Jacobian (2N, 15):
    columns 0-2 by a rotation vector applied to P_rotated (at 0), whose derivatives are
    those by xi's rotation, 3-5 by t."""
    uv_hat, jac = cv2.projectPoints(P_rotated, _ZERO_ROTVEC, t, camera.K,
                                    None if camera.distortion is None else camera.dist_coeffs)
    return uv_hat.reshape(-1, 2), jac


def reprojected(P_base: np.ndarray, camera: CameraIntrinsics, T: np.ndarray
                ) -> np.ndarray | None:
    """Pixels (N, 2) of base-frame points (N, 3) seen from `T_cam_base` T, without
    derivatives (`linearise` without its Jacobian); None if a point is behind the camera."""
    P_cam = P_base @ T[:3, :3].T + T[:3, 3]
    if not (P_cam[:, 2] > 0).all():
        return None
    return project(camera, P_cam)


def reprojection_distance(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                          T: np.ndarray) -> np.ndarray:
    """(N,) pixel distance between projected and observed keypoints (inf behind the camera)."""
    RP = P_base @ T[:3, :3].T
    front = RP[:, 2] + T[2, 3] > 0
    if front.all():
        return pixel_distances(_project(RP, T[:3, 3], camera)[0] - uv)
    distance = np.full(len(P_base), np.inf)
    if np.any(front):
        distance[front] = pixel_distances(_project(RP[front], T[:3, 3], camera)[0] - uv[front])
    return distance


def pixel_distances(e: np.ndarray) -> np.ndarray:
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


def weighted_rows(J: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(..., 2N, 6) rows of the Jacobians (..., N, 2, 6) scaled by their keypoint's weight
    (..., N): with them, J^T W J = `weighted_rows(J, w).T @ J.reshape(-1, 6)`."""
    return (J * weights[..., None, None]).reshape(*J.shape[:-3], -1, 6)
