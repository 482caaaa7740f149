"""Writing a `Sequence` as a DREAM dataset folder, atomically."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

from dream.camera import CameraIntrinsics
from dream.io.atomic import atomic_directory, dumps
from dream.io.common import check_images_match, frame_name
from dream.io.dream_layout.camera_settings import camera_settings_json
from dream.io.dream_layout.frame_record import frame_json
from dream.io.dream_layout.names import (
    CAMERA_SETTINGS,
    JPEG_RGB_SUFFIX,
    JPEG_SUFFIXES,
    JSON_SUFFIX,
    MASK_SUFFIX,
    PNG_RGB_SUFFIX,
    PNG_SUFFIXES,
)
from dream.io.images import NPZ_SUFFIX, encode_png, load_image, load_mask_ids, mask_ids_for_png
from dream.sequence import Frame, Sequence

logger = logging.getLogger(__name__)


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
    """Write `sequence` as a DREAM dataset folder (docs/data_format.md#dream-layout),
    atomically.

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
            (tmp / f"{stem}{JSON_SUFFIX}").write_text(dumps(frame_json(sequence, frame)),
                                              encoding="utf-8")
            if copy_images:
                _write_image(frame, sequence.camera, tmp, stem)
                _write_mask(frame, sequence.camera, tmp, stem)
    logger.info("wrote %d frames to %s", len(sequence.frames), out_dir)
    return out_dir
