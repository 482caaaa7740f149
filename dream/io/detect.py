"""Which supported layout a path holds."""

from __future__ import annotations

import os
from pathlib import Path

from dream.errors import InputError
from dream.io import fields
from dream.io.csv_layout import CSV_FILE
from dream.io.dream_layout.names import CAMERA_SETTINGS, FRAME_FILE
from dream.io.franka_offline import COLOR_DIR, QPOS_DIR
from dream.io.images import NPZ_SUFFIX
from dream.io.panda_teleop import INFO_FILE
from dream.io.rosbag import is_bag

DREAM = "dream"
PANDA_TELEOP = "panda_teleop"
FRANKA_OFFLINE = "franka_offline"
MANIUNICON = "maniunicon"
CSV = "csv"
ROSBAG = "rosbag"
FORMATS = (DREAM, PANDA_TELEOP, FRANKA_OFFLINE, MANIUNICON, CSV, ROSBAG)
LOOKED_FOR = (f"{CAMERA_SETTINGS} or NNNNNN.json frames (dream), {INFO_FILE} here or in one "
              f"sub-folder (panda_teleop), {QPOS_DIR}/ and {COLOR_DIR}/ folders "
              f"(franka_offline), an .npz file (maniunicon), {CSV_FILE} and images (csv), a ROS 1 "
              f".bag file or ROS 2 bag folder (rosbag)")


def _detect_file(path: Path) -> str | None:
    if path.suffix.lower() == NPZ_SUFFIX:
        return MANIUNICON
    if path.name == INFO_FILE:
        return PANDA_TELEOP
    if path.name == CSV_FILE:
        return CSV
    if path.name == CAMERA_SETTINGS or FRAME_FILE.match(path.name):
        return DREAM
    return None


def _detect_folder(path: Path) -> str | None:
    try:
        listing = set(os.listdir(path))
    except OSError as exc:
        raise InputError(f"cannot list the folder ({fields.os_reason(exc)})", path) from None
    if CAMERA_SETTINGS in listing:
        return DREAM
    if INFO_FILE in listing:
        return PANDA_TELEOP
    if (path / QPOS_DIR).is_dir() and (path / COLOR_DIR).is_dir():
        return FRANKA_OFFLINE
    if CSV_FILE in listing:
        return CSV
    if any(FRAME_FILE.match(name) for name in listing):
        return DREAM
    if sum(name.lower().endswith(NPZ_SUFFIX) for name in listing) == 1:
        return MANIUNICON
    if any((path / name / INFO_FILE).is_file() for name in listing):
        return PANDA_TELEOP
    return None


def detect_format(path: str | Path) -> str:
    """The layout at `path`: one of `FORMATS`; an unknown layout is an `InputError`."""
    path = Path(path)
    if not path.exists():
        raise InputError("does not exist", path, "check the recording's path (--data)")
    if is_bag(path):
        return ROSBAG
    found = _detect_file(path) if path.is_file() else _detect_folder(path)
    if found is None:
        raise InputError(f"is not a known dataset layout; looked for {LOOKED_FOR}", path,
                         "point --data at a supported dataset or give its format")
    return found
