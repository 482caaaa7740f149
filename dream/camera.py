"""Pinhole camera with optional plumb_bob (Brown-Conrady) distortion.

Pixels `uv`: u to the right, v down, the centre of the top-left pixel at (0, 0) (OpenCV).
Camera frame: x right, y down, z forward.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from dream.errors import InputError

PLUMB_BOB = "plumb_bob"
_UNDISTORT_ITERATIONS = 20  # fixed-point iterations of the inverse distortion map


@dataclass(frozen=True)
class CameraIntrinsics:
    """Intrinsics of one camera. Distortion `coeffs` are OpenCV's (k1, k2, p1, p2, k3)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, float, float, float, float] | None = field(default=None)

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not np.isfinite(value):
                raise InputError(f"camera intrinsic {name} = {value} is not finite",
                                 fix="give finite intrinsics in pixels")
        if self.fx <= 0 or self.fy <= 0:
            raise InputError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}",
                             fix="give fx and fy in pixels")
        if int(self.width) != self.width or int(self.height) != self.height or \
                self.width <= 0 or self.height <= 0:
            raise InputError(f"image size must be positive integers, got "
                             f"{self.width}x{self.height}", fix="give width and height in pixels")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        if self.distortion is not None:
            coeffs = tuple(float(c) for c in self.distortion)
            if len(coeffs) == 4:
                coeffs = coeffs + (0.0,)
            if len(coeffs) != 5 or not all(np.isfinite(coeffs)):
                raise InputError(f"plumb_bob distortion needs 5 finite coefficients "
                                 f"(k1, k2, p1, p2, k3), got {self.distortion}")
            object.__setattr__(self, "distortion", None if not any(coeffs) else coeffs)

    @classmethod
    def from_K(cls, K: np.ndarray, width: int, height: int,
               distortion: tuple[float, ...] | None = None) -> CameraIntrinsics:
        K = np.asarray(K, dtype=float)
        if K.shape != (3, 3):
            raise InputError(f"camera matrix K has shape {K.shape}, expected (3, 3)")
        if abs(K[0, 1]) > 1e-9 * max(1.0, abs(K[0, 0])):
            raise InputError("camera matrix K has a non-zero skew", fix="give a K with K[0,1]=0")
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                   width, height, distortion)

    @property
    def K(self) -> np.ndarray:
        """The 3 x 3 camera matrix (read-only, shared by equal cameras: the solvers project
        with it often; copy it to change it)."""
        return _camera_matrix(self.fx, self.fy, self.cx, self.cy)

    @property
    def dist_coeffs(self) -> np.ndarray:
        """OpenCV distortion vector (5,), zeros when there is none (read-only, shared)."""
        return _distortion_vector(self.distortion)

    def with_distortion(self, coeffs: tuple[float, ...] | None) -> CameraIntrinsics:
        return CameraIntrinsics(self.fx, self.fy, self.cx, self.cy, self.width, self.height,
                                None if coeffs is None else tuple(coeffs))

    def in_image(self, uv: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Mask (...,) of pixels that lie inside the image (pixel centres -0.5..W-0.5)."""
        uv = np.asarray(uv, dtype=float)
        return ((uv[..., 0] >= -0.5 - margin_px) & (uv[..., 0] <= self.width - 0.5 + margin_px)
                & (uv[..., 1] >= -0.5 - margin_px) & (uv[..., 1] <= self.height - 0.5 + margin_px))


@lru_cache(maxsize=64)
def _camera_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """`CameraIntrinsics.K`, made once per intrinsics (read-only)."""
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    K.setflags(write=False)
    return K


@lru_cache(maxsize=64)
def _distortion_vector(distortion: tuple[float, ...] | None) -> np.ndarray:
    """`CameraIntrinsics.dist_coeffs`, made once per distortion (read-only)."""
    coeffs = np.zeros(5) if distortion is None else np.array(distortion)
    coeffs.setflags(write=False)
    return coeffs


def distort_normalized(xy: np.ndarray, coeffs: np.ndarray | None) -> np.ndarray:
    """Apply plumb_bob distortion to normalised image coordinates (..., 2)."""
    xy = np.asarray(xy, dtype=float)
    if coeffs is None or not np.any(coeffs):
        return xy
    return np.stack(_distorted(xy[..., 0], xy[..., 1], coeffs), axis=-1)


def _distorted(x: np.ndarray, y: np.ndarray, coeffs) -> tuple[np.ndarray, np.ndarray]:
    """plumb_bob distortion of normalised coordinates x, y (...) given apart."""
    k1, k2, p1, p2, k3 = coeffs
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def undistort_normalized(xy_d: np.ndarray, coeffs: np.ndarray | None) -> np.ndarray:
    """Invert `distort_normalized` by fixed-point iteration (as OpenCV does)."""
    xy_d = np.asarray(xy_d, dtype=float)
    if coeffs is None or not np.any(coeffs):
        return xy_d
    k1, k2, p1, p2, k3 = coeffs
    xy = xy_d.copy()
    for _ in range(_UNDISTORT_ITERATIONS):
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        xy = np.stack([(xy_d[..., 0] - dx) / radial, (xy_d[..., 1] - dy) / radial], axis=-1)
    return xy


def project(camera: CameraIntrinsics, P_cam: np.ndarray) -> np.ndarray:
    """Project camera-frame points (..., 3) to pixels (..., 2), with the camera's distortion.

    Points at or behind the camera (z <= 0) project to NaN.
    """
    P_cam = np.asarray(P_cam, dtype=float)
    if P_cam.shape[-1:] != (3,):
        raise InputError(f"P_cam has shape {P_cam.shape}, expected (..., 3)")
    z = P_cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = P_cam[..., 0] / z, P_cam[..., 1] / z
    front = z > 0
    if not front.all():
        x, y = np.where(front, x, np.nan), np.where(front, y, np.nan)
    if camera.distortion is not None:
        x, y = _distorted(x, y, camera.distortion)
    uv = np.empty(z.shape + (2,))
    uv[..., 0] = camera.fx * x + camera.cx
    uv[..., 1] = camera.fy * y + camera.cy
    return uv


def pixels_to_normalized(camera: CameraIntrinsics, uv: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) -> undistorted normalised coordinates (x/z, y/z)."""
    uv = np.asarray(uv, dtype=float)
    xy_d = (uv - np.array([camera.cx, camera.cy])) / np.array([camera.fx, camera.fy])
    return undistort_normalized(xy_d, None if camera.distortion is None else camera.dist_coeffs)


def project_with_jacobian(camera: CameraIntrinsics,
                          P_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of camera-frame points (N, 3) and d uv / d P_cam (N, 2, 3).

    Includes the plumb_bob distortion. Points must lie in front of the camera.
    """
    P_cam = np.asarray(P_cam, dtype=float)
    if P_cam.ndim != 2 or P_cam.shape[1] != 3:
        raise InputError(f"P_cam has shape {P_cam.shape}, expected (N, 3)")
    X, Y, Z = P_cam[:, 0], P_cam[:, 1], P_cam[:, 2]
    inv_z = 1.0 / Z
    x, y = X * inv_z, Y * inv_z
    # J_uv_P = diag(fx, fy) @ J_d @ d(x, y)/d(X, Y, Z), d(x, y)/d(X, Y, Z) = [[1, 0, -x],
    # [0, 1, -y]] / Z, with J_d = d(distorted) / d(x, y) (the identity without distortion)
    J_uv_P = np.empty((len(P_cam), 2, 3))
    if camera.distortion is None:
        xd, yd = x, y
        J_uv_P[:, 0, 0] = camera.fx * inv_z
        J_uv_P[:, 0, 1] = 0.0
        J_uv_P[:, 0, 2] = -camera.fx * x * inv_z
        J_uv_P[:, 1, 0] = 0.0
        J_uv_P[:, 1, 1] = camera.fy * inv_z
        J_uv_P[:, 1, 2] = -camera.fy * y * inv_z
    else:
        k1, k2, p1, p2, k3 = camera.distortion
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        d_radial = k1 + 2 * k2 * r2 + 3 * k3 * r2 ** 2  # d radial / d r2
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        d_xx = radial + 2 * x * x * d_radial + 2 * p1 * y + 6 * p2 * x
        d_xy = 2 * x * y * d_radial + 2 * p1 * x + 2 * p2 * y   # = d_yx
        d_yy = radial + 2 * y * y * d_radial + 6 * p1 * y + 2 * p2 * x
        for row, f, (a, b) in ((0, camera.fx, (d_xx, d_xy)), (1, camera.fy, (d_xy, d_yy))):
            J_uv_P[:, row, 0] = f * a * inv_z
            J_uv_P[:, row, 1] = f * b * inv_z
            J_uv_P[:, row, 2] = -f * (a * x + b * y) * inv_z
    uv = np.empty((len(P_cam), 2))
    uv[:, 0] = camera.fx * xd + camera.cx
    uv[:, 1] = camera.fy * yd + camera.cy
    return uv, J_uv_P
