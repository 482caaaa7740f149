"""Rigid transforms named with their frames (pytransform3d style).

`T_a_b` is a 4x4 homogeneous matrix mapping points in frame b to frame a: `P_a = T_a_b @ P_b`.
Rotations are stored as 3x3 matrices; `rotvec` is a Rodrigues vector (axis * angle, rad);
quaternions are `[x, y, z, w]` (`quaternion_xyzw`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from dream.errors import InputError

WORLD_UP = np.array([0.0, 0.0, 1.0])  # robot base z axis points up
_RODRIGUES_SERIES_BELOW = 1e-4  # rad: below this angle Rodrigues uses its Taylor series (error
                                # ~theta^4 / 120 < 1e-18)
_LOOK_AT_MIN_DISTANCE_M = 1e-9  # look_at: a closer target gives no viewing direction
_LOOK_AT_MIN_SINE = 1e-9        # look_at: sine of the angle between the optical axis and up


def _check_shape(name: str, a: np.ndarray, shape_tail: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim < len(shape_tail) or a.shape[a.ndim - len(shape_tail):] != shape_tail:
        raise InputError(f"{name} has shape {a.shape}, expected (..., {shape_tail})")
    return a


def _as_float_array(a: Any, name: str, expected: str) -> np.ndarray:
    """`a` as a float array; an `InputError` naming `name` when it holds no numbers."""
    try:
        return np.asarray(a, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be {expected}, got {a!r:.80}") from None


def _check_point(name: str, p: np.ndarray) -> np.ndarray:
    p = _as_float_array(p, name, "a finite 3-vector")
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InputError(f"{name} must be a finite 3-vector, got {np.array2string(p)}")
    return p


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of vectors, shape (..., 3) -> (..., 3, 3)."""
    v = _check_shape("v", v, (3,))
    K = np.zeros(v.shape + (3,))
    K[..., 0, 1], K[..., 0, 2] = -v[..., 2], v[..., 1]
    K[..., 1, 0], K[..., 1, 2] = v[..., 2], -v[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -v[..., 1], v[..., 0]
    return K


def R_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues vectors (..., 3) -> rotation matrices (..., 3, 3)."""
    rotvec = _check_shape("rotvec", rotvec, (3,))
    if rotvec.ndim == 1:  # one rotation (the solvers' updates): scalar maths, no masks
        # I + a K + b K^2 with K^2 = v v^T - theta^2 I
        x, y, z = rotvec.tolist()
        theta2 = x * x + y * y + z * z
        a, b = _rodrigues_coefficients(theta2)
        c = 1.0 - b * theta2
        return np.array([[c + b * x * x, b * x * y - a * z, b * x * z + a * y],
                         [b * x * y + a * z, c + b * y * y, b * y * z - a * x],
                         [b * x * z - a * y, b * y * z + a * x, c + b * z * z]])
    K = skew(rotvec)
    theta2 = np.sum(rotvec * rotvec, axis=-1)[..., None, None]
    small = theta2 < _RODRIGUES_SERIES_BELOW ** 2
    safe2 = np.where(small, 1.0, theta2)
    theta = np.sqrt(safe2)
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(theta) / theta)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(theta)) / safe2)
    return np.eye(3) + a * K + b * (K @ K)


def _rodrigues_coefficients(theta2: float) -> tuple[float, float]:
    """sin(t) / t and (1 - cos(t)) / t^2 for t^2 = theta2 (Taylor series near 0)."""
    if theta2 < _RODRIGUES_SERIES_BELOW ** 2:
        return 1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0
    theta = math.sqrt(theta2)
    return math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta2


def rotvec_from_R(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> Rodrigues vectors (..., 3), angle in [0, pi]."""
    R = _check_shape("R", R, (3, 3))
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-1])


