"""Small helpers shared by the readers: default names, argument checks, image checks."""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.io.images import check_size, image_size

PANDA_ROBOT = "panda"
PANDA_ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
FRAME_DIGITS = 6
CACHE_ENV = "DREAM_CACHE_DIR"
DEFAULT_CACHE_ROOT = Path("~/.cache/dream")


def cache_folder(name: str) -> Path:
    """`$DREAM_CACHE_DIR/NAME`, or `~/.cache/dream/NAME`: where the project keeps what it can
    rebuild (compiled scenes, a bag's decoded images)."""
    base = os.environ.get(CACHE_ENV)
    return (Path(base) if base else DEFAULT_CACHE_ROOT).expanduser() / name


def frame_name(index: int) -> str:
    """The name of the frame at `index`: six digits, "000000" first."""
    return f"{index:0{FRAME_DIGITS}d}"


def check_joint_names(joint_names: Sequence[str] | None,
                      default: tuple[str, ...] | None) -> tuple[str, ...] | None:
    """The `joint_names` argument as a tuple of distinct non-empty names, else `default`."""
    if joint_names is None:
        return default
    fix = "give the joint names as a list of distinct strings, e.g. panda_joint1 ... panda_joint7"
    if isinstance(joint_names, (str, bytes)):
        raise InputError(f"joint_names must be a list of names, got the text {joint_names!r}",
                         fix=fix)
    names = tuple(joint_names)
    if not names or not all(isinstance(n, str) and n for n in names):
        raise InputError(f"joint_names must be non-empty strings, got {names!r}", fix=fix)
    if len(set(names)) != len(names):
        raise InputError(f"joint_names repeats a name: {', '.join(names)}", fix=fix)
    return names


def check_robot(robot: str | None, default: str | None) -> str | None:
    """The `robot` argument if given (a non-empty string), else `default`."""
    if robot is None:
        return default
    if not isinstance(robot, str) or not robot:
        raise InputError(f"robot must be a robot name or a URDF path, got {robot!r}",
                         fix="pass a built-in robot name (dream robots) or a URDF path")
    return robot


def common_image_size(paths: Iterable[Path]) -> tuple[int, int] | None:
    """The (width, height) shared by all image files (headers only); None when there are none.

    A missing file, an unreadable header or a size different from the first image's is an
    `InputError` naming that file.
    """
    size: tuple[int, int] | None = None
    first: Path | None = None
    for path in paths:
        this = image_size(path)
        if size is None:
            size, first = this, path
        elif this != size:
            raise InputError(f"image is {this[0]}x{this[1]} but {first.name} is "
                             f"{size[0]}x{size[1]}", path,
                             "use images of one resolution in a sequence")
    return size


def check_images_match(paths: Iterable[Path], camera: CameraIntrinsics) -> None:
    """Every image file is camera.width x camera.height (headers only)."""
    for path in paths:
        check_size(*image_size(path), camera, path)
