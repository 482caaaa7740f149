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
- `RESULT.urdf.xml`: a fixed URDF `<joint>` from the base link to the camera frame (and the
  camera `<link>`), to paste into the robot's URDF or xacro; `origin` xyz in metres, rpy in
  radians (fixed axes: R = Rz(yaw) Ry(pitch) Rx(roll)).
- `RESULT.launch.py`: a ROS 2 launch file starting `static_transform_publisher` with the pose.
- `RESULT.handeye.yaml`: the calibration in easy_handeye's YAML (`eye_on_hand: false`,
  `robot_base_frame`, `tracking_base_frame`, `transformation` x y z qx qy qz qw).

Frame names: the base frame defaults to the robot's base link and the camera frame to
`camera_optical_frame`; `dream calibrate --base-frame / --camera-frame` set them.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from dream.errors import InputError
from dream.transforms import invert_T, is_rigid, quaternion_xyzw_from_R

CAMERA_OPTICAL_FRAME = "camera_optical_frame"
ROS_SUFFIX = ".ros.txt"
MATRIX_SUFFIX = ".T_base_cam.txt"
URDF_SUFFIX = ".urdf.xml"
LAUNCH_SUFFIX = ".launch.py"
HANDEYE_SUFFIX = ".handeye.yaml"
SIGNIFICANT_DIGITS = 9
FRAME_NAME = re.compile(r"[A-Za-z0-9_./-]+")
_RIGID_TOLERANCE = 1e-6


def _number(value: float) -> str:
    text = f"{float(value):.{SIGNIFICANT_DIGITS}g}"
    return "0" if text == "-0" else text


def _check_T(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not is_rigid(T, atol=_RIGID_TOLERANCE):
        raise InputError(f"{what} is not a 4x4 rigid transform")
    return T


def check_frame_name(name: str, what: str, fix: str | None = None) -> str:
    """`name` when it is a tf frame name; else an `InputError` naming `what` (e.g. an option)."""
    if not isinstance(name, str) or not FRAME_NAME.fullmatch(name):
        raise InputError(f"{what} {name!r} must be a non-empty tf frame name (letters, digits, "
                         "'_', '/', '.', '-')", fix=fix)
    return name


def static_transform_args(T_base_cam: np.ndarray, base_frame: str,
                          camera_frame: str = CAMERA_OPTICAL_FRAME) -> str:
    """`x y z qx qy qz qw base_frame camera_frame`: the camera pose in the base frame, in the
    positional order of ROS 1 tf / tf2_ros `static_transform_publisher` (no period)."""
    T = _check_T(T_base_cam, "T_base_cam")
    q = quaternion_xyzw_from_R(T[:3, :3])
    numbers = " ".join(_number(v) for v in (*T[:3, 3], *q))
    return f"{numbers} {' '.join(_check_frames(base_frame, camera_frame))}"


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


def _check_frames(base_frame: str, camera_frame: str) -> tuple[str, str]:
    return (check_frame_name(base_frame, "base frame"),
            check_frame_name(camera_frame, "camera frame"))


def _pose_numbers(T_cam_base: np.ndarray) -> tuple[list[str], list[str]]:
    """(x y z, qx qy qz qw) of T_base_cam as text."""
    T_base_cam = invert_T(_check_T(T_cam_base, "T_cam_base"))
    return ([_number(v) for v in T_base_cam[:3, 3]],
            [_number(v) for v in quaternion_xyzw_from_R(T_base_cam[:3, :3])])


def rpy_from_R(R: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw), rad, of R = Rz(yaw) Ry(pitch) Rx(roll) (URDF's fixed-axis rpy).

    >>> rpy_from_R(np.eye(3)).tolist()
    [0.0, -0.0, 0.0]
    """
    R = np.asarray(R, dtype=float)
    pitch = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    return np.array([np.arctan2(R[2, 1], R[2, 2]), pitch, np.arctan2(R[1, 0], R[0, 0])])


def urdf_text(T_cam_base: np.ndarray, base_frame: str,
              camera_frame: str = CAMERA_OPTICAL_FRAME) -> str:
    """The RESULT.urdf.xml file: a fixed joint base -> camera and the camera link."""
    base, camera = _check_frames(base_frame, camera_frame)
    T_base_cam = invert_T(_check_T(T_cam_base, "T_cam_base"))
    xyz = " ".join(_number(v) for v in T_base_cam[:3, 3])
    rpy = " ".join(_number(v) for v in rpy_from_R(T_base_cam[:3, :3]))
    return (f"<!-- camera pose from dream calibrate: paste into the robot's URDF or xacro; "
            f"{camera} is the OpenCV optical frame (x right, y down, z forward) -->\n"
            f'<joint name="{camera}_joint" type="fixed">\n'
            f'  <parent link="{base}"/>\n'
            f'  <child link="{camera}"/>\n'
            f'  <origin xyz="{xyz}" rpy="{rpy}"/>\n'
            f"</joint>\n"
            f'<link name="{camera}"/>\n')


def launch_text(T_cam_base: np.ndarray, base_frame: str,
                camera_frame: str = CAMERA_OPTICAL_FRAME) -> str:
    """The RESULT.launch.py file: a ROS 2 launch description with the static transform."""
    base, camera = _check_frames(base_frame, camera_frame)
    (x, y, z), (qx, qy, qz, qw) = _pose_numbers(T_cam_base)
    args = ", ".join(f"'--{k}', '{v}'" for k, v in (
        ("x", x), ("y", y), ("z", z), ("qx", qx), ("qy", qy), ("qz", qz), ("qw", qw),
        ("frame-id", base), ("child-frame-id", camera)))
    return ("# camera pose from dream calibrate: ros2 launch this file, or include it\n"
            "from launch import LaunchDescription\n"
            "from launch_ros.actions import Node\n\n\n"
            "def generate_launch_description():\n"
            "    return LaunchDescription([Node(\n"
            "        package='tf2_ros', executable='static_transform_publisher',\n"
            f"        name='{camera}_static_tf',\n"
            f"        arguments=[{args}])])\n")


def handeye_text(T_cam_base: np.ndarray, base_frame: str,
                 camera_frame: str = CAMERA_OPTICAL_FRAME) -> str:
    """The RESULT.handeye.yaml file, in easy_handeye's calibration format (eye on base)."""
    base, camera = _check_frames(base_frame, camera_frame)
    (x, y, z), (qx, qy, qz, qw) = _pose_numbers(T_cam_base)
    return ("# camera pose from dream calibrate, in easy_handeye's format (eye on base)\n"
            "eye_on_hand: false\n"
            f"robot_base_frame: {base}\n"
            f"tracking_base_frame: {camera}\n"
            "transformation:\n"
            f"  x: {x}\n  y: {y}\n  z: {z}\n"
            f"  qx: {qx}\n  qy: {qy}\n  qz: {qz}\n  qw: {qw}\n")


def snippet_paths(result_path: str | Path) -> tuple[Path, Path, Path]:
    """(RESULT.urdf.xml, RESULT.launch.py, RESULT.handeye.yaml) next to RESULT.json."""
    path = Path(result_path)
    return (path.with_suffix(URDF_SUFFIX), path.with_suffix(LAUNCH_SUFFIX),
            path.with_suffix(HANDEYE_SUFFIX))
