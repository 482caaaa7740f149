"""The names of the DREAM / NDDS layout: file names, file suffixes, JSON keys, the fix texts.

Every reader and writer of the layout (`dream.io`, `dream synth`) takes them from here.
"""

from __future__ import annotations

import re

from dream.io.common import FRAME_DIGITS

LAYOUT_DOC = "docs/data_format.md#dream-layout"  # where the layout is described

# ----- files of a dataset folder -----------------------------------------------------------------
CAMERA_SETTINGS = "_camera_settings.json"
JSON_SUFFIX = ".json"                   # NNNNNN.json: one frame's record
FRAME_FILE = re.compile(r"^(\d+)\.json$")
FRAME_PART = re.compile(rf"[0-9]{{{FRAME_DIGITS}}}\.")  # any file of a frame named by its index
RGB_SUFFIXES = (".rgb.png", ".rgb.jpg", ".rgb.jpeg")
PNG_RGB_SUFFIX = ".rgb.png"
JPEG_RGB_SUFFIX = ".rgb.jpg"
MASK_SUFFIX = ".seg.png"                # per-pixel link ids (0 background)
DEPTH_SUFFIX = ".depth.png"             # uint16 millimetres, written by `dream synth`; not read
PNG_SUFFIXES = (".png",)
JPEG_SUFFIXES = (".jpg", ".jpeg")

# ----- JSON keys ----------------------------------------------------------------------------------
OBJECTS_KEY = "objects"                # a frame's list of objects (the robot is one of them)
KEYPOINTS_KEY = "keypoints"            # an object's list of keypoints
FRAME_INTRINSICS_KEY = "camera_intrinsics"  # optional per-frame fx, fy, cx, cy (dream synth)
REFERENCE_KEY = "reference_T_cam_base"
DEFAULT_CAMERA_NAME = "camera"

# ----- what to do about a malformed file ---------------------------------------------------------
FIX_CAMERA = ('write {"camera_settings": [{"intrinsic_settings": {"fx", "fy", "cx", "cy", '
              f'"resolution": {{"width", "height"}}}}}}]}} (see {LAYOUT_DOC})')
FIX_FRAME = (f"write the frame as in {LAYOUT_DOC} (objects[0].keypoints, "
             "sim_state.joints)")
