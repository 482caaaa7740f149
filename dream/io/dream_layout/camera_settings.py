"""`_camera_settings.json` of the DREAM layout: the camera record, read and written.

One camera (the first of `camera_settings`): `intrinsic_settings` {fx, fy, cx, cy, s = 0}, the
image size (`captured_image_size` and / or `intrinsic_settings.resolution`), and the extensions
`distortion` (plumb_bob) and `reference_T_cam_base` (4x4, metres).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dream.camera import PLUMB_BOB, CameraIntrinsics
from dream.errors import InputError
from dream.io import fields
from dream.io.dream_layout.names import DEFAULT_CAMERA_NAME, FIX_CAMERA, REFERENCE_KEY
from dream.io.intrinsics import parse_distortion
from dream.sequence import Sequence
from dream.transforms import is_rigid

logger = logging.getLogger(__name__)

RIGID_ATOL = 1e-4  # tolerance of a written 4x4 pose's rotation block being orthonormal


@dataclass(frozen=True)
class CameraSettings:
    """What `_camera_settings.json` says: intrinsics, camera name, optional reference pose."""

    camera: CameraIntrinsics
    name: str
    T_cam_base_reference: np.ndarray | None


def _image_size_entry(entry: dict[str, Any], path: Path) -> tuple[int, int]:
    intrinsic = entry["intrinsic_settings"]
    sizes = {}
    for what, holder, key in (("captured_image_size", entry, "captured_image_size"),
                              ("intrinsic_settings.resolution", intrinsic, "resolution")):
        if key in holder:
            size = fields.as_dict(holder[key], what, path, FIX_CAMERA)
            sizes[what] = tuple(
                fields.as_int(fields.require(size, k, f"{what}.{k}", path, FIX_CAMERA),
                              f"{what}.{k}", path, FIX_CAMERA, minimum=1)
                for k in ("width", "height"))
    if not sizes:
        raise InputError("camera_settings[0] gives no image size (captured_image_size or "
                         "intrinsic_settings.resolution)", path, FIX_CAMERA)
    values = list(sizes.values())
    if len(values) > 1 and values[0] != values[1]:
        logger.warning("%s: captured_image_size %s differs from resolution %s; using the "
                       "captured size", path, values[0], values[1])
    width, height = values[0]
    return width, height


def _parse_reference(value: Any, path: Path) -> np.ndarray:
    what = f"camera_settings[0].{REFERENCE_KEY}"
    T = fields.as_matrix(value, what, path, 4, 4, "write a 4x4 rigid transform (metres)")
    if not is_rigid(T, atol=RIGID_ATOL):
        raise InputError(f"{what} is not a rigid transform", path,
                         "write a rotation block with orthonormal rows and a last row 0 0 0 1")
    return T


def parse_camera_settings(data: Any, path: Path) -> CameraSettings:
    """Check and convert the content of a `_camera_settings.json`."""
    data = fields.as_dict(data, "the file", path, FIX_CAMERA)
    cameras = fields.as_list(fields.require(data, "camera_settings", '"camera_settings"', path,
                                            FIX_CAMERA), '"camera_settings"', path, FIX_CAMERA)
    if not cameras:
        raise InputError('"camera_settings" is empty', path, FIX_CAMERA)
    if len(cameras) > 1:
        logger.warning("%s: %d cameras listed; using the first", path, len(cameras))
    entry = fields.as_dict(cameras[0], "camera_settings[0]", path, FIX_CAMERA)
    intrinsic = fields.as_dict(fields.require(entry, "intrinsic_settings",
                                              "camera_settings[0].intrinsic_settings", path,
                                              FIX_CAMERA),
                               "camera_settings[0].intrinsic_settings", path, FIX_CAMERA)
    values = {}
    for key in ("fx", "fy", "cx", "cy"):
        what = f"intrinsic_settings.{key}"
        values[key] = fields.as_number(fields.require(intrinsic, key, what, path, FIX_CAMERA),
                                       what, path, FIX_CAMERA)
    skew = fields.as_number(intrinsic.get("s", 0), "intrinsic_settings.s", path, FIX_CAMERA)
    if skew != 0:
        raise InputError(f"intrinsic_settings.s (skew) is {skew}; only 0 is supported", path,
                         "write s: 0")
    width, height = _image_size_entry(entry, path)
    distortion = parse_distortion(entry.get("distortion"), "camera_settings[0].distortion", path)
    with fields.errors_name(path, FIX_CAMERA):
        camera = CameraIntrinsics(values["fx"], values["fy"], values["cx"], values["cy"],
                                  width, height, distortion)
    name = entry.get("name")
    reference = entry.get(REFERENCE_KEY)
    return CameraSettings(camera, name if isinstance(name, str) and name else DEFAULT_CAMERA_NAME,
                          None if reference is None else _parse_reference(reference, path))


def read_camera_settings(path: Path) -> CameraSettings:
    """Read and check a `_camera_settings.json`."""
    return parse_camera_settings(fields.load_json(path, FIX_CAMERA), path)


def camera_settings_json(sequence: Sequence) -> dict[str, Any]:
    """The `_camera_settings.json` content of a sequence."""
    cam = sequence.camera
    size = {"width": cam.width, "height": cam.height}
    entry: dict[str, Any] = {
        "name": sequence.camera_name,
        "intrinsic_settings": {"fx": float(cam.fx), "fy": float(cam.fy), "cx": float(cam.cx),
                               "cy": float(cam.cy), "s": 0, "resolution": dict(size)},
        "captured_image_size": dict(size),
    }
    if cam.distortion is not None:
        entry["distortion"] = {"model": PLUMB_BOB, "coeffs": [float(c) for c in cam.distortion]}
    if sequence.T_cam_base_reference is not None:
        entry[REFERENCE_KEY] = sequence.T_cam_base_reference.tolist()
    return {"camera_settings": [entry]}
