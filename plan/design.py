"""Choosing robot poses by the information they give about the extrinsic (D-optimal design).

Each candidate pose contributes the Fisher information of its keypoint projections about the
camera pose, F = J^T J / sigma^2, with J the (2K, 6) derivative of the pixels by the pose
increment xi = (delta_rot, delta_t) of `dream.pnp` (camera axes). A calibration from a set of
poses has the summed information; its inverse is the Cramer-Rao bound `dream.crb` states.
A D-optimal set maximises log det of that sum, i.e. shrinks the volume of the uncertainty
ellipsoid; the criterion does not depend on the units of rotation and translation.

The camera is known only roughly, so the information is computed for several camera poses drawn
from its stated uncertainty, and a set is scored by the mean of their log dets.

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> F = rng.normal(size=(2, 30, 6, 8)); F = F @ F.transpose(0, 1, 3, 2)
    >>> chosen = select_d_optimal(F, 4, rng=rng)
    >>> len(set(chosen.tolist()))
    4
"""

from __future__ import annotations

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.pnp.reprojection import linearise_rows
from dream.result import camera_position_covariance

# added to every summed information, relative to its mean diagonal: keeps log det finite for
# the first pick of a greedy selection without changing any ranking measurably
PRIOR_RELATIVE = 1e-9
EXCHANGE_TOLERANCE = 1e-9   # an exchange must raise the mean log det by more than this
MAX_EXCHANGE_ROUNDS = 20    # passes over the chosen poses; each pass swaps each pose at most once


def pose_information(P_base: np.ndarray, camera: CameraIntrinsics, T_cam_base: np.ndarray,
                     noise_px: float) -> np.ndarray:
    """(6, 6) Fisher information about xi of K keypoints at `P_base` (K, 3) seen by a camera at
    `T_cam_base` with i.i.d. Gaussian pixel noise `noise_px`. A keypoint behind that camera or
    outside its image is not observed and adds nothing.

    >>> from dream.transforms import look_at
    >>> camera = CameraIntrinsics(600.0, 600.0, 319.5, 239.5, 640, 480)
    >>> T = look_at(np.array([1.5, 0.0, 0.5]), np.zeros(3))
    >>> F = pose_information(np.random.default_rng(1).normal(size=(7, 3)) * 0.2, camera, T, 1.0)
    >>> F.shape, bool(np.allclose(F, F.T))
    ((6, 6), True)
    """
    P_base = np.asarray(P_base, dtype=float)
    if P_base.ndim != 2 or P_base.shape[1] != 3:
        raise InputError(f"P_base must have shape (K, 3), got {P_base.shape}")
    if not (np.isfinite(noise_px) and noise_px > 0):
        raise InputError(f"the keypoint noise must be a positive number of pixels, got "
                         f"{noise_px}", fix="give e.g. --noise-px 2")
    uv, J, front = linearise_rows(P_base, np.zeros((len(P_base), 2)), camera, T_cam_base)
    seen = front & camera.in_image(uv) & np.all(np.isfinite(uv), axis=-1)
    J = J[seen].reshape(-1, 6)
    return J.T @ J / noise_px ** 2


def information_table(P_base: np.ndarray, camera: CameraIntrinsics, T_cam_base: np.ndarray,
                      noise_px: float) -> np.ndarray:
    """(S, N, 6, 6) information of N poses' keypoints `P_base` (N, K, 3) for each of S camera
    poses `T_cam_base` (S, 4, 4) (`pose_information`)."""
    P_base = np.asarray(P_base, dtype=float)
    T_cam_base = np.asarray(T_cam_base, dtype=float)
    if P_base.ndim != 3 or P_base.shape[2] != 3:
        raise InputError(f"P_base must have shape (N, K, 3), got {P_base.shape}")
    if T_cam_base.ndim != 3 or T_cam_base.shape[1:] != (4, 4):
        raise InputError(f"T_cam_base must have shape (S, 4, 4), got {T_cam_base.shape}")
    return np.array([[pose_information(P, camera, T, noise_px) for P in P_base]
                     for T in T_cam_base])


def _prior(F: np.ndarray) -> np.ndarray:
    """(S, 6, 6) the small ridge `PRIOR_RELATIVE` adds for each camera sample."""
    scale = np.trace(F.sum(axis=1), axis1=-2, axis2=-1) / (6 * F.shape[1])
    return PRIOR_RELATIVE * np.maximum(scale, np.finfo(float).tiny)[:, None, None] * np.eye(6)


