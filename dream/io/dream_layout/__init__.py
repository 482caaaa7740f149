"""The DREAM / NDDS dataset folder (docs/data_format.md#dream-layout): reading and writing.

A folder holds `_camera_settings.json` and one `NNNNNN.json` per frame, with optional
`NNNNNN.rgb.png|jpg` images and `NNNNNN.seg.png` robot masks. Fields the project does not use
(`camera_data`, `_object_settings.json`, `visibility`, ...) are ignored. Extensions: a frame
`timestamp` (s), a frame's own `camera_intrinsics` {fx, fy, cx, cy} (`dream synth` with a random
field of view; same image size and distortion as the camera settings), a camera `distortion` and
a camera `reference_T_cam_base` (4x4).

Modules: `names` (file names, suffixes, keys), `camera_settings` (the camera record),
`frame_record` (one frame's record), `read` (a folder into a `Sequence`), `write` (a
`Sequence` into a folder).
"""

from dream.io.dream_layout.camera_settings import (
    CameraSettings,
    camera_settings_json,
    parse_camera_settings,
    read_camera_settings,
)
from dream.io.dream_layout.frame_record import RawFrame, frame_json, parse_frame
from dream.io.dream_layout.names import CAMERA_SETTINGS, FRAME_FILE
from dream.io.dream_layout.read import dataset_folder, frame_files, read_dream
from dream.io.dream_layout.write import write_dream

__all__ = [
    "CAMERA_SETTINGS",
    "FRAME_FILE",
    "CameraSettings",
    "RawFrame",
    "camera_settings_json",
    "dataset_folder",
    "frame_files",
    "frame_json",
    "parse_camera_settings",
    "parse_frame",
    "read_camera_settings",
    "read_dream",
    "write_dream",
]
