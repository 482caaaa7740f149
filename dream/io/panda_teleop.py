"""The panda_teleop layout: `info.json` and PNG images (docs/data_format.md#panda_teleop).

`info.json` holds `calibration_info.intrinsic` (3x3 K, pixels), optionally
`calibration_info.extrinsic` (`[[rx, ry, rz, tx, ty, tz]]`: Rodrigues vector and metres,
X_cam = R X_base + t, a reference extrinsic that only scores; a recording to calibrate has
none) and `steps`, keyed by Unix capture time (s) as strings, in no guaranteed order, each with
`img_file` and `joint_angles` (rad; values after the arm's joints, a gripper's, are left out).
Frames are named "000000"... in time order.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence as SequenceOf
from pathlib import Path
from typing import Any

import numpy as np

from dream.errors import InputError
from dream.io import fields
from dream.io.common import (
    PANDA_ARM_JOINTS,
    PANDA_ROBOT,
    check_joint_names,
    check_robot,
    common_image_size,
    frame_name,
)
from dream.io.intrinsics import IntrinsicsArg, camera_from_argument, camera_from_K
from dream.sequence import Frame, Sequence
from dream.transforms import T_from_rotvec_t

logger = logging.getLogger(__name__)

INFO_FILE = "info.json"
EXTRINSIC_SIZE = 6  # rx, ry, rz (Rodrigues, rad), tx, ty, tz (m)
FIX_INFO = ('write info.json with "calibration_info": {"intrinsic": 3x3} (and, to score the '
            'result, "extrinsic": [[rx, ry, rz, tx, ty, tz]]) and "steps": {"<unix time>": '
            '{"img_file", "joint_angles"}}')


def find_episode(path: Path) -> Path:
    """The episode folder: `path` itself when it holds `info.json`, or its one sub-folder that does.

    `path` may also be the `info.json` file.
    """
    if path.is_file() and path.name == INFO_FILE:
        return path.parent
    if (path / INFO_FILE).is_file():
        return path
    if not path.is_dir():
        raise InputError("is not a folder", path, f"point at the folder holding {INFO_FILE}")
    try:
        episodes = sorted(p for p in path.iterdir() if (p / INFO_FILE).is_file())
    except OSError as exc:
        raise InputError(f"cannot list the folder ({fields.os_reason(exc)})",
                         path) from None
    if not episodes:
        raise InputError(f"holds no {INFO_FILE}, neither directly nor in a sub-folder", path,
                         f"point at a panda_teleop episode folder holding {INFO_FILE}")
    if len(episodes) > 1:
        names = ", ".join(fields.quote(p.name) for p in episodes)
        raise InputError(f"holds several episodes ({names})", path,
                         "point at one of those folders")
    return episodes[0]


def _step_time(key: str, path: Path) -> float:
    try:
        time_s = float(key)
    except ValueError:
        raise InputError(f"step key {fields.quote(key)} is not a Unix time in seconds", path,
                         FIX_INFO) from None
    if not math.isfinite(time_s):
        raise InputError(f"step key {fields.quote(key)} is not a finite time", path, FIX_INFO)
    return time_s


def _parse_steps(steps: dict[str, Any], folder: Path, path: Path, n_joints: int
                 ) -> list[tuple[float, Path, np.ndarray]]:
    """(time, image, joints) of every step, sorted by time."""
    out = []
    for key, step in steps.items():
        time_s = _step_time(key, path)
        what = f"steps[{fields.quote(key)}]"
        step = fields.as_dict(step, what, path, FIX_INFO)
        img_file = fields.as_str(fields.require(step, "img_file", f"{what}.img_file", path,
                                                FIX_INFO), f"{what}.img_file", path, FIX_INFO)
        angles = fields.as_list(fields.require(step, "joint_angles", f"{what}.joint_angles",
                                               path, FIX_INFO), f"{what}.joint_angles", path,
                                FIX_INFO)
        fix = (f"write the arm's {n_joints} joint angles in radians first (finger positions "
               "may follow)")
        if len(angles) < n_joints:
            raise InputError(f"{what}.joint_angles has {len(angles)} values, fewer than the "
                             f"arm's {n_joints} joints", path, fix)
        joints = fields.as_vector(angles[:n_joints], f"{what}.joint_angles", path, n_joints,
                                  fix)              # the gripper's values after them left out
        image = folder / img_file
        if not image.is_file():
            raise InputError(f"{what}.img_file {fields.quote(img_file)} not found in {folder}",
                             path, "add the image or remove the step")
        out.append((time_s, image, joints))
    out.sort(key=lambda item: item[0])
    times = [time_s for time_s, _, _ in out]
    for t0, t1 in zip(times, times[1:], strict=False):
        if t1 == t0:
            raise InputError(f"two steps share the time {t0!r} s", path,
                             "give every step its own capture time")
    return out


def _reference(calibration: dict[str, Any], path: Path) -> np.ndarray | None:
    """The reference extrinsic, or None where the file gives none (or gives null)."""
    what = "calibration_info.extrinsic"
    value = calibration.get("extrinsic")
    if value is None:
        return None
    if isinstance(value, list) and len(value) == 1 and isinstance(value[0], list):
        value = value[0]  # the published form wraps the six numbers in a list
    rt = fields.as_vector(value, what, path, EXTRINSIC_SIZE, FIX_INFO)
    return T_from_rotvec_t(rt[:3], rt[3:])


def read_panda_teleop(path: str | Path, *, joint_names: SequenceOf[str] | None = None,
                      intrinsics: IntrinsicsArg | None = None,
                      robot: str | None = None) -> Sequence:
    """Read a panda_teleop episode into a `Sequence` (its reference extrinsic where it has one).

    Args:
        path: the episode folder, its parent holding one episode, or `info.json`.
        joint_names: names of the `joint_angles` columns; default panda_joint1..7.
        intrinsics: replaces `calibration_info.intrinsic` when given.
        robot: robot name; default "panda".
    """
    folder = find_episode(Path(path))
    info_path = folder / INFO_FILE
    names = check_joint_names(joint_names, PANDA_ARM_JOINTS)
    robot = check_robot(robot, PANDA_ROBOT)
    data = fields.as_dict(fields.load_json(info_path, FIX_INFO), "the file", info_path, FIX_INFO)
    calibration = fields.as_dict(fields.require(data, "calibration_info", "calibration_info",
                                                info_path, FIX_INFO),
                                 "calibration_info", info_path, FIX_INFO)
    steps = fields.as_dict(fields.require(data, "steps", "steps", info_path, FIX_INFO),
                           "steps", info_path, FIX_INFO)
    if not steps:
        raise InputError("steps is empty", info_path, FIX_INFO)
    parsed = _parse_steps(steps, folder, info_path, len(names))
    width, height = common_image_size(image for _, image, _ in parsed)
    if intrinsics is not None:
        camera = camera_from_argument(intrinsics, width, height, info_path)
    else:
        K = fields.as_matrix(fields.require(calibration, "intrinsic", "calibration_info.intrinsic",
                                            info_path, FIX_INFO),
                             "calibration_info.intrinsic", info_path, 3, 3, FIX_INFO)
        camera = camera_from_K(K, width, height, info_path, fix=FIX_INFO)
    reference = _reference(calibration, info_path)
    frames = [Frame(name=frame_name(i), joints=joints, image_path=image, timestamp=time_s,
                    source=info_path)
              for i, (time_s, image, joints) in enumerate(parsed)]
    sequence = Sequence(robot=robot, camera=camera, joint_names=names, keypoint_names=(),
                        frames=tuple(frames), T_cam_base_reference=reference, source=folder)
    logger.info("read %d panda_teleop frames (%.3f s) from %s", len(frames),
                parsed[-1][0] - parsed[0][0], folder)
    return sequence
