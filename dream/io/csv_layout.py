"""The images + CSV layout: a folder of images and `joints.csv` (docs/data_format.md#images--csv).

`joints.csv` has a header row. Its columns: `image` (optional: the image file, relative to the
folder), `timestamp` (optional: capture time, s) and one column per joint, named after the
URDF's joints, in radians (prismatic joints in metres); one row per image. Without an `image`
column the folder's images (`.png`, `.jpg`, `.jpeg`), sorted by name with numbers by value
(frame_2 before frame_10), go with the rows in order. Another spelling of the two known columns
(`Image`, `image_path`, `time`, `timestamps`, `header.stamp`...) is refused rather than taken
for a joint, and so are a first line of numbers (no header) and timestamps that cannot be
seconds (nanoseconds...). The camera: `camera_info.yaml` (ROS CameraInfo,
`dream.io.camera_info`) or `K.txt` in the folder, or `--intrinsics` / `--camera-info`. Frames
are named "000000"... in row order (in time order when the timestamps say another).
"""

from __future__ import annotations

import csv
import io
import logging
import math
import re
from collections.abc import Sequence as SequenceOf
from pathlib import Path

import numpy as np

from dream.errors import InputError
from dream.io import fields
from dream.io.camera_info import read_camera_info
from dream.io.common import (
    PANDA_ROBOT,
    check_joint_names,
    check_robot,
    common_image_size,
    frame_name,
)
from dream.io.intrinsics import IntrinsicsArg, camera_from_argument, camera_from_K, read_K_txt
from dream.plausibility import check_seconds
from dream.sequence import Frame, Sequence

logger = logging.getLogger(__name__)

CSV_FILE = "joints.csv"
CAMERA_INFO_FILE = "camera_info.yaml"
K_FILE = "K.txt"
IMAGE_COLUMN = "image"
TIME_COLUMN = "timestamp"
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")
# other names of the two known columns, refused so that neither passes as an unused joint
TIME_ALIASES = ("time", "stamp", "t", "time_s", "timestamp_s", "stamp_s", "time_ns",
                "timestamp_ns", "stamp_ns", "secs", "seconds")
# and any name with a time word and unit suffixes (`timestamps`, `ts`, `time_sec`,
# `header.stamp`, `rosbag_time`)
TIME_LIKE = re.compile(r"(?:^|[._])(?:time(?:stamp)?s?|stamps?|ts|secs?|nsecs?)(?:$|[._])")
IMAGE_ALIASES = ("image_path", "image_file", "images", "img", "filename", "file", "path",
                 "rgb", "color", "colour")
FIX_CSV = (f"write {CSV_FILE} with a header row: [image,] [timestamp,] then one column per "
           "joint (the URDF's joint names), radians, one row per image")


def _rows(path: Path) -> tuple[list[str], list[list[str]]]:
    text = fields.read_text(path, FIX_CSV)
    first = text.split("\n", 1)[0]
    if first.count(";") > first.count(","):
        raise InputError("its values are separated by ';', not commas (a spreadsheet's "
                         "locale?)", path, "save it as CSV with commas between values and '.' "
                         "as the decimal point")
    rows = [row for row in csv.reader(io.StringIO(text)) if any(c.strip() for c in row)]
    if len(rows) < 2:
        raise InputError("needs a header row and at least one row of readings", path, FIX_CSV)
    header = [c.strip() for c in rows[0]]
    if len(set(header)) != len(header) or not all(header):
        raise InputError(f"the header repeats or leaves out a column name: {rows[0]}", path,
                         FIX_CSV)
    for i, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise InputError(f"line {i} has {len(row)} values, the header {len(header)}", path,
                             FIX_CSV)
    return header, [[c.strip() for c in row] for row in rows[1:]]


def _number(text: str, what: str, path: Path) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise InputError(f"{what} is {fields.quote(text)}, not a finite number", path,
                         "give every joint a reading (radians) and the timestamp in seconds "
                         "in every row, or drop the row and its image")
    return value


def _images(folder: Path, header: list[str], rows: list[list[str]], path: Path) -> list[Path]:
    if IMAGE_COLUMN in header:
        column = header.index(IMAGE_COLUMN)
        images = [folder / row[column] for row in rows]
        for i, image in enumerate(images, start=2):
            if not image.is_file():
                raise InputError(f"line {i}: image {fields.quote(image.name)} not found in "
                                 f"{folder}", path, "add the image or remove the row")
        return images
    images = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS),
                    key=lambda p: natural_key(p.name))
    if len(images) != len(rows):
        raise InputError(f"{len(rows)} rows of readings but {len(images)} images in the folder",
                         path, f"add an '{IMAGE_COLUMN}' column naming each row's image, or "
                         "keep one image per row")
    return images


def natural_key(name: str) -> tuple:
    """Sort key of a file name that orders its numbers by value (frame_2 before frame_10).

    >>> sorted(["f_10.png", "f_2.png", "f_1.png"], key=natural_key)
    ['f_1.png', 'f_2.png', 'f_10.png']
    """
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part)
                 for part in re.split(r"(\d+)", name))


