"""The extrinsic for robot software: a ROS static transform and a plain 4x4 matrix.

`dream calibrate --out RESULT.json` also writes, next to it:

- `RESULT.ros.txt`: the arguments of ROS's `static_transform_publisher` for the camera pose in
  the robot base frame, `x y z qx qy qz qw frame_id child_frame_id` (the ROS 1 tf / tf2_ros
  positional order; metres, unit quaternion), with `frame_id` the robot's base link (e.g.
  `panda_link0`) and `child_frame_id` `camera_optical_frame` (the OpenCV camera frame: x right,
  y down, z forward). Comment lines (`#`) say how to use it:

      rosrun tf2_ros static_transform_publisher $(grep -v '^#' result.ros.txt)

- `RESULT.T_base_cam.txt`: `T_base_cam` (maps camera-frame points into the base frame, the
  inverse of RESULT.json's `T_cam_base`), 4 rows of 4 numbers with 9 significant digits after
  a comment line; `numpy.loadtxt` reads it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dream.errors import InputError
from dream.transforms import invert_T, is_rigid, quaternion_xyzw_from_R

CAMERA_OPTICAL_FRAME = "camera_optical_frame"
ROS_SUFFIX = ".ros.txt"
MATRIX_SUFFIX = ".T_base_cam.txt"
SIGNIFICANT_DIGITS = 9
_RIGID_TOLERANCE = 1e-6


def _number(value: float) -> str:
    text = f"{float(value):.{SIGNIFICANT_DIGITS}g}"
    return "0" if text == "-0" else text


def _check_T(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not is_rigid(T, atol=_RIGID_TOLERANCE):
        raise InputError(f"{what} is not a 4x4 rigid transform")
    return T


def _check_frame(name: str, what: str) -> str:
    if not isinstance(name, str) or not name or any(c.isspace() for c in name):
        raise InputError(f"{what} {name!r} must be a non-empty name without spaces")
    return name


def static_transform_args(T_base_cam: np.ndarray, base_frame: str,
                          camera_frame: str = CAMERA_OPTICAL_FRAME) -> str:
    """`x y z qx qy qz qw base_frame camera_frame`: the camera pose in the base frame, in the
    positional order of ROS 1 tf / tf2_ros `static_transform_publisher` (no period)."""
    T = _check_T(T_base_cam, "T_base_cam")
    q = quaternion_xyzw_from_R(T[:3, :3])
    numbers = " ".join(_number(v) for v in (*T[:3, 3], *q))
    return f"{numbers} {_check_frame(base_frame, 'base frame')} " \
           f"{_check_frame(camera_frame, 'camera frame')}"


def ros_text(T_cam_base: np.ndarray, base_frame: str, camera_frame: str = CAMERA_OPTICAL_FRAME,
             file_name: str = "RESULT" + ROS_SUFFIX) -> str:
    """The RESULT.ros.txt file (named `file_name` in its usage line): comment lines, then the
    argument line of `T_cam_base`'s inverse."""
    T_base_cam = invert_T(_check_T(T_cam_base, "T_cam_base"))
    args = static_transform_args(T_base_cam, base_frame, camera_frame)
    x, y, z, qx, qy, qz, qw = args.split()[:7]
    return (
        f"# camera pose in the robot base frame (T_base_cam), metres and unit quaternion\n"
        f"# arguments: x y z qx qy qz qw frame_id child_frame_id (ROS 1 tf / tf2_ros order)\n"
        f"# frame_id = {base_frame} (robot base link), child_frame_id = {camera_frame} "
        f"(OpenCV optical frame: x right, y down, z forward)\n"
        f"# ROS 1: rosrun tf2_ros static_transform_publisher $(grep -v '^#' {file_name})\n"
        f"# ROS 2: ros2 run tf2_ros static_transform_publisher --x {x} --y {y} --z {z} "
        f"--qx {qx} --qy {qy} --qz {qz} --qw {qw} --frame-id {base_frame} "
        f"--child-frame-id {camera_frame}\n"
        f"{args}\n")


def matrix_text(T_cam_base: np.ndarray, base_frame: str) -> str:
    """The RESULT.T_base_cam.txt file: a comment line and `T_base_cam`, 4 rows."""
    T_base_cam = invert_T(_check_T(T_cam_base, "T_cam_base"))
    rows = "\n".join(" ".join(_number(v) for v in row) for row in T_base_cam)
    return (f"# T_base_cam: maps points in the camera optical frame (x right, y down, z forward) "
            f"into the robot base frame {base_frame}: P_base = T_base_cam @ P_cam; metres\n"
            f"{rows}\n")


def output_paths(result_path: str | Path) -> tuple[Path, Path]:
    """(RESULT.ros.txt, RESULT.T_base_cam.txt) next to RESULT.json (its suffix replaced)."""
    path = Path(result_path)
    return path.with_suffix(ROS_SUFFIX), path.with_suffix(MATRIX_SUFFIX)
