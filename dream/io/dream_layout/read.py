"""Reading a DREAM / NDDS dataset folder (DREAM's published sets too) into a `Sequence`."""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Sequence as SequenceOf
from pathlib import Path

import numpy as np

from dream.errors import InputError
from dream.io import fields
from dream.io.common import check_images_match, check_joint_names, check_robot
from dream.io.dream_layout.camera_settings import CameraSettings, read_camera_settings
from dream.io.dream_layout.frame_record import RawFrame, parse_frame
from dream.io.dream_layout.names import (
    CAMERA_SETTINGS,
    DEFAULT_CAMERA_NAME,
    FIX_FRAME,
    FRAME_FILE,
    FRAME_INTRINSICS_KEY,
    JSON_SUFFIX,
    LAYOUT_DOC,
    MASK_SUFFIX,
    RGB_SUFFIXES,
)
from dream.io.images import image_size
from dream.io.intrinsics import IntrinsicsArg, camera_from_argument
from dream.sequence import Frame, Sequence

logger = logging.getLogger(__name__)

CENTIMETRE_SUSPECT_DEPTH_M = 20.0  # keypoints this deep (median) were probably written in cm


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


def _align_joints(raws: list[RawFrame], names: tuple[str, ...] | None
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


def _labels(raw: RawFrame, names: tuple[str, ...]) -> tuple[np.ndarray | None,
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


def _robot_name(raws: list[RawFrame], robot: str | None, folder: Path) -> str:
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
                             f"write {CAMERA_SETTINGS} ({LAYOUT_DOC}) or pass --intrinsics")
        return settings
    if settings is not None:
        width, height = settings.camera.width, settings.camera.height
    elif image_paths:
        width, height = image_size(image_paths[0])
    else:
        raise InputError(f"no {CAMERA_SETTINGS} and no image to take the image size from",
                         folder, f"write {CAMERA_SETTINGS} ({LAYOUT_DOC})")
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
                         f"point at a DREAM dataset folder ({LAYOUT_DOC})")
    listed = set(listing)
    stems = [p.name[: -len(JSON_SUFFIX)] for p in files]
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
