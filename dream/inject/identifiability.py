"""Which effects a fixed camera can see: joints, link lengths and keypoints whose change moves
the keypoints in a way that one constant extrinsic cannot absorb."""

from __future__ import annotations

import numpy as np

from dream.errors import InputError
from dream.robot import Robot
from dream.robot.tree import MIN_OFFSET_M
from dream.sample import random_joints
from dream.transforms import skew

PROBE_SEED = 20240611            # fixed: the probes never draw from the caller's rng
PROBE_CONFIGS = 16               # random configurations the probes look at
PROBE_RANGE_FRACTION = 0.8       # ... drawn in this central part of the joint limits
PROBE_STRETCH_M = 1e-3           # finite-difference step of a link length change, m
MIN_KEYPOINT_MOTION = 1e-3       # RMS keypoint motion per unit change (m/rad, m/m) to count
MIN_NON_RIGID_FRACTION = 0.05    # share of that motion a fixed extrinsic must fail to explain


def rigid_motion_residual(dP: np.ndarray, P: np.ndarray) -> float:
    """Share of a keypoint motion that no constant rigid motion of the base frame explains.

    Fits dP ~ w x P + v (one small rotation w and translation v for all configurations and
    keypoints: what a fixed extrinsic absorbs) by least squares.

    Args:
        dP: (C, K, 3) motion of the keypoints per unit change. P: (C, K, 3) keypoints, m.
    Returns:
        ||residual|| / ||dP|| in [0, 1] (0 when dP is zero).
    """
    dP, P = np.asarray(dP, dtype=float), np.asarray(P, dtype=float)
    if dP.shape != P.shape or dP.shape[-1:] != (3,):
        raise InputError(f"dP {dP.shape} and P {P.shape} must both be (..., 3)")
    b = dP.reshape(-1)
    norm = float(np.linalg.norm(b))
    if norm == 0.0:
        return 0.0
    points = P.reshape(-1, 3)
    A = np.concatenate([-skew(points), np.broadcast_to(np.eye(3), (len(points), 3, 3))], axis=2)
    A = A.reshape(-1, 6)
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    return float(np.linalg.norm(A @ x - b) / norm)


def _probe_joints(robot: Robot) -> np.ndarray:
    return random_joints(np.random.default_rng(PROBE_SEED), robot, PROBE_CONFIGS,
                         PROBE_RANGE_FRACTION)


def _visible_change(dP: np.ndarray, P: np.ndarray) -> bool:
    rms = float(np.sqrt(np.mean(np.sum(dP ** 2, axis=-1))))
    return rms >= MIN_KEYPOINT_MOTION and rigid_motion_residual(dP, P) >= MIN_NON_RIGID_FRACTION


def identifiable_joints(robot: Robot) -> tuple[str, ...]:
    """Joints whose offset a fixed camera can tell from the extrinsic: the keypoints move
    (non-zero `keypoint_jacobian` column) and not as one rigid body (for a fixed-base arm the
    first joint only turns everything about its axis, which the extrinsic absorbs)."""
    q = _probe_joints(robot)
    P = robot.forward_kinematics(q)
    jac = robot.keypoint_jacobian(q)
    return tuple(name for j, name in enumerate(robot.joint_names)
                 if _visible_change(jac[..., j], P))


def stretchable_joints(robot: Robot) -> tuple[str, ...]:
    """Joints (fixed ones too) on the chains to the keypoints whose origin offset is non-zero
    and whose length change moves the keypoints in a way the extrinsic cannot absorb."""
    q = _probe_joints(robot)
    P = robot.forward_kinematics(q)
    out = []
    for joint in robot.chain_joints:
        if np.linalg.norm(joint.origin[:3, 3]) < max(MIN_OFFSET_M, PROBE_STRETCH_M):
            continue
        stretched = robot.with_link_length_changes({joint.name: PROBE_STRETCH_M})
        dP = (stretched.forward_kinematics(q) - P) / PROBE_STRETCH_M
        if _visible_change(dP, P):
            out.append(joint.name)
    return tuple(out)


def moving_keypoints(robot: Robot) -> tuple[str, ...]:
    """Keypoints that move with the joints. A keypoint that never moves (the base link's)
    projects to one pixel of a fixed camera in every frame, so the component of its bias along
    the viewing ray is unobservable: `dream diagnose` reports it as not identifiable, and such
    a bias is not drawn here (its truth could not be compared in 3D)."""
    q = _probe_joints(robot)
    P = robot.forward_kinematics(q)
    spread = np.sqrt(np.mean(np.sum((P - P.mean(axis=0)) ** 2, axis=-1), axis=0))
    return tuple(k for k, s in zip(robot.keypoint_names, spread, strict=True)
                 if s >= MIN_KEYPOINT_MOTION)