def quaternion_xyzw_from_R(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions [x, y, z, w] with w >= 0."""
    R = _check_shape("R", R, (3, 3))
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = np.where(q[:, 3:4] < 0, -q, q)
    return q.reshape(R.shape[:-2] + (4,))


def R_from_quaternion_xyzw(quaternion_xyzw: np.ndarray) -> np.ndarray:
    """Quaternions [x, y, z, w] (..., 4), normalised here -> rotation matrices (..., 3, 3)."""
    q = _check_shape("quaternion_xyzw", quaternion_xyzw, (4,))
    norm = np.linalg.norm(q, axis=-1)
    if not np.all(np.isfinite(q)) or np.any(norm < 1e-12):
        raise InputError("quaternion_xyzw must be finite and non-zero")
    return Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(q.shape[:-1] + (3, 3))


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Homogeneous transforms (..., 4, 4) from rotations (..., 3, 3) and translations (..., 3)."""
    R = _check_shape("R", R, (3, 3))
    t = _check_shape("t", t, (3,))
    T = np.zeros(np.broadcast_shapes(R.shape[:-2], t.shape[:-1]) + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def T_from_rotvec_t(rotvec: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Pose from a Rodrigues vector and a translation (OpenCV's rvec, tvec)."""
    return make_T(R_from_rotvec(rotvec), t)


def rotvec_t_from_T(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rotvec, t) of a pose (..., 4, 4)."""
    T = _check_shape("T", T, (4, 4))
    return rotvec_from_R(T[..., :3, :3]), T[..., :3, 3].copy()


def T_from_quaternion_xyzw_t(quaternion_xyzw: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Pose from a quaternion [x, y, z, w] and a translation."""
    return make_T(R_from_quaternion_xyzw(quaternion_xyzw), t)


def invert_T(T_a_b: np.ndarray) -> np.ndarray:
    """T_b_a from T_a_b, shape (..., 4, 4)."""
    T_a_b = _check_shape("T_a_b", T_a_b, (4, 4))
    R_t = np.swapaxes(T_a_b[..., :3, :3], -1, -2)
    return make_T(R_t, -np.einsum("...ij,...j->...i", R_t, T_a_b[..., :3, 3]))


def compose(T_a_b: np.ndarray, T_b_c: np.ndarray) -> np.ndarray:
    """T_a_c = T_a_b @ T_b_c (broadcasting over leading axes)."""
    return _check_shape("T_a_b", T_a_b, (4, 4)) @ _check_shape("T_b_c", T_b_c, (4, 4))


def transform_points(T_a_b: np.ndarray, P_b: np.ndarray) -> np.ndarray:
    """P_a = R P_b + t for points (..., 3); T_a_b (4, 4) or broadcastable (..., 4, 4)."""
    T_a_b = _check_shape("T_a_b", T_a_b, (4, 4))
    P_b = _check_shape("P_b", P_b, (3,))
    if T_a_b.ndim == 2:
        return P_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]
    return np.einsum("...ij,...j->...i", T_a_b[..., :3, :3], P_b) + T_a_b[..., :3, 3]


def camera_coordinates(points: np.ndarray, T: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """X, Y, Z, each (B, ...), of base-frame points (..., 3) in each of the cameras
    T (B, 4, 4): one coordinate array at a time, a third of the memory of a (B, ..., 3) array.

    >>> T = np.stack([np.eye(4), np.eye(4)]); T[1, :3, 3] = [0.0, 0.0, 1.0]
    >>> [c.tolist() for c in camera_coordinates(np.array([[1.0, 2.0, 3.0]]), T)]
    [[[1.0], [1.0]], [[2.0], [2.0]], [[3.0], [4.0]]]
    """
    points, T = np.asarray(points), np.asarray(T)
    if points.ndim < 1 or points.shape[-1] != 3 or T.ndim != 3 or T.shape[1:] != (4, 4):
        raise InputError(f"points {points.shape} and T {T.shape} must be (..., 3) and "
                         "(B, 4, 4)")
    extra = (None,) * (points.ndim - 1)
    R = T[(slice(None), slice(0, 3), slice(0, 3), *extra)]
    t = T[(slice(None), slice(0, 3), 3, *extra)]
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    X, Y, Z = (R[:, i, 0] * x + R[:, i, 1] * y + R[:, i, 2] * z + t[:, i] for i in range(3))
    return X, Y, Z


def is_rigid(T: np.ndarray, atol: float = 1e-6) -> bool:
    """True when T is a finite 4x4 homogeneous transform with an orthonormal, det +1 rotation."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return False
    R = T[:3, :3]
    return (np.allclose(R @ R.T, np.eye(3), atol=atol) and abs(np.linalg.det(R) - 1) < atol
            and np.allclose(T[3], [0, 0, 0, 1], atol=atol))


def check_pose(T: np.ndarray, name: str) -> np.ndarray:
    """T as a float (4, 4) array with finite entries; InputError naming `name` otherwise."""
    T = _as_float_array(T, name, "a finite 4x4 transform")
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"{name} must be a finite 4x4 transform, got shape {T.shape}"
                         + ("" if T.shape != (4, 4) else " with non-finite entries"))
    return T


def rotation_angle_between(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Geodesic angle (rad) between rotations (..., 3, 3)."""
    R_rel = np.swapaxes(R_a, -1, -2) @ R_b
    cos = (np.trace(R_rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def look_at(position_base: np.ndarray, target_base: np.ndarray, roll_rad: float = 0.0,
            up_base: np.ndarray = WORLD_UP) -> np.ndarray:
    """T_cam_base of a camera at `position_base` whose optical axis passes through
    `target_base`, image 'up' towards `up_base`, then rolled about the optical axis."""
    position_base = _check_point("position_base", position_base)
    up_base = _check_point("up_base", up_base)
    roll = _as_float_array(roll_rad, "roll_rad", "a finite angle (radians)")
    if roll.shape != () or not np.isfinite(roll):
        raise InputError(f"roll_rad must be a finite angle, got {roll_rad!r:.80}",
                         fix="give the roll about the optical axis in radians")
    z = _check_point("target_base", target_base) - position_base
    distance = np.linalg.norm(z)
    if not distance >= _LOOK_AT_MIN_DISTANCE_M:  # also NaN
        raise InputError(f"the camera position and its target are {distance} m apart",
                         fix="give a finite target away from the camera position")
    z /= distance
    x = np.cross(z, up_base)
    if not np.linalg.norm(x) >= _LOOK_AT_MIN_SINE:
        raise InputError("the camera looks straight along the up direction",
                         fix="move the camera or change up_base")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    T_base_cam = make_T(np.stack([x, y, z], axis=1), position_base)
    return invert_T(T_base_cam)


def camera_position_covariance(T_cam_base: np.ndarray, covariance_xi: np.ndarray) -> np.ndarray:
    """Covariance (3, 3) of the camera centre in the base frame, c = -R^T t, propagated from the
    covariance of xi = (delta_rot, delta_t) (camera frame, `dream.pnp`)."""
    R, t = T_cam_base[:3, :3], T_cam_base[:3, 3]
    J = np.concatenate([-R.T @ skew(t), -R.T], axis=1)  # d c / d xi
    return J @ covariance_xi @ J.T
