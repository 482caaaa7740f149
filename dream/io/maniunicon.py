"""The maniunicon layout: one `.npz` episode with an image stack and joint readings.

Arrays: `rgb_images` (N, H, W, 3) uint8 RGB, `captured_joint_values` (N, >= J) in radians (extra
columns, e.g. the gripper, are dropped), optionally `timestamps` (N,) in seconds;
`target_joint_values` is ignored. Intrinsics come from the `intrinsics` argument, else from a side
file next to the archive: `<stem>.intrinsics.json`, `intrinsics.json` (fx, fy, cx, cy
[, distortion]) or `K.txt`. Frames refer to the archive with `image_index`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence as SequenceOf
from pathlib import Path

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.io import fields, npz
from dream.io.common import (
    PANDA_ARM_JOINTS,
    PANDA_ROBOT,
    check_joint_names,
    check_robot,
    frame_name,
)
from dream.io.images import NPZ_SUFFIX, STACK_KEY
from dream.io.intrinsics import (
    FIX_K_TXT,
    IntrinsicsArg,
    camera_from_argument,
    camera_from_K,
    read_intrinsics_json,
    read_K_txt,
)
from dream.sequence import Frame, Sequence

logger = logging.getLogger(__name__)

JOINTS_KEY = "captured_joint_values"
TIMESTAMPS_KEY = "timestamps"
SIDE_JSON_SUFFIX = ".intrinsics.json"
SHARED_JSON = "intrinsics.json"
K_FILE = "K.txt"
NUMERIC_KINDS = "iuf"
FIX_INTRINSICS = (f"pass --intrinsics fx,fy,cx,cy or write <name>{SIDE_JSON_SUFFIX} / "
                  f'{SHARED_JSON} ({{"fx": ..., "fy": ..., "cx": ..., "cy": ...}}, pixels) '
                  f"next to the .npz")


def find_npz(path: Path) -> Path:
    """The episode archive: `path` itself, or the only `.npz` in the folder `path`."""
    if path.is_dir():
        try:
            found = sorted(p for p in path.iterdir() if p.suffix.lower() == NPZ_SUFFIX)
        except OSError as exc:
            raise InputError(f"cannot list the folder ({fields.os_reason(exc)})", path) from None
        if len(found) != 1:
            raise InputError(f"holds {len(found)} .npz files, expected one", path,
                             "point at the .npz episode file")
        return found[0]
    if not path.is_file():
        raise InputError("file not found", path, "point at the .npz episode file")
    return path


def _side_camera(npz_path: Path, width: int, height: int) -> CameraIntrinsics:
    for candidate in (npz_path.with_name(npz_path.stem + SIDE_JSON_SUFFIX),
                      npz_path.with_name(SHARED_JSON)):
        if candidate.is_file():
            return read_intrinsics_json(candidate, width, height)
    k_path = npz_path.with_name(K_FILE)
    if k_path.is_file():
        return camera_from_K(read_K_txt(k_path), width, height, k_path, fix=FIX_K_TXT)
    raise InputError("no camera intrinsics: none given and no side file found", npz_path,
                     FIX_INTRINSICS)


def _joint_table(path: Path, n_frames: int, n_joints: int) -> np.ndarray:
    header = npz.read_header(path, JOINTS_KEY)
    fix = f'store "{JOINTS_KEY}" as an (N, >= {n_joints}) float array in radians'
    if header.dtype.kind not in NUMERIC_KINDS or len(header.shape) != 2:
        raise InputError(f'"{JOINTS_KEY}" must be a 2-D numeric array, got {header.shape} '
                         f"{header.dtype}", path, fix)
    if header.shape[0] != n_frames:
        raise InputError(f'"{JOINTS_KEY}" has {header.shape[0]} rows but "{STACK_KEY}" '
                         f"holds {n_frames} images", path, "store one joint row per image")
    if header.shape[1] < n_joints:
        raise InputError(f'"{JOINTS_KEY}" has {header.shape[1]} columns, fewer than the '
                         f"{n_joints} joints", path, fix + " or pass fewer joint names")
    table = npz.read_array(path, JOINTS_KEY).astype(float)[:, :n_joints]
    bad = np.argwhere(~np.isfinite(table))
    if bad.size:
        row, col = bad[0]
        raise InputError(f'"{JOINTS_KEY}"[{row}, {col}] is not finite', path, fix)
    return table


def _timestamps(path: Path, n_frames: int) -> np.ndarray | None:
    if TIMESTAMPS_KEY not in npz.members(path):
        return None
    fix = f'store "{TIMESTAMPS_KEY}" as N finite times in seconds, or leave it out'
    header = npz.read_header(path, TIMESTAMPS_KEY)
    if header.dtype.kind not in NUMERIC_KINDS or header.shape != (n_frames,):
        raise InputError(f'"{TIMESTAMPS_KEY}" must be ({n_frames},) numbers, got {header.shape} '
                         f"{header.dtype}", path, fix)
    times = npz.read_array(path, TIMESTAMPS_KEY).astype(float)
    if not np.all(np.isfinite(times)):
        raise InputError(f'"{TIMESTAMPS_KEY}" holds non-finite values', path, fix)
    return times


def read_maniunicon(path: str | Path, *, joint_names: SequenceOf[str] | None = None,
                    intrinsics: IntrinsicsArg | None = None,
                    robot: str | None = None) -> Sequence:
    """Read a maniunicon `.npz` episode into a `Sequence` (images stay in the archive).

    Args:
        path: the `.npz` file, or a folder holding exactly one.
        joint_names: names of the first columns of `captured_joint_values`; default
            panda_joint1..7.
        intrinsics: a `CameraIntrinsics` or (fx, fy, cx, cy) in pixels; default: a side file.
        robot: robot name; default "panda".
    """
    npz_path = find_npz(Path(path))
    names = check_joint_names(joint_names, PANDA_ARM_JOINTS)
    robot = check_robot(robot, PANDA_ROBOT)
    stack = npz.read_header(npz_path, STACK_KEY)
    npz.check_rgb_stack(stack, STACK_KEY, npz_path)
    n_frames, height, width = stack.shape[:3]
    if n_frames == 0 or height == 0 or width == 0:
        raise InputError(f'"{STACK_KEY}" is empty (shape {stack.shape})', npz_path,
                         "store at least one image")
    joints = _joint_table(npz_path, n_frames, len(names))
    times = _timestamps(npz_path, n_frames)
    if intrinsics is not None:
        camera = camera_from_argument(intrinsics, width, height, npz_path)
    else:
        camera = _side_camera(npz_path, width, height)
    frames = [Frame(name=frame_name(i), joints=joints[i], image_path=npz_path, image_index=i,
                    timestamp=None if times is None else float(times[i]), source=npz_path)
              for i in range(n_frames)]
    sequence = Sequence(robot=robot, camera=camera, joint_names=names, keypoint_names=(),
                        frames=tuple(frames), source=npz_path)
    logger.info("read %d maniunicon frames from %s", n_frames, npz_path)
    return sequence