def mean_log_det(F: np.ndarray, chosen: np.ndarray) -> float:
    """The D-criterion of the poses `chosen` (indices into F's N): mean over the S camera
    samples of log det of their summed information (ridge included)."""
    total = _prior(F) + F[:, np.asarray(chosen, dtype=int)].sum(axis=1)
    return float(np.mean(np.linalg.slogdet(total)[1]))


def _greedy(F: np.ndarray, num: int, first: int, prior: np.ndarray) -> list[int]:
    chosen = [first]
    total = prior + F[:, first]
    available = np.ones(F.shape[1], bool)
    available[first] = False
    while len(chosen) < num:
        scores = np.linalg.slogdet(total[:, None] + F)[1].mean(axis=0)
        scores[~available] = -np.inf
        best = int(np.argmax(scores))
        chosen.append(best)
        available[best] = False
        total = total + F[:, best]
    return chosen


def _exchange(F: np.ndarray, chosen: list[int], prior: np.ndarray) -> list[int]:
    """Swap chosen poses for unchosen ones while the criterion rises (Fedorov's exchange)."""
    chosen = list(chosen)
    total = prior + F[:, chosen].sum(axis=1)
    score = float(np.linalg.slogdet(total)[1].mean())
    for _ in range(MAX_EXCHANGE_ROUNDS):
        improved = False
        for slot in range(len(chosen)):
            without = total - F[:, chosen[slot]]
            scores = np.linalg.slogdet(without[:, None] + F)[1].mean(axis=0)
            scores[chosen] = -np.inf
            best = int(np.argmax(scores))
            if scores[best] > score + EXCHANGE_TOLERANCE:
                chosen[slot], total, score = best, without + F[:, best], float(scores[best])
                improved = True
        if not improved:
            break
    return chosen


def select_d_optimal(F: np.ndarray, num: int, *, restarts: int = 4,
                     rng: np.random.Generator | None = None) -> np.ndarray:
    """Indices (num,) of the poses that maximise `mean_log_det`: a greedy pick from the best
    single pose and from `restarts` random first poses, each improved by exchanges; the best
    of them.

    Args:
        F: (S, N, 6, 6) `information_table`.
        num: poses to choose, 1 <= num <= N.
        restarts: extra greedy runs from random first poses.
        rng: draws those first poses.
    """
    F = np.asarray(F, dtype=float)
    if F.ndim != 4 or F.shape[2:] != (6, 6) or F.shape[0] < 1:
        raise InputError(f"the information table must have shape (S, N, 6, 6), got {F.shape}")
    if not 1 <= num <= F.shape[1]:
        raise InputError(f"cannot choose {num} of {F.shape[1]} poses")
    rng = np.random.default_rng(0) if rng is None else rng
    prior = _prior(F)
    single = np.linalg.slogdet(prior[:, None] + F)[1].mean(axis=0)
    firsts = [int(np.argmax(single))]
    firsts += rng.choice(F.shape[1], size=min(restarts, F.shape[1]), replace=False).tolist()
    best, best_score = None, -np.inf
    for first in dict.fromkeys(firsts):
        chosen = _exchange(F, _greedy(F, num, first, prior), prior)
        score = mean_log_det(F, chosen)
        if score > best_score:
            best, best_score = chosen, score
    return np.array(best, dtype=int)


def predicted_sigmas(information: np.ndarray, T_cam_base: np.ndarray) -> dict[str, object]:
    """1-sigma of the calibration the summed `information` (6, 6) predicts at `T_cam_base`:
    the camera position in the base frame (per axis and along its worst direction, m) and the
    rotation (worst direction, rad). Infinite where the information is singular."""
    try:
        covariance = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        covariance = np.full((6, 6), np.inf)
    if not np.all(np.isfinite(covariance)):
        inf3 = [float("inf")] * 3
        return {"position_base_m": inf3, "position_worst_m": float("inf"),
                "rotation_worst_rad": float("inf")}
    position = camera_position_covariance(T_cam_base, covariance)
    return {
        "position_base_m": np.sqrt(np.clip(np.diag(position), 0, None)).tolist(),
        "position_worst_m": float(np.sqrt(max(np.linalg.eigvalsh(position)[-1], 0.0))),
        "rotation_worst_rad": float(np.sqrt(max(np.linalg.eigvalsh(covariance[:3, :3])[-1],
                                                0.0))),
    }
