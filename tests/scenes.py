"""Random keypoint scenes for solver tests (no robot model needed)."""

from __future__ import annotations

import numpy as np

from dream.calibration import Observations
from dream.camera import CameraIntrinsics, project
from dream.transforms import look_at, transform_points

CAMERA = CameraIntrinsics(600.0, 600.0, 319.5, 239.5, 640, 480)


def random_extrinsic(rng: np.random.Generator, distance=(1.0, 2.0)) -> np.ndarray:
    """Camera 1-2 m from a point near the base, looking at it."""
    az, el, r = rng.uniform(0, 2 * np.pi), rng.uniform(0.1, 0.9), rng.uniform(*distance)
    target = np.array([0.0, 0.0, 0.4]) + rng.uniform(-0.1, 0.1, 3)
    pos = target + r * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return look_at(pos, target, rng.uniform(-0.2, 0.2))


def random_scene(rng: np.random.Generator, frames: int, keypoints: int = 7,
                 noise_px: float = 0.0, camera: CameraIntrinsics = CAMERA,
                 outlier_fraction: float = 0.0):
    """Observations of `frames` random arm-sized point sets; returns (obs, T_cam_base, uv_true)."""
    T = random_extrinsic(rng)
    P_base = rng.uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (frames, keypoints, 3))
    uv_true = project(camera, transform_points(T, P_base))
    uv = uv_true + rng.normal(0, noise_px, uv_true.shape)
    out = rng.random(uv.shape[:2]) < outlier_fraction
    uv = np.where(out[..., None], rng.uniform([0, 0], [camera.width, camera.height], uv.shape), uv)
    obs = Observations(P_base, uv, np.ones((frames, keypoints)),
                       tuple(f"{i:06d}" for i in range(frames)),
                       tuple(f"k{j}" for j in range(keypoints)))
    return obs, T, uv_true
