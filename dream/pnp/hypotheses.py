"""Pose hypotheses of a frame ranked by their MSAC score, and the best one refined.

The multi-frame solve (`dream.calibration.calibrate_all`) gathers hypotheses of the one
extrinsic (each frame's own pose, SQPnP on every keypoint, random samples across frames); these
rank them over the usable keypoints (squared pixel distances truncated at
`SolverSettings.ransac_threshold_px`) and refine the best with `fit_pose`.
"""

from __future__ import annotations

import numpy as np

from dream.camera import CameraIntrinsics
from dream.pnp.reprojection import reprojection_distance
from dream.pnp.settings import NoSolution, PoseFit, SolverSettings
from dream.pnp.single import best_scored, fit_pose


def best_hypothesis(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                    hypotheses: list[np.ndarray], usable: np.ndarray,
                    settings: SolverSettings) -> tuple[np.ndarray, np.ndarray] | NoSolution:
    """The hypothesis with the lowest MSAC score over the usable keypoints and its inliers (N,)
    (every usable keypoint when fewer than `min_keypoints` are inliers)."""
    if not hypotheses:
        return NoSolution("no initial pose could be found")
    return best_scored([reprojection_distance(P_base[usable], uv[usable], camera, T) ** 2
                        for T in hypotheses], hypotheses, usable, settings)


def refine_best(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics,
                hypotheses: list[np.ndarray], confidence: np.ndarray, usable: np.ndarray,
                settings: SolverSettings) -> PoseFit | NoSolution:
    """Rank hypotheses by MSAC score over the usable keypoints and refine the best one."""
    start = best_hypothesis(P_base, uv, camera, hypotheses, usable, settings)
    if isinstance(start, NoSolution):
        return start
    return fit_pose(P_base, uv, camera, start[0], confidence=confidence, inlier=start[1],
                    settings=settings)
