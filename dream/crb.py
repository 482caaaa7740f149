"""Cramer-Rao bound on the extrinsic from keypoint observations with Gaussian pixel noise."""

from __future__ import annotations

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import CalibrationError, InputError
from dream.pnp import linearise
from dream.transforms import check_pose

# above this condition number of the Fisher information the bound is refused (numerically
# singular: inverting it would lose every significant digit of the smallest direction)
MAX_FISHER_CONDITION = 1e14


def extrinsic_crb(P_base: np.ndarray, camera: CameraIntrinsics, T_cam_base: np.ndarray,
                  pixel_sigma_px: float) -> np.ndarray:
    """Lower bound (6, 6) on the covariance of any unbiased estimate of `T_cam_base`.

    Args:
        P_base: (N, 3) base-frame positions of every observed keypoint of every frame
            (forward kinematics of each frame's joints), m.
        camera: intrinsics (distortion included).
        T_cam_base: the true extrinsic.
        pixel_sigma_px: standard deviation of the i.i.d. Gaussian noise on each pixel coordinate.

    Returns:
        The inverse Fisher information of xi = (delta_rot rad, delta_t m), both about the camera
        axes, the parametrisation of `dream.pnp` (so it compares with `PoseFit.covariance`).
    """
    P_base = np.asarray(P_base, dtype=float)
    if P_base.ndim != 2 or P_base.shape[1] != 3 or not np.all(np.isfinite(P_base)):
        raise InputError(f"P_base must be finite with shape (N, 3), got {P_base.shape}")
    if not (np.isfinite(pixel_sigma_px) and pixel_sigma_px > 0):
        raise InputError(f"pixel_sigma_px must be positive, got {pixel_sigma_px}")
    T_cam_base = check_pose(T_cam_base, "T_cam_base")
    lin = linearise(P_base, np.zeros((len(P_base), 2)), camera, T_cam_base)
    if lin is None:
        raise CalibrationError("a keypoint lies behind the camera: no bound")
    J = lin[1].reshape(-1, 6)
    fisher = J.T @ J / pixel_sigma_px ** 2
    if np.linalg.cond(fisher) > MAX_FISHER_CONDITION:
        raise CalibrationError("the extrinsic is not identifiable from these keypoints")
    return np.linalg.inv(fisher)
