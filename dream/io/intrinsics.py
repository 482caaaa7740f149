"""Camera intrinsics from the places the readers find them: an argument, `K.txt`, a JSON file.

The `intrinsics` argument of the readers is either a full `CameraIntrinsics` or the four numbers
(fx, fy, cx, cy) in pixels, optionally followed by the five plumb_bob coefficients; the image
size then comes from the images. A full `CameraIntrinsics` must have the images' size.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Union

import numpy as np

from dream.camera import PLUMB_BOB, CameraIntrinsics
from dream.errors import InputError
from dream.io import fields

IntrinsicsArg = Union[CameraIntrinsics, Sequence[float]]  # noqa: UP007 (a runtime alias)

PINHOLE_PARAMS = ("fx", "fy", "cx", "cy")
DISTORTION_SIZES = (4, 5)  # (k1, k2, p1, p2) or (k1, k2, p1, p2, k3)
K_ROWS = 3
K_LAST_ROW = (0.0, 0.0, 1.0)
K_TOLERANCE = 1e-9
FIX_ARGUMENT = "pass --intrinsics fx,fy,cx,cy (pixels)"
FIX_K_TXT = "write K.txt as the 3x3 camera matrix, three numbers a line"


def parse_intrinsics_text(text: str, what: str = "intrinsics"
                          ) -> tuple[float, float, float, float]:
    """"fx,fy,cx,cy" (pixels) -> a tuple to pass as the readers' `intrinsics` argument;
    `what` names the text's origin in messages (e.g. the command-line option)."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != len(PINHOLE_PARAMS):
        raise InputError(f"{what} {fields.quote(text)} must be four comma-separated "
                         f"numbers", fix=FIX_ARGUMENT)
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise InputError(f"{what} {fields.quote(text)} must be four comma-separated "
                         f"numbers", fix=FIX_ARGUMENT) from None
    for name, value in zip(PINHOLE_PARAMS, values, strict=True):
        if not np.isfinite(value):
            raise InputError(f"{what} {fields.quote(text)}: {name} = {value} is not a "
                             "finite number", fix=FIX_ARGUMENT)
    fx, fy, cx, cy = values
    if fx <= 0 or fy <= 0:
        raise InputError(f"{what} {fields.quote(text)}: focal lengths must be positive, "
                         f"got fx={fx:g}, fy={fy:g}", fix=FIX_ARGUMENT)
    return fx, fy, cx, cy


def camera_from_argument(arg: IntrinsicsArg, width: int, height: int,
                         where: Path | None) -> CameraIntrinsics:
    """A `CameraIntrinsics` from the readers' `intrinsics` argument for images of this size."""
    if isinstance(arg, CameraIntrinsics):
        if (arg.width, arg.height) != (width, height):
            raise InputError(f"the given intrinsics are for {arg.width}x{arg.height} images but "
                             f"the images are {width}x{height}", where,
                             "give intrinsics for the images' resolution")
        return arg
    if isinstance(arg, (str, bytes)):
        raise InputError("intrinsics must be numbers, not text", where,
                         "parse the text with parse_intrinsics_text first")
    try:
        values = [float(v) for v in arg]
    except (TypeError, ValueError):
        raise InputError(f"intrinsics must be (fx, fy, cx, cy), got {arg!r}", where,
                         FIX_ARGUMENT) from None
    n = len(PINHOLE_PARAMS)
    if len(values) not in (n, n + max(DISTORTION_SIZES)):
        raise InputError(f"intrinsics must be four numbers (fx, fy, cx, cy), optionally with "
                         f"five distortion coefficients, got {len(values)}", where, FIX_ARGUMENT)
    distortion = tuple(values[n:]) or None
    with fields.errors_name(where, FIX_ARGUMENT):
        return CameraIntrinsics(*values[:n], width=width, height=height, distortion=distortion)


def camera_from_K(K: np.ndarray, width: int, height: int, path: Path,
                  distortion: tuple[float, ...] | None = None,
                  fix: str | None = None) -> CameraIntrinsics:
    """A camera from a 3x3 matrix K (last row 0 0 1, no skew), checked, naming `path`."""
    if not np.allclose(K[2], K_LAST_ROW, atol=K_TOLERANCE):
        transposed = np.allclose(K[:, 2], K_LAST_ROW, atol=K_TOLERANCE)
        raise InputError(f"camera matrix K has last row {K[2].tolist()}, expected [0, 0, 1]"
                         f"{' (it is transposed: its last column is)' if transposed else ''}",
                         path, fix or ("write K row by row: fx 0 cx / 0 fy cy / 0 0 1"))
    with fields.errors_name(path, fix):
        return CameraIntrinsics.from_K(K, width, height, distortion)


def read_K_txt(path: Path) -> np.ndarray:
    """The 3x3 camera matrix of a whitespace-separated text file."""
    text = fields.read_text(path, FIX_K_TXT)
    return fields.parse_numbers(text, path, count=K_ROWS * K_ROWS,
                                fix=FIX_K_TXT).reshape(K_ROWS, K_ROWS)


def parse_distortion(value: Any, what: str, path: Path) -> tuple[float, ...] | None:
    """Distortion as `{"model": "plumb_bob", "coeffs": [...]}` or a bare coefficient list."""
    fix = 'write {"model": "plumb_bob", "coeffs": [k1, k2, p1, p2, k3]}'
    if value is None:
        return None
    if isinstance(value, dict):
        model = value.get("model", PLUMB_BOB)
        if model != PLUMB_BOB:
            raise InputError(f"{what}.model {fields.describe(model)} is not supported (only "
                             f'"{PLUMB_BOB}")',
                             path, fix)
        value = fields.require(value, "coeffs", f"{what}.coeffs", path, fix)
    items = fields.as_list(value, what, path, fix)
    if len(items) not in DISTORTION_SIZES:
        raise InputError(f"{what} has {len(items)} coefficients, expected 4 or 5", path, fix)
    return tuple(fields.as_number(v, f"{what}[{i}]", path, fix) for i, v in enumerate(items))


def read_intrinsics_json(path: Path, width: int, height: int) -> CameraIntrinsics:
    """A side file `{"fx", "fy", "cx", "cy" [, "distortion"] [, "width", "height"]}`."""
    fix = 'write {"fx": ..., "fy": ..., "cx": ..., "cy": ...} in pixels'
    data = fields.as_dict(fields.load_json(path, fix), "the file", path, fix)
    values = [fields.as_number(fields.require(data, k, f'"{k}"', path, fix), f'"{k}"', path, fix)
              for k in PINHOLE_PARAMS]
    for key, actual in (("width", width), ("height", height)):
        if key in data and fields.as_int(data[key], f'"{key}"', path, fix) != actual:
            raise InputError(f'"{key}" is {data[key]} but the images are {width}x{height}',
                             path, "give intrinsics for the images' resolution")
    distortion = parse_distortion(data.get("distortion"), '"distortion"', path)
    with fields.errors_name(path, fix):
        return CameraIntrinsics(*values, width=width, height=height, distortion=distortion)
