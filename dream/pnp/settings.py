"""The pose solver's settings and results: `SolverSettings`, `PoseFit` and `NoSolution`.

A `PoseFit`'s covariance is that of the 6-vector xi = (delta_rot rad, delta_t m) in the camera
frame (`dream.pnp.reprojection`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dream.errors import InputError
from dream.optim import RobustLoss

MIN_KEYPOINTS = 4
RAYLEIGH_MEDIAN = float(np.sqrt(2.0 * np.log(2.0)))  # median of |e| / sigma for 2D Gaussian e
DAMPING_FACTOR = 10.0    # LM lambda is multiplied / divided by this on a rejected / kept step
MIN_DAMPING = 1e-12
MAX_DAMPING = 1e12       # a step is given up when lambda exceeds this (converged)


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


DEFAULT_SETTINGS = SolverSettings()


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
