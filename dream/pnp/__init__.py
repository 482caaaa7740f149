"""Perspective-n-point: initial pose by SQPnP, then robust Levenberg-Marquardt on SE(3).

All functions take base-frame points `P_base` (N, 3) and observed pixels `uv` (N, 2) and return
`T_cam_base`. A pose update is `P_cam = exp(delta_rot) R P_base + t + delta_t`, so the
6-vector `xi = (delta_rot, delta_t)` lives in the camera frame: rotation in rad about the camera
axes, translation in m along them. Covariances and sigmas use this order and these frames.

Modules: `settings` (SolverSettings, PoseFit, NoSolution), `reprojection` (residuals, their
Jacobians by xi, the increment), `single` (one frame: `solve_pnp`, `fit_pose`), `batch` (many
frames at once: `solve_pnp_batch`, the same results), `hypotheses` (MSAC ranking of candidate
poses: `best_hypothesis`, `refine_best`).
"""

from dream.optim import RobustLoss
from dream.pnp.batch import solve_pnp_batch
from dream.pnp.hypotheses import best_hypothesis, refine_best
from dream.pnp.reprojection import apply_increment, increment_between, linearise
from dream.pnp.settings import MIN_KEYPOINTS, RAYLEIGH_MEDIAN, NoSolution, PoseFit, SolverSettings
from dream.pnp.single import (
    check_correspondences,
    degeneracy,
    fit_pose,
    initial_pose,
    lm_settings,
    refine_pose,
    solve_pnp,
)

__all__ = [
    "MIN_KEYPOINTS",
    "RAYLEIGH_MEDIAN",
    "NoSolution",
    "PoseFit",
    "RobustLoss",
    "SolverSettings",
    "apply_increment",
    "best_hypothesis",
    "check_correspondences",
    "degeneracy",
    "fit_pose",
    "increment_between",
    "initial_pose",
    "refine_pose",
    "linearise",
    "lm_settings",
    "refine_best",
    "solve_pnp",
    "solve_pnp_batch",
]
