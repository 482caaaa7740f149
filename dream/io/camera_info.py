"""A camera from ROS's CameraInfo YAML: `camera_calibration`'s file or a `CameraInfo` message.

Two forms are read:

- the file `camera_calibration` and `camera_info_manager` write: `image_width`,
  `image_height`, `camera_matrix: {rows: 3, cols: 3, data: [9]}`, `distortion_model`,
  `distortion_coefficients: {data: [...]}`;
- a `sensor_msgs/CameraInfo` message as `ros2 topic echo` (`width`, `height`, `k`, `d`,
  `distortion_model`) or ROS 1's `rostopic echo` (`K`, `D`) print it (each message followed
  by `---`: the first message is read).

Only the `plumb_bob` model is supported (OpenCV's k1, k2, p1, p2, k3), and `rational_polynomial`
whose coefficients beyond the fifth are zero.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dream.camera import PLUMB_BOB, CameraIntrinsics
from dream.errors import InputError
from dream.io import fields
from dream.io.intrinsics import camera_from_K

RATIONAL = "rational_polynomial"
PLUMB_BOB_SIZE = 5
FIX_CAMERA_INFO = ("give the YAML that camera_calibration writes (image_width, image_height, "
                   "camera_matrix, distortion_model, distortion_coefficients) or a CameraInfo "
                   "message (width, height, k, d)")


def _load_yaml(path: Path) -> dict[str, Any]:
    import yaml

    text = fields.read_text(path, FIX_CAMERA_INFO)
    try:   # an echoed topic: messages each followed by `---`; the first is taken
        documents = [d for d in yaml.safe_load_all(text) if d is not None]
    except yaml.YAMLError as exc:
        raise InputError(f"not valid YAML ({fields.one_line(exc)})", path,
                         FIX_CAMERA_INFO) from None
    data = documents[0] if documents else None
    return fields.as_dict(data, "the file", path, FIX_CAMERA_INFO)


def _matrix_data(value: Any, what: str, path: Path) -> list[Any]:
    """`{rows, cols, data}` (camera_calibration) or a bare list (a message)."""
    if isinstance(value, dict):
        value = fields.require(value, "data", f"{what}.data", path, FIX_CAMERA_INFO)
    return fields.as_list(value, what, path, FIX_CAMERA_INFO)


def _distortion(model: Any, coeffs: list[Any], path: Path) -> tuple[float, ...] | None:
    values = [fields.as_number(c, f"distortion[{i}]", path, FIX_CAMERA_INFO)
              for i, c in enumerate(coeffs)]
    if not values or not any(values):
        return None
    if model == RATIONAL and not any(values[PLUMB_BOB_SIZE:]):
        values = values[:PLUMB_BOB_SIZE]
    elif model != PLUMB_BOB:
        raise InputError(f"distortion_model {fields.describe(model)} is not supported (only "
                         f"{PLUMB_BOB}, or {RATIONAL} with k4-k6 zero)", path,
                         "calibrate the camera with the plumb_bob model")
    if len(values) not in (4, PLUMB_BOB_SIZE):
        raise InputError(f"{PLUMB_BOB} distortion has {len(values)} coefficients, expected 4 "
                         "or 5 (k1, k2, p1, p2[, k3])", path, FIX_CAMERA_INFO)
    return tuple(values + [0.0] * (PLUMB_BOB_SIZE - len(values)))


def read_camera_info(path: str | Path) -> CameraIntrinsics:
    """The camera of a CameraInfo YAML (module doc).

    Raises:
        InputError: unreadable file, missing fields, a K that is not a camera matrix, or an
            unsupported distortion model, naming the file and the fix.
    """
    path = Path(path)
    data = _load_yaml(path)
    if "camera_matrix" in data:
        keys = ("image_width", "image_height", "camera_matrix", "distortion_coefficients")
    else:
        upper = "K" in data and "k" not in data
        keys = ("width", "height", "K" if upper else "k", "D" if upper else "d")
    w_key, h_key, k_key, d_key = keys
    width = fields.as_int(fields.require(data, w_key, w_key, path, FIX_CAMERA_INFO), w_key, path,
                          FIX_CAMERA_INFO)
    height = fields.as_int(fields.require(data, h_key, h_key, path, FIX_CAMERA_INFO), h_key,
                           path, FIX_CAMERA_INFO)
    k = _matrix_data(fields.require(data, k_key, k_key, path, FIX_CAMERA_INFO), k_key, path)
    K = np.array([fields.as_number(v, f"{k_key}[{i}]", path, FIX_CAMERA_INFO)
                  for i, v in enumerate(k)])
    if K.size != 9:
        raise InputError(f"{k_key} has {K.size} numbers, expected 9 (3x3, row-major)", path,
                         FIX_CAMERA_INFO)
    coeffs = _matrix_data(data.get(d_key) or [], d_key, path)
    distortion = _distortion(data.get("distortion_model", PLUMB_BOB), coeffs, path)
    return camera_from_K(K.reshape(3, 3), width, height, path, distortion, FIX_CAMERA_INFO)


def camera_info_text(camera: CameraIntrinsics, name: str = "camera") -> str:
    """`camera`, as the YAML camera_calibration writes (what `read_camera_info` reads back)."""
    K = camera.K.reshape(-1).tolist()
    D = list(camera.distortion or (0.0,) * PLUMB_BOB_SIZE)
    P = [camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return (f"image_width: {camera.width}\nimage_height: {camera.height}\n"
            f"camera_name: {name}\n"
            f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: {K!r}\n"
            f"distortion_model: {PLUMB_BOB}\n"
            f"distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: {D!r}\n"
            f"rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
            f"projection_matrix:\n  rows: 3\n  cols: 4\n  data: {P!r}\n")
