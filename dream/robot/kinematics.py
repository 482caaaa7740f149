"""Vectorised forward kinematics of one joint step (pure numpy).

A link frame is carried as a rotation `R` (..., 3, 3) and a position `p` (..., 3), both
expressed in one reference frame (the tree's root); leading batch axes broadcast freely and a
frame that no joint value moves stays unbatched (3, 3) / (3,).
"""

from __future__ import annotations

import numpy as np

from dream.robot.tree import FIXED, PRISMATIC, ROTATING_TYPES, JointModel

IDENTITY_R = np.eye(3)
IDENTITY_R.setflags(write=False)
ZERO_P = np.zeros(3)
ZERO_P.setflags(write=False)


def rotation_about_axis(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotations by `angle` (...) rad about a unit `axis` (3,) (Rodrigues): shape (..., 3, 3)."""
    axis = np.asarray(axis, dtype=float)
    if axis.shape != (3,):
        raise ValueError(f"axis has shape {axis.shape}, expected (3,)")
    angle = np.asarray(angle, dtype=float)
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    s = np.sin(angle)[..., None, None]
    c = np.cos(angle)[..., None, None]
    return IDENTITY_R + s * K + (1.0 - c) * (K @ K)


def apply(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R @ v for rotations (..., 3, 3) and vectors (..., 3), broadcasting: shape (..., 3)."""
    return np.einsum("...ij,...j->...i", R, v)


def joint_frame(R_parent: np.ndarray, p_parent: np.ndarray,
                joint: JointModel) -> tuple[np.ndarray, np.ndarray]:
    """The joint frame (child frame at value 0) from its parent link frame.

    Args:
        R_parent: (..., 3, 3) parent link orientation in the reference frame.
        p_parent: (..., 3) parent link origin in the reference frame, m.
        joint: supplies `origin` = T_parent_joint.
    Returns:
        (R_joint (..., 3, 3), p_joint (..., 3)) in the reference frame.
    """
    return R_parent @ joint.origin[:3, :3], p_parent + apply(R_parent, joint.origin[:3, 3])


def child_frame(R_joint: np.ndarray, p_joint: np.ndarray, joint: JointModel,
                value: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """The child link frame from the joint frame and the joint value.

    Args:
        R_joint, p_joint: the joint frame, (..., 3, 3) and (..., 3).
        joint: a fixed, revolute, continuous or prismatic joint.
        value: joint value(s), rad or m, shape (...) broadcasting with the frame; ignored for
            fixed joints.
    Returns:
        (R_child (..., 3, 3), p_child (..., 3)) in the reference frame.
    Raises:
        ValueError: an unsupported joint type (callers check types beforehand).
    """
    if joint.type == FIXED:
        return R_joint, p_joint
    if joint.type in ROTATING_TYPES:
        return R_joint @ rotation_about_axis(joint.axis, value), p_joint
    if joint.type == PRISMATIC:
        shift = np.asarray(value, dtype=float)[..., None] * joint.axis
        return R_joint, p_joint + apply(R_joint, shift)
    raise ValueError(f"joint '{joint.name}' of type '{joint.type}' is not supported")


def joint_point_jacobian(R_joint: np.ndarray, p_joint: np.ndarray, joint: JointModel,
                         points: np.ndarray) -> np.ndarray:
    """d point / d value for points carried by the joint's child, in the reference frame.

    Args:
        R_joint, p_joint: the joint frame, (..., 3, 3) and (..., 3).
        joint: a revolute, continuous or prismatic joint.
        points: (..., N, 3) points downstream of the joint, reference frame, m.
    Returns:
        (..., N, 3): axis x (point - joint origin) for rotating joints, the axis for prismatic.
    """
    axis = apply(R_joint, joint.axis)[..., None, :]
    if joint.type in ROTATING_TYPES:
        return np.cross(axis, points - p_joint[..., None, :])
    if joint.type == PRISMATIC:
        return np.broadcast_to(axis, np.broadcast_shapes(axis.shape, points.shape))
    raise ValueError(f"joint '{joint.name}' of type '{joint.type}' does not move")
