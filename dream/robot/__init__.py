"""Robot kinematics for calibration: URDF loading, built-in robots, keypoint forward kinematics.

Public API:
    load_robot(name_or_urdf, keypoints=None, base_link=None) -> Robot
    builtin_robots() -> tuple[RobotEntry, ...]
    Robot: forward_kinematics, link_poses, keypoint_jacobian, joints_from_named, ...
    resolve_resource(uri, urdf_path): `package://` and relative mesh paths -> files.
"""

from dream.robot.registry import (
    RobotEntry,
    builtin_robot,
    builtin_robots,
    is_robot_reference,
    load_robot,
)
from dream.robot.resources import filename_handler, resolve_resource, robot_data_dir, share_dir
from dream.robot.robot import Robot
from dream.robot.tree import JointModel, KinematicTree, Mimic
from dream.robot.urdf import parse_urdf

__all__ = [
    "JointModel",
    "KinematicTree",
    "Mimic",
    "Robot",
    "RobotEntry",
    "builtin_robot",
    "builtin_robots",
    "filename_handler",
    "is_robot_reference",
    "load_robot",
    "parse_urdf",
    "resolve_resource",
    "robot_data_dir",
    "share_dir",
]
