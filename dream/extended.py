"""What a model extension changes, applied (pure): the camera, the robot, the joints at the
image times and the keypoints (`dream.extension` holds the vocabulary)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.extension import HeldReadings, ModelExtension
from dream.robot import Robot


def extended_camera(camera: CameraIntrinsics, extension: ModelExtension) -> CameraIntrinsics:
    """The camera with corrected intrinsics and distortion (others kept)."""
    fx, fy, cx, cy = extension.intrinsics or (camera.fx, camera.fy, camera.cx, camera.cy)
    distortion = camera.distortion
    if extension.distortion is not None:
        k3 = camera.distortion[4] if camera.distortion else 0.0
        distortion = tuple(extension.distortion) + (k3,)
    return CameraIntrinsics(fx, fy, cx, cy, camera.width, camera.height, distortion)


def extended_robot(robot: Robot, extension: ModelExtension) -> Robot:
    """The robot with the link length changes applied (unknown joint -> RobotError)."""
    if extension.robot and extension.robot != robot.name:
        raise InputError(f"the model extension was fitted for robot '{extension.robot}', not "
                         f"'{robot.name}'", fix="use the extension of this robot")
    return robot.with_link_length_changes(extension.link_length_m) \
        if extension.link_length_m else robot


def joint_offset_vector(robot: Robot, offsets: Mapping[str, float]) -> np.ndarray:
    """(J,) offsets in the robot's joint order from joint name -> offset."""
    out = np.zeros(robot.num_joints)
    for name, value in offsets.items():
        if name not in robot.joint_names:
            raise InputError(f"joint offset for unknown joint '{name}'",
                             fix=f"use joints of {robot.name}: {', '.join(robot.joint_names)}")
        out[robot.joint_names.index(name)] = value
    return out


