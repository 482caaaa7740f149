"""`read_sequence`: read any supported layout into a `Sequence`."""

from __future__ import annotations

import logging
from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from pathlib import Path

from dream.errors import InputError
from dream.io.csv_layout import read_csv_layout
from dream.io.detect import (
    CSV,
    DREAM,
    FORMATS,
    FRANKA_OFFLINE,
    MANIUNICON,
    PANDA_TELEOP,
    ROSBAG,
    detect_format,
)
from dream.io.dream_layout.read import read_dream
from dream.io.franka_offline import read_franka_offline
from dream.io.intrinsics import IntrinsicsArg
from dream.io.maniunicon import read_maniunicon
from dream.io.panda_teleop import read_panda_teleop
from dream.io.rosbag import BagTopics, read_rosbag
from dream.sequence import Sequence

logger = logging.getLogger(__name__)

READERS: dict[str, Callable[..., Sequence]] = {
    DREAM: read_dream,
    PANDA_TELEOP: read_panda_teleop,
    FRANKA_OFFLINE: read_franka_offline,
    MANIUNICON: read_maniunicon,
    CSV: read_csv_layout,
    ROSBAG: read_rosbag,
}


def read_sequence(path: str | Path, *, fmt: str | None = None,
                  joint_names: SequenceOf[str] | None = None,
                  intrinsics: IntrinsicsArg | None = None,
                  robot: str | None = None, topics: BagTopics | None = None) -> Sequence:
    """Read the dataset at `path` into a `Sequence`.

    Args:
        path: a dataset folder or file of one of the layouts in `FORMATS`.
        fmt: the layout; detected from the path when None.
        joint_names: names of the joint columns (panda_teleop, franka_offline, maniunicon;
            default panda_joint1..7) or the joints to keep (dream; default all of the file's).
        intrinsics: a `CameraIntrinsics`, or (fx, fy, cx, cy) in pixels with the size taken from
            the images; replaces the dataset's own intrinsics (required for maniunicon without a
            side file).
        robot: robot name or URDF path; default from the data (dream) or "panda".
        topics: the image, joint state and camera info topics of a ROS bag (default: found by
            their message types); refused for the other layouts.

    Raises:
        InputError: for any missing, unreadable or malformed input, naming the file and the fix.
    """
    path = Path(path)
    if fmt is None:
        fmt = detect_format(path)
        logger.debug("%s: detected the %s layout", path, fmt)
    elif fmt not in READERS:
        raise InputError(f"unknown format {fmt!r}", path, f"use one of {', '.join(FORMATS)}")
    if fmt == ROSBAG:
        return read_rosbag(path, joint_names=joint_names, intrinsics=intrinsics, robot=robot,
                           topics=topics)
    if topics is not None and topics != BagTopics():
        raise InputError(f"topics are for ROS bags, and this is the {fmt} layout", path,
                         "drop --image-topic, --joint-topic and --camera-info-topic")
    return READERS[fmt](path, joint_names=joint_names, intrinsics=intrinsics, robot=robot)