def _check_column_names(header: list[str], path: Path) -> None:
    """Refuse a header of numbers (no header row) and another spelling of `image` or
    `timestamp` (module doc)."""
    if sum(_is_number(c) for c in header) * 2 > len(header):
        raise InputError(f"its first line holds numbers ({', '.join(header[:3])}...), not the "
                         "column names", path, FIX_CSV)
    for column in header:
        known = column.lower()
        if known == IMAGE_COLUMN and column != IMAGE_COLUMN:
            raise InputError(f"column {fields.quote(column)}: the image column is called "
                             f"{fields.quote(IMAGE_COLUMN)}", path, f"rename it to {IMAGE_COLUMN}")
        if (known in IMAGE_ALIASES or known.startswith(f"{IMAGE_COLUMN}_")) \
                and column != IMAGE_COLUMN:
            raise InputError(f"column {fields.quote(column)} looks like the image column, which "
                             f"is called {fields.quote(IMAGE_COLUMN)}", path,
                             f"rename it to {IMAGE_COLUMN}")
        if (known == TIME_COLUMN or known in TIME_ALIASES or TIME_LIKE.search(known)) \
                and column != TIME_COLUMN:
            raise InputError(f"column {fields.quote(column)} looks like a time; the time column "
                             f"is called {fields.quote(TIME_COLUMN)}, in seconds", path,
                             f"rename it to {TIME_COLUMN} (in seconds), or remove it")


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _warn_repeated_times(times: list[float], joints: np.ndarray, path: Path) -> None:
    """Log the first two rows stamped alike with other joint readings (a log's clock that
    stood still, or rows copied in twice): the frames' order in time is then a guess."""
    first: dict[float, int] = {}
    for i, t in enumerate(times):
        j = first.setdefault(t, i)
        if j != i and not np.array_equal(joints[i], joints[j]):
            logger.warning("%s: lines %d and %d share the timestamp %r but not the joint "
                           "readings; check the log's clock", path, j + 2, i + 2, t)
            return


def _camera(folder: Path, intrinsics: IntrinsicsArg | None, width: int, height: int):
    if intrinsics is not None:      # given on the command line: no file of the folder to name
        return camera_from_argument(intrinsics, width, height, None)
    if (folder / CAMERA_INFO_FILE).is_file():
        camera = read_camera_info(folder / CAMERA_INFO_FILE)
        return camera_from_argument(camera, width, height, folder / CAMERA_INFO_FILE)
    if (folder / K_FILE).is_file():
        return camera_from_K(read_K_txt(folder / K_FILE), width, height, folder / K_FILE)
    raise InputError(f"has no camera: neither {CAMERA_INFO_FILE} nor {K_FILE}", folder,
                     f"add {CAMERA_INFO_FILE} (ROS CameraInfo) or {K_FILE}, or pass "
                     "--camera-info FILE or --intrinsics fx,fy,cx,cy")


def read_csv_layout(path: str | Path, *, joint_names: SequenceOf[str] | None = None,
                    intrinsics: IntrinsicsArg | None = None,
                    robot: str | None = None) -> Sequence:
    """Read a folder of images and `joints.csv` (module doc) into a `Sequence`.

    Args:
        path: the folder, or its `joints.csv`.
        joint_names: the joint columns to keep, in this order; default every column that is
            neither `image` nor `timestamp`.
        intrinsics: replaces the folder's camera when given.
        robot: robot name; default "panda".
    """
    path = Path(path)
    folder = path.parent if path.name == CSV_FILE else path
    csv_path = folder / CSV_FILE
    header, rows = _rows(csv_path)
    _check_column_names(header, csv_path)
    columns = [c for c in header if c not in (IMAGE_COLUMN, TIME_COLUMN)]
    names = check_joint_names(joint_names, tuple(columns))
    missing = [n for n in names if n not in header]
    if missing or not names:
        raise InputError(f"has no column for joints {', '.join(missing) or '(none)'}", csv_path,
                         FIX_CSV)
    index = [header.index(n) for n in names]
    joints = np.array([[_number(row[j], f"line {i} {header[j]}", csv_path) for j in index]
                       for i, row in enumerate(rows, start=2)])
    times = None
    if TIME_COLUMN in header:
        t = header.index(TIME_COLUMN)
        times = [_number(row[t], f"line {i} {TIME_COLUMN}", csv_path)
                 for i, row in enumerate(rows, start=2)]
        check_seconds(times, csv_path)
        _warn_repeated_times(times, joints, csv_path)
    images = _images(folder, header, rows, csv_path)
    order = np.argsort(times, kind="stable") if times is not None else np.arange(len(rows))
    width, height = common_image_size(images)
    camera = _camera(folder, intrinsics, width, height)
    frames = tuple(Frame(name=frame_name(k), joints=joints[i], image_path=images[i],
                         timestamp=None if times is None else times[i], source=csv_path)
                   for k, i in enumerate(order))
    logger.info("read %d frames of images + %s from %s", len(frames), CSV_FILE, folder)
    return Sequence(robot=check_robot(robot, PANDA_ROBOT), camera=camera, joint_names=names,
                    keypoint_names=(), frames=frames, source=folder)
