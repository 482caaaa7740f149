"""The DREAM / NDDS dataset folder of SPEC.md: reading (DREAM's published sets too) and writing.

A folder holds `_camera_settings.json` and one `NNNNNN.json` per frame, with optional
`NNNNNN.rgb.png|jpg` images and `NNNNNN.seg.png` robot masks. Fields the project does not use
(`camera_data`, `_object_settings.json`, `visibility`, ...) are ignored. Extensions: a frame
`timestamp` (s), a frame's own `camera_intrinsics` {fx, fy, cx, cy} (`dream synth` with a random
field of view; same image size and distortion as the camera settings), a camera `distortion` and
a camera `reference_T_cam_base` (4x4).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import re
import shutil
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dream.camera import PLUMB_BOB, CameraIntrinsics
from dream.errors import InputError
from dream.io import fields
from dream.io.atomic import atomic_directory, dumps
from dream.io.common import check_images_match, check_joint_names, check_robot, frame_name
from dream.io.images import (
    NPZ_SUFFIX,
    encode_png,
    image_size,
    load_image,
    load_mask_ids,
    mask_ids_for_png,
)
from dream.io.intrinsics import IntrinsicsArg, camera_from_argument, parse_distortion
from dream.sequence import Frame, Sequence
from dream.transforms import (
    T_from_quaternion_xyzw_t,
    is_rigid,
    quaternion_xyzw_from_R,
)

logger = logging.getLogger(__name__)

CAMERA_SETTINGS = "_camera_settings.json"
FRAME_INTRINSICS_KEY = "camera_intrinsics"  # optional per-frame fx, fy, cx, cy (dream synth)
FRAME_FILE = re.compile(r"^(\d+)\.json$")
RGB_SUFFIXES = (".rgb.png", ".rgb.jpg", ".rgb.jpeg")
PNG_RGB_SUFFIX = ".rgb.png"
JPEG_RGB_SUFFIX = ".rgb.jpg"
MASK_SUFFIX = ".seg.png"
REFERENCE_KEY = "reference_T_cam_base"
DEFAULT_CAMERA_NAME = "camera"
RIGID_ATOL = 1e-4  # tolerance of a written 4x4 pose's rotation block being orthonormal
QUATERNION_NORM_ATOL = 1e-3  # how far from unit length a written quaternion may be
CENTIMETRE_SUSPECT_DEPTH_M = 20.0  # keypoints this deep (median) were probably written in cm
PNG_SUFFIXES = (".png",)
JPEG_SUFFIXES = (".jpg", ".jpeg")
FIX_CAMERA = ('write {"camera_settings": [{"intrinsic_settings": {"fx", "fy", "cx", "cy", '
              '"resolution": {"width", "height"}}}]} (see SPEC.md)')
FIX_FRAME = "write the frame as in SPEC.md (objects[0].keypoints, sim_state.joints)"


@dataclass(frozen=True)
class CameraSettings:
    """What `_camera_settings.json` says: intrinsics, camera name, optional reference pose."""

    camera: CameraIntrinsics
    name: str
    T_cam_base_reference: np.ndarray | None


@dataclass(frozen=True)
class _RawFrame:
    """One frame JSON, checked but not yet aligned with the other frames."""

    path: Path
    robot_class: str | None
    joints: dict[str, float]
    keypoints: dict[str, tuple[np.ndarray | None, np.ndarray | None]]  # name -> (P_cam, uv)
    T_cam_base: np.ndarray | None
    timestamp: float | None
    intrinsics: dict[str, float] | None  # the frame's own fx, fy, cx, cy (`camera_intrinsics`)


# ----------------------------------------------------------------------------- reading


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
    items = fields.as_list(obj.get("keypoints", []), "objects[0].keypoints", path, FIX_FRAME)
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


def parse_frame(data: Any, path: Path, robot: str | None = None) -> _RawFrame:
    """Check and convert the content of one `NNNNNN.json` frame file."""
    data = fields.as_dict(data, "the file", path, FIX_FRAME)
    timestamp = data.get("timestamp")
    if timestamp is not None:
        timestamp = fields.as_number(timestamp, "timestamp", path, "write the time in seconds")
    objects = fields.as_list(data.get("objects", []), "objects", path, FIX_FRAME)
    obj = _pick_object(objects, robot, path)
    robot_class = None
    if obj is not None and "class" in obj:
        robot_class = fields.as_str(obj["class"], "objects[0].class", path, FIX_FRAME)
    return _RawFrame(
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


def dataset_folder(path: Path) -> Path:
    """The dataset folder of `path` (a folder, or its `_camera_settings.json` / a frame file)."""
    if path.is_file() and (path.name == CAMERA_SETTINGS or FRAME_FILE.match(path.name)):
        return path.parent
    if not path.is_dir():
        raise InputError("is not a folder", path,
                         "point at the dataset folder holding _camera_settings.json")
    return path


def frame_files(folder: Path, listing: SequenceOf[str]) -> list[Path]:
    """The frame files of a folder listing, in numeric order."""
    numbered = [(int(m.group(1)), name) for name in listing
                if (m := FRAME_FILE.match(name))]
    numbered.sort()
    return [folder / name for _, name in numbered]


def _align_joints(raws: list[_RawFrame], names: tuple[str, ...] | None
                  ) -> tuple[tuple[str, ...], list[np.ndarray]]:
    if names is None:
        names = tuple(raws[0].joints)
        expected = set(names)
        for raw in raws:
            if set(raw.joints) != expected:
                missing = [fields.quote(n) for n in sorted(expected - set(raw.joints))]
                extra = [fields.quote(n) for n in sorted(set(raw.joints) - expected)]
                raise InputError(f"joint names differ from {raws[0].path.name} (missing: "
                                 f"{', '.join(missing) or 'none'}; extra: "
                                 f"{', '.join(extra) or 'none'})", raw.path,
                                 "write the same joints in every frame")
    for raw in raws:
        missing = [fields.quote(n) for n in names if n not in raw.joints]
        if missing:
            raise InputError(f"sim_state.joints lacks {', '.join(missing)}", raw.path,
                             "write every joint in every frame or pass other joint names")
    return names, [np.array([raw.joints[n] for n in names]) for raw in raws]


def _labels(raw: _RawFrame, names: tuple[str, ...]) -> tuple[np.ndarray | None,
                                                              np.ndarray | None]:
    P = np.full((len(names), 3), np.nan)
    uv = np.full((len(names), 2), np.nan)
    for k, name in enumerate(names):
        location, projected = raw.keypoints.get(name, (None, None))
        if location is not None:
            P[k] = location
        if projected is not None:
            uv[k] = projected
    has_P = any(loc is not None for loc, _ in raw.keypoints.values())
    has_uv = any(proj is not None for _, proj in raw.keypoints.values())
    return (uv if has_uv else None), (P if has_P else None)


def _robot_name(raws: list[_RawFrame], robot: str | None, folder: Path) -> str:
    if robot is not None:
        return robot
    first = next((raw for raw in raws if raw.robot_class is not None), None)
    if first is None:
        raise InputError("no frame names its robot (objects[0].class)", folder,
                         "write objects[0].class or pass --robot")
    for raw in raws:
        if raw.robot_class is not None and raw.robot_class != first.robot_class:
            raise InputError(f"objects[0].class is {fields.quote(raw.robot_class)} but "
                             f"{first.path.name} says {fields.quote(first.robot_class)}", raw.path,
                             "use one robot per dataset or pass --robot")
    return first.robot_class


def _find_file(stem: str, suffixes: tuple[str, ...], listing: set[str],
               folder: Path) -> Path | None:
    for suffix in suffixes:
        if stem + suffix in listing:
            return folder / (stem + suffix)
    return None


def _camera(folder: Path, listing: set[str], intrinsics: IntrinsicsArg | None,
            image_paths: list[Path]) -> CameraSettings:
    settings_path = folder / CAMERA_SETTINGS
    settings = read_camera_settings(settings_path) if CAMERA_SETTINGS in listing else None
    if intrinsics is None:
        if settings is None:
            raise InputError(f"no {CAMERA_SETTINGS}", folder,
                             f"write {CAMERA_SETTINGS} (SPEC.md) or pass --intrinsics")
        return settings
    if settings is not None:
        width, height = settings.camera.width, settings.camera.height
    elif image_paths:
        width, height = image_size(image_paths[0])
    else:
        raise InputError(f"no {CAMERA_SETTINGS} and no image to take the image size from",
                         folder, f"write {CAMERA_SETTINGS} (SPEC.md)")
    camera = camera_from_argument(intrinsics, width, height, settings_path)
    if settings is None:
        return CameraSettings(camera, DEFAULT_CAMERA_NAME, None)
    return CameraSettings(camera, settings.name, settings.T_cam_base_reference)


def read_dream(path: str | Path, *, joint_names: SequenceOf[str] | None = None,
               intrinsics: IntrinsicsArg | None = None, robot: str | None = None) -> Sequence:
    """Read a DREAM / NDDS dataset folder into a `Sequence`.

    Args:
        path: the folder (or its `_camera_settings.json`).
        joint_names: joints to keep, in this order; default: those of the first frame.
        intrinsics: replaces the camera settings' intrinsics when given.
        robot: robot name; default `objects[0].class`. Also picks the object of that class.
    """
    folder = dataset_folder(Path(path))
    names_arg = check_joint_names(joint_names, None)
    robot = check_robot(robot, None)
    try:
        listing = sorted(os.listdir(folder))
    except OSError as exc:
        raise InputError(f"cannot list the folder ({fields.os_reason(exc)})",
                         folder) from None
    files = frame_files(folder, listing)
    if not files:
        raise InputError("holds no frame files (NNNNNN.json)", folder,
                         "point at a DREAM dataset folder (SPEC.md)")
    listed = set(listing)
    stems = [p.name[: -len(".json")] for p in files]
    images = [_find_file(s, RGB_SUFFIXES, listed, folder) for s in stems]
    masks = [_find_file(s, (MASK_SUFFIX,), listed, folder) for s in stems]
    settings = _camera(folder, listed, intrinsics, [p for p in images if p is not None])
    check_images_match((p for p in images + masks if p is not None), settings.camera)

    raws = [parse_frame(fields.load_json(p, FIX_FRAME), p, robot) for p in files]
    names, joints = _align_joints(raws, names_arg)
    keypoint_names = tuple(dict.fromkeys(n for raw in raws for n in raw.keypoints))
    frames = []
    for stem, raw, q, image, mask in zip(stems, raws, joints, images, masks, strict=True):
        uv, P = _labels(raw, keypoint_names)
        own = None
        if raw.intrinsics is not None and intrinsics is None:  # --intrinsics overrides all
            try:
                own = dataclasses.replace(settings.camera, **raw.intrinsics)
            except InputError as exc:
                raise InputError(f"{FRAME_INTRINSICS_KEY}: {exc.problem}", raw.path,
                                 exc.fix) from None
        frames.append(Frame(name=stem, joints=q, image_path=image, mask_path=mask,
                            timestamp=raw.timestamp, uv_labels=uv, P_cam_labels=P,
                            T_cam_base_true=raw.T_cam_base, source=raw.path, camera=own))
    sequence = Sequence(robot=_robot_name(raws, robot, folder), camera=settings.camera,
                        joint_names=names, keypoint_names=keypoint_names, frames=tuple(frames),
                        T_cam_base_reference=settings.T_cam_base_reference, source=folder,
                        camera_name=settings.name)
    _warn_if_centimetres(sequence)
    logger.info("read %d DREAM frames from %s", len(frames), folder)
    return sequence


def _warn_if_centimetres(sequence: Sequence) -> None:
    depths = [f.P_cam_labels[:, 2] for f in sequence.frames if f.P_cam_labels is not None]
    finite = np.concatenate(depths)[np.isfinite(np.concatenate(depths))] if depths else []
    if len(finite) and np.median(np.abs(finite)) > CENTIMETRE_SUSPECT_DEPTH_M:
        logger.warning("%s: keypoint locations lie %.0f m from the camera (median); they look "
                       "like centimetres, but DREAM files must be in metres", sequence.source,
                       float(np.median(np.abs(finite))))


# ----------------------------------------------------------------------------- writing


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
    obj["keypoints"] = keypoints
    data: dict[str, Any] = {}
    if frame.timestamp is not None:
        data["timestamp"] = float(frame.timestamp)
    data["objects"] = [obj]
    data["sim_state"] = {"joints": [{"name": n, "position": float(q)}
                                    for n, q in zip(sequence.joint_names, frame.joints,
                                                    strict=True)]}
    if frame.camera is not None and frame.camera != sequence.camera:
        cam = frame.camera
        data[FRAME_INTRINSICS_KEY] = {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy}
    return data


def _write_image(frame: Frame, camera: CameraIntrinsics, folder: Path, stem: str) -> None:
    src = frame.image_path
    if src is None:
        return
    suffix = src.suffix.lower()
    if suffix in PNG_SUFFIXES + JPEG_SUFFIXES:
        check_images_match([src], camera)
        target = PNG_RGB_SUFFIX if suffix in PNG_SUFFIXES else JPEG_RGB_SUFFIX
        shutil.copyfile(src, folder / (stem + target))
        return
    if suffix != NPZ_SUFFIX:
        logger.debug("re-encoding %s as PNG", src)
    (folder / (stem + PNG_RGB_SUFFIX)).write_bytes(encode_png(load_image(frame, camera), src))


def _write_mask(frame: Frame, camera: CameraIntrinsics, folder: Path, stem: str) -> None:
    src = frame.mask_path
    if src is None:
        return
    if src.suffix.lower() in PNG_SUFFIXES:
        check_images_match([src], camera)
        shutil.copyfile(src, folder / (stem + MASK_SUFFIX))
        return
    ids = mask_ids_for_png(load_mask_ids(frame, camera), src)
    (folder / (stem + MASK_SUFFIX)).write_bytes(encode_png(ids, src))


def write_dream(sequence: Sequence, out_dir: str | Path, *, copy_images: bool = True,
                overwrite: bool = False) -> Path:
    """Write `sequence` as a DREAM dataset folder (SPEC.md), atomically.

    Frames are named by their index (`000000.json`, ...). With `copy_images`, PNG/JPEG images
    and PNG masks are copied (`NNNNNN.rgb.png|jpg`, `NNNNNN.seg.png`) and other sources (e.g.
    `.npz` stacks) re-encoded as PNG; without it only the JSON files are written. Everything
    is written into a temporary sibling folder renamed to `out_dir` at the end, so a failure
    leaves no partial output. An existing non-empty `out_dir` is refused unless `overwrite`.

    Returns:
        `out_dir` as a Path.
    """
    out_dir = Path(out_dir)
    with atomic_directory(out_dir, overwrite) as tmp:
        (tmp / CAMERA_SETTINGS).write_text(dumps(camera_settings_json(sequence)),
                                           encoding="utf-8")
        for index, frame in enumerate(sequence.frames):
            stem = frame_name(index)
            (tmp / f"{stem}.json").write_text(dumps(frame_json(sequence, frame)),
                                              encoding="utf-8")
            if copy_images:
                _write_image(frame, sequence.camera, tmp, stem)
                _write_mask(frame, sequence.camera, tmp, stem)
    logger.info("wrote %d frames to %s", len(sequence.frames), out_dir)
    return out_dir