def distinct_readings(times_s: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The readings at which the joint vector changed (a logger that repeats the last reading
    between updates writes stale copies: the time of a reading is when its value appeared).

    Args:
        times_s: (F,) increasing times; joints: (F, J).
    Returns:
        (times (M,), joints (M, J)) with M >= 1.
    """
    times_s = np.asarray(times_s, dtype=float)
    joints = np.asarray(joints, dtype=float)
    if times_s.ndim != 1 or joints.shape[:1] != times_s.shape:
        raise InputError(f"times {times_s.shape} and joints {joints.shape} do not match")
    keep = np.ones(len(times_s), bool)
    keep[1:] = np.any(joints[1:] != joints[:-1], axis=1)
    return times_s[keep], joints[keep]


def interpolate_joints(times_s: np.ndarray, joints: np.ndarray,
                       query_s: np.ndarray) -> np.ndarray:
    """Joint readings (M,) / (M, J) interpolated at `query_s` (Q,): shape-preserving cubic
    (PCHIP) between readings, held constant outside them. Returns (Q, J)."""
    from scipy.interpolate import PchipInterpolator

    times_s = np.asarray(times_s, dtype=float)
    joints = np.asarray(joints, dtype=float)
    query = np.clip(np.asarray(query_s, dtype=float), times_s[0], times_s[-1])
    if len(times_s) == 1:
        return np.broadcast_to(joints[0], (len(query), joints.shape[1])).copy()
    if np.any(np.diff(times_s) <= 0):
        raise InputError("joint reading times must increase strictly",
                         fix="sort frames by timestamp")
    return PchipInterpolator(times_s, joints, axis=0, extrapolate=False)(query)


def held_joints(joints: np.ndarray, times_s: np.ndarray, held: HeldReadings,
                joint_names: tuple[str, ...]) -> np.ndarray:
    """(F, J) the held joints interpolated in time between their updates
    (`dream.readings.interpolated_joints`), the others as logged. A column that does not repeat
    its readings (already interpolated, e.g. by `dream calibrate --joint-readings interpolate`)
    is left as it is."""
    from dream.readings import interpolated_joints, reading_updates

    out = np.array(joints, dtype=float)
    for j in held.columns(tuple(joint_names)):
        column = out[:, [j]]
        updates = reading_updates(times_s, column)
        if updates.held:
            out[:, j] = interpolated_joints(times_s, column, updates)[:, 0]
    return out


def effective_joints(joints: np.ndarray, times_s: np.ndarray | None,
                     time_offset_s: float | None, held: HeldReadings | None = None,
                     joint_names: tuple[str, ...] = ()) -> np.ndarray:
    """(F, J) joint values at the image times: held readings interpolated between their
    updates (`held`, with the robot's `joint_names`), then shifted by the time offset."""
    joints = np.asarray(joints, dtype=float)
    if time_offset_s is None and held is None:  # not modelled: the readings as logged
        return joints  # (a modelled offset of 0 still interpolates: one model for every value)
    if times_s is None:
        raise InputError("a time offset or held readings need frame timestamps",
                         fix="give data with timestamps or drop the time_offset and "
                             "held_readings effects")
    shift = time_offset_s or 0.0
    if held is not None:
        joints = held_joints(joints, np.asarray(times_s, dtype=float), held, joint_names)
        shift += held.phase_s
        if time_offset_s is None and held.phase_s == 0.0:
            return joints
    t, q = distinct_readings(times_s, joints)
    return interpolate_joints(t, q, np.asarray(times_s, dtype=float) + shift)


def interpolated_frames(joints: np.ndarray, times_s: np.ndarray | None,
                        time_offset_s: float | None, held: HeldReadings | None = None,
                        joint_names: tuple[str, ...] = ()) -> np.ndarray:
    """(F,) True where `effective_joints` places the frame between two readings; False where
    it holds the first or the last reading because the image time (shifted by the time offset)
    lies outside the log: after a held log's last update the joints lag the arm by up to one
    update period. Everything is True where the readings are used as logged.

        >>> t = np.arange(8) / 30
        >>> q = np.repeat(np.arange(3.0), 3)[:8, None]      # updates at frames 0, 3, 6
        >>> interpolated_frames(q, t, None, HeldReadings(0.1), ("j",)).tolist()
        [True, True, True, True, True, True, False, False]
    """
    from dream.readings import reading_updates, update_times

    joints = np.asarray(joints, dtype=float)
    if (time_offset_s is None and held is None) or times_s is None:
        return np.ones(len(joints), bool)
    t = np.asarray(times_s, dtype=float)
    last = t[-1]
    for j in held.columns(tuple(joint_names)) if held is not None else ():
        updates = reading_updates(t, joints[:, [j]])
        if updates.held:
            last = min(last, float(update_times(t, updates.update_index)[-1]))
    query = t + (time_offset_s or 0.0) + (held.phase_s if held is not None else 0.0)
    return (query >= t[0]) & (query <= last)


def keypoint_points(robot: Robot, joints: np.ndarray, joint_offsets: np.ndarray | None,
                    keypoint_bias_m: Mapping[str, Any]) -> np.ndarray:
    """(F, K, 3) keypoints in the base frame: link origins, or biased points of the links."""
    if not keypoint_bias_m:
        return robot.forward_kinematics(joints, joint_offsets)
    for name in keypoint_bias_m:
        if name not in robot.keypoint_names:
            raise InputError(f"keypoint bias for unknown keypoint '{name}'",
                             fix=f"use keypoints of {robot.name}: "
                                 f"{', '.join(robot.keypoint_names)}")
    T = robot.link_poses(joints, robot.keypoint_names, joint_offsets)
    bias = np.array([keypoint_bias_m.get(k, (0.0, 0.0, 0.0)) for k in robot.keypoint_names],
                    dtype=float)
    return np.einsum("...kij,kj->...ki", T[..., :3, :3], bias) + T[..., :3, 3]


def frames_after_move(frame_names: tuple[str, ...], extension: ModelExtension) -> np.ndarray:
    """(F,) bool: frames at or after the camera move (all False without one)."""
    after = np.zeros(len(frame_names), bool)
    if extension.camera_moved is None:
        return after
    if extension.camera_moved.frame not in frame_names:
        raise InputError(f"camera_moved names frame '{extension.camera_moved.frame}', which "
                         f"the data does not have", fix="use the extension of this data")
    after[frame_names.index(extension.camera_moved.frame):] = True
    return after


def extended_points(robot: Robot, joints: np.ndarray, times_s: np.ndarray | None,
                    extension: ModelExtension) -> np.ndarray:
    """(F, K, 3) keypoints in the base frame under the extension's kinematic effects
    (time offset, joint offsets, link lengths, keypoint bias)."""
    robot_x = extended_robot(robot, extension)
    return keypoint_points(robot_x, image_joints(robot_x, joints, times_s, extension), None,
                           extension.keypoint_bias_m)


def image_joints(robot: Robot, joints: np.ndarray, times_s: np.ndarray | None,
                 extension: ModelExtension) -> np.ndarray:
    """(F, J) the joint values the images show under the extension's timing effects and joint
    offsets (time offset, held readings; true joint = reading + offset), in the robot's joint
    order: what the image refinements render (with `extended_robot`'s link lengths)."""
    q = effective_joints(joints, times_s, extension.time_offset_s, extension.held_readings,
                         robot.joint_names)
    if extension.joint_offset_rad:
        q = q + joint_offset_vector(robot, extension.joint_offset_rad)
    return q
