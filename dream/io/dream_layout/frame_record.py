"""`NNNNNN.json` of the DREAM layout: one frame's record, read and written.

A frame holds `sim_state.joints` [{name, position}] (rad or m), `objects` (the robot's entry:
`class`, `keypoints` [{name, location (camera frame, m), projected_location (px)}], and its
pose `location` + `quaternion_xyzw`), and the extensions `timestamp` (s) and
`camera_intrinsics` {fx, fy, cx, cy} (the frame's own intrinsics, px).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dream.errors import InputError
from dream.io import fields
from dream.io.dream_layout.names import (
    FIX_FRAME,
    FRAME_INTRINSICS_KEY,
    KEYPOINTS_KEY,
    OBJECTS_KEY,
)
from dream.sequence import Frame, Sequence
from dream.transforms import T_from_quaternion_xyzw_t, quaternion_xyzw_from_R

logger = logging.getLogger(__name__)

QUATERNION_NORM_ATOL = 1e-3  # how far from unit length a written quaternion may be


@dataclass(frozen=True)
class RawFrame:
    """One frame JSON, checked but not yet aligned with the other frames."""

    path: Path
    robot_class: str | None
    joints: dict[str, float]
    keypoints: dict[str, tuple[np.ndarray | None, np.ndarray | None]]  # name -> (P_cam, uv)
    T_cam_base: np.ndarray | None
    timestamp: float | None
    intrinsics: dict[str, float] | None  # the frame's own fx, fy, cx, cy (`camera_intrinsics`)


# ----------------------------------------------------------------------------- reading


def _pick_object(objects: list[Any], robot: str | None, path: Path) -> dict[str, Any] | None:
    if not objects:
        return None
    checked = [fields.as_dict(o, f"objects[{i}]", path, FIX_FRAME) for i, o in enumerate(objects)]
    if robot is not None:
        for obj in checked:
            if obj.get("class") == robot:
                return obj
    return checked[0]


def _parse_pose(obj: dict[str, Any], path: Path) -> np.ndarray | None:
    if "location" not in obj or "quaternion_xyzw" not in obj:
        if "location" in obj or "quaternion_xyzw" in obj:
            logger.debug("%s: object pose needs both location and quaternion_xyzw; ignored",
                         path)
        return None
    fix = "write location [x, y, z] in metres and a unit quaternion_xyzw [x, y, z, w]"
    t = fields.as_vector(obj["location"], "objects[0].location", path, 3, fix)
    q = fields.as_vector(obj["quaternion_xyzw"], "objects[0].quaternion_xyzw", path, 4, fix)
    if abs(np.linalg.norm(q) - 1.0) > QUATERNION_NORM_ATOL:
        raise InputError(f"objects[0].quaternion_xyzw {q.tolist()} is not a unit quaternion",
                         path, fix)
    return T_from_quaternion_xyzw_t(q / np.linalg.norm(q), t)


def _parse_keypoints(obj: dict[str, Any], path: Path
                     ) -> dict[str, tuple[np.ndarray | None, np.ndarray | None]]:
    items = fields.as_list(obj.get(KEYPOINTS_KEY, []), "objects[0].keypoints", path, FIX_FRAME)
    out: dict[str, tuple[np.ndarray | None, np.ndarray | None]] = {}
    for i, item in enumerate(items):
        what = f"objects[0].keypoints[{i}]"
        item = fields.as_dict(item, what, path, FIX_FRAME)
        name = fields.as_str(fields.require(item, "name", f"{what}.name", path, FIX_FRAME),
                             f"{what}.name", path, FIX_FRAME)
        if name in out:
            raise InputError(f"keypoint {fields.quote(name)} appears twice", path,
                             "list each keypoint once")
        location = item.get("location")
        uv = item.get("projected_location")
        out[name] = (
            None if location is None else fields.as_vector(
                location, f"{what}.location", path, 3, "write [x, y, z] in metres"),
            None if uv is None else fields.as_vector(
                uv, f"{what}.projected_location", path, 2, "write [u, v] in pixels"))
    return out


def _parse_joints(data: dict[str, Any], path: Path) -> dict[str, float]:
    fix = 'write sim_state.joints as [{"name": "panda_joint1", "position": 0.1}, ...] (rad or m)'
    state = fields.as_dict(fields.require(data, "sim_state", "sim_state", path, fix),
                           "sim_state", path, fix)
    items = fields.as_list(fields.require(state, "joints", "sim_state.joints", path, fix),
                           "sim_state.joints", path, fix)
    joints: dict[str, float] = {}
    for i, item in enumerate(items):
        what = f"sim_state.joints[{i}]"
        item = fields.as_dict(item, what, path, fix)
        name = fields.as_str(fields.require(item, "name", f"{what}.name", path, fix),
                             f"{what}.name", path, fix)
        if name in joints:
            raise InputError(f"joint {fields.quote(name)} appears twice in sim_state.joints",
                             path, fix)
        joints[name] = fields.as_number(fields.require(item, "position", f"{what}.position",
                                                       path, fix), f"{what}.position", path, fix)
    if not joints:
        raise InputError("sim_state.joints is empty", path, fix)
    return joints


def parse_frame(data: Any, path: Path, robot: str | None = None) -> RawFrame:
    """Check and convert the content of one `NNNNNN.json` frame file."""
    data = fields.as_dict(data, "the file", path, FIX_FRAME)
    timestamp = data.get("timestamp")
    if timestamp is not None:
        timestamp = fields.as_number(timestamp, "timestamp", path, "write the time in seconds")
    objects = fields.as_list(data.get(OBJECTS_KEY, []), "objects", path, FIX_FRAME)
    obj = _pick_object(objects, robot, path)
    robot_class = None
    if obj is not None and "class" in obj:
        robot_class = fields.as_str(obj["class"], "objects[0].class", path, FIX_FRAME)
    return RawFrame(
        path=path,
        robot_class=robot_class,
        joints=_parse_joints(data, path),
        keypoints={} if obj is None else _parse_keypoints(obj, path),
        T_cam_base=None if obj is None else _parse_pose(obj, path),
        timestamp=timestamp,
        intrinsics=_parse_frame_intrinsics(data.get(FRAME_INTRINSICS_KEY), path),
    )


def _parse_frame_intrinsics(data: Any, path: Path) -> dict[str, float] | None:
    """The optional per-frame `camera_intrinsics` {fx, fy, cx, cy} (pixels)."""
    if data is None:
        return None
    fix = (f'write "{FRAME_INTRINSICS_KEY}": {{"fx": ..., "fy": ..., "cx": ..., "cy": ...}} '
           "in pixels")
    data = fields.as_dict(data, FRAME_INTRINSICS_KEY, path, fix)
    return {k: fields.as_number(fields.require(data, k, f"{FRAME_INTRINSICS_KEY}.{k}", path, fix),
                                f"{FRAME_INTRINSICS_KEY}.{k}", path, fix)
            for k in ("fx", "fy", "cx", "cy")}


# ----------------------------------------------------------------------------- writing


def _finite_row(row: np.ndarray | None) -> list[float] | None:
    if row is None or not np.all(np.isfinite(row)):
        return None
    return [float(v) for v in row]


def frame_json(sequence: Sequence, frame: Frame) -> dict[str, Any]:
    """The `NNNNNN.json` content of one frame."""
    keypoints = []
    for k, name in enumerate(sequence.keypoint_names):
        item: dict[str, Any] = {"name": name}
        location = _finite_row(None if frame.P_cam_labels is None else frame.P_cam_labels[k])
        projected = _finite_row(None if frame.uv_labels is None else frame.uv_labels[k])
        if location is not None:
            item["location"] = location
        if projected is not None:
            item["projected_location"] = projected
        keypoints.append(item)
    obj: dict[str, Any] = {"class": sequence.robot}
    if frame.T_cam_base_true is not None:
        obj["location"] = [float(v) for v in frame.T_cam_base_true[:3, 3]]
        obj["quaternion_xyzw"] = [float(v) for v in
                                  quaternion_xyzw_from_R(frame.T_cam_base_true[:3, :3])]
    obj[KEYPOINTS_KEY] = keypoints
    data: dict[str, Any] = {}
    if frame.timestamp is not None:
        data["timestamp"] = float(frame.timestamp)
    data[OBJECTS_KEY] = [obj]
    data["sim_state"] = {"joints": [{"name": n, "position": float(q)}
                                    for n, q in zip(sequence.joint_names, frame.joints,
                                                    strict=True)]}
    if frame.camera is not None and frame.camera != sequence.camera:
        cam = frame.camera
        data[FRAME_INTRINSICS_KEY] = {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy}
    return data
