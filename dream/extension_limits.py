"""The largest plausible size of each model effect: the diagnosis does not accept a fitted
effect beyond it (`dream.diagnosis.select.plausible`), and a model extension read from a file is
refused beyond it (`check_plausible`: a joint offset in degrees written as radians, a distortion
from another camera's units), naming the value and the likely slip.

    >>> from dream.extension import ModelExtension
    >>> check_plausible(ModelExtension(joint_offset_rad={"panda_joint4": 2.0}), None)
    ... # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    dream.errors.InputError: joint_offset panda_joint4 = 2 (115 deg) is beyond a plausible ...
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dream.errors import InputError

PLAUSIBLE = {                      # largest plausible magnitude of each kind of parameter
    "joint_offset": np.deg2rad(10.0),  # rad: encoder zero errors are a few degrees at most
    "link_length": 0.05,               # m
    "keypoint_bias": 0.05,             # m (norm of a keypoint's offset)
    "lens_distortion.k": 0.5,          # k1, k2 (changes)
    "lens_distortion.p": 0.05,         # p1, p2 (changes)
    "intrinsics_error.f": 0.2,         # relative focal length change
    "intrinsics_error.c": 0.1,         # principal point change / focal length
    "time_offset": 0.5,                # s
    "camera_moved.r": np.deg2rad(10.0),  # rad (rotation vector norm)
    "camera_moved.t": 0.2,             # m (translation norm)
}
FIX = "give the values as dream diagnose writes them: radians, metres, seconds"


def check_plausible(extension, path: Path | str | None) -> None:
    """Refuse a `dream.extension.ModelExtension` (read from `path`) with an effect beyond
    `PLAUSIBLE` (the distortion terms are absolute here, the lens's own)."""
    values = [(f"joint_offset {name}", v, "joint_offset", True)
              for name, v in extension.joint_offset_rad.items()]
    values += [(f"link_length {name}", v, "link_length", False)
               for name, v in extension.link_length_m.items()]
    values += [(f"keypoint_bias {name}", float(np.linalg.norm(v)), "keypoint_bias", False)
               for name, v in extension.keypoint_bias_m.items()]
    if extension.distortion is not None:
        k1, k2, p1, p2 = extension.distortion
        values += [("lens_distortion k1", k1, "lens_distortion.k", False),
                   ("lens_distortion k2", k2, "lens_distortion.k", False),
                   ("lens_distortion p1", p1, "lens_distortion.p", False),
                   ("lens_distortion p2", p2, "lens_distortion.p", False)]
    if extension.time_offset_s is not None:
        values.append(("time_offset seconds", extension.time_offset_s, "time_offset", False))
    move = extension.camera_moved
    if move is not None:
        values += [("camera_moved rotation_rad", float(np.linalg.norm(move.rotation_rad)),
                    "camera_moved.r", True),
                   ("camera_moved translation_m", float(np.linalg.norm(move.translation_m)),
                    "camera_moved.t", False)]
    for what, value, kind, angle in values:
        limit = PLAUSIBLE[kind]
        if abs(value) > limit:
            degrees = f" ({np.rad2deg(value):.0f} deg)" if angle else ""
            bound = f" ({np.rad2deg(limit):.0f} deg)" if angle else ""
            raise InputError(f"{what} = {value:g}{degrees} is beyond a plausible {limit:.3g}"
                             f"{bound}: degrees, millimetres or another unit?", path, FIX)
