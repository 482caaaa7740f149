"""The franka_offline layout (docs/data_format.md#franka_offline).

`K.txt` (3x3 camera matrix), `color/NNNNNN.png` photos, `mask/NNNNNN.png` robot masks (optional)
and `qpos/NNNNNN.txt` (the seven arm joints in radians, then two finger values, one a line).
Only the arm joints are kept. There is no reference extrinsic.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Sequence as SequenceOf
from pathlib import Path

from dream.errors import InputError
from dream.io import fields
from dream.io.common import (
    PANDA_ARM_JOINTS,
    PANDA_ROBOT,
    check_joint_names,
    check_robot,
    common_image_size,
)
from dream.io.intrinsics import (
    FIX_K_TXT,
    IntrinsicsArg,
    camera_from_argument,
    camera_from_K,
    read_K_txt,
)
from dream.sequence import Frame, Sequence

logger = logging.getLogger(__name__)

K_FILE = "K.txt"
COLOR_DIR = "color"
MASK_DIR = "mask"
QPOS_DIR = "qpos"
NUMBERED = re.compile(r"^(\d+)\.(png|jpg|jpeg|txt)$", re.IGNORECASE)
IMAGE_EXTENSIONS = ("png", "jpg", "jpeg")


def _numbered_files(folder: Path, extensions: tuple[str, ...]) -> dict[str, Path]:
    """stem -> file for the `NNNNNN.ext` files of a folder ({} when the folder is absent)."""
    if not folder.is_dir():
        return {}
    try:
        names = os.listdir(folder)
    except OSError as exc:
        raise InputError(f"cannot list the folder ({fields.os_reason(exc)})", folder) from None
    out: dict[str, Path] = {}
    for name in sorted(names):
        match = NUMBERED.match(name)
        if match and match.group(2).lower() in extensions and match.group(1) not in out:
            out[match.group(1)] = folder / name
    return out


def _pair_files(root: Path) -> tuple[list[str], dict[str, Path], dict[str, Path],
                                     dict[str, Path]]:
    qpos = _numbered_files(root / QPOS_DIR, ("txt",))
    color = _numbered_files(root / COLOR_DIR, IMAGE_EXTENSIONS)
    mask = _numbered_files(root / MASK_DIR, IMAGE_EXTENSIONS)
    if not qpos:
        raise InputError(f"holds no {QPOS_DIR}/NNNNNN.txt joint files", root,
                         "point at a franka_offline folder (K.txt, color/, qpos/)")
    for stem, image in color.items():
        if stem not in qpos:
            raise InputError(f"image has no joint file {QPOS_DIR}/{stem}.txt", image,
                             "add the joint file or remove the image")
    for stem, joints in qpos.items():
        if stem not in color:
            raise InputError(f"joint file has no image {COLOR_DIR}/{stem}.png", joints,
                             "add the image or remove the joint file")
    stems = sorted(qpos, key=lambda s: (int(s), s))
    return stems, qpos, color, mask


def read_franka_offline(path: str | Path, *, joint_names: SequenceOf[str] | None = None,
                        intrinsics: IntrinsicsArg | None = None,
                        robot: str | None = None) -> Sequence:
    """Read a franka_offline folder into a `Sequence` (no reference extrinsic).

    Args:
        path: the folder holding K.txt, color/, mask/ and qpos/.
        joint_names: names of the first columns of each qpos file to keep; default
            panda_joint1..7 (the finger values that follow are dropped).
        intrinsics: replaces K.txt when given.
        robot: robot name; default "panda".
    """
    root = Path(path)
    if not root.is_dir():
        raise InputError("is not a folder", root, "point at the franka_offline folder")
    names = check_joint_names(joint_names, PANDA_ARM_JOINTS)
    robot = check_robot(robot, PANDA_ROBOT)
    stems, qpos, color, mask = _pair_files(root)
    width, height = common_image_size(color[s] for s in stems)
    k_path = root / K_FILE
    if intrinsics is not None:
        camera = camera_from_argument(intrinsics, width, height, k_path)
    else:
        camera = camera_from_K(read_K_txt(k_path), width, height, k_path, fix=FIX_K_TXT)
    common_image_size([color[stems[0]]] + [mask[s] for s in stems if s in mask])
    frames = []
    for stem in stems:
        fix = f"write at least {len(names)} joint values (rad), one a line"
        values = fields.parse_numbers(fields.read_text(qpos[stem], fix), qpos[stem],
                                      minimum=len(names), fix=fix)
        frames.append(Frame(name=stem, joints=values[: len(names)], image_path=color[stem],
                            mask_path=mask.get(stem), source=qpos[stem]))
    missing = [s for s in stems if s not in mask]
    if mask and missing:
        logger.warning("%s: %d frames have no mask (%s...)", root, len(missing), missing[0])
    sequence = Sequence(robot=robot, camera=camera, joint_names=names, keypoint_names=(),
                        frames=tuple(frames), source=root)
    logger.info("read %d franka_offline frames from %s", len(frames), root)
    return sequence
