"""Which data a result was made from: a record for RESULT.json and the check `dream eval` makes.

The record names the data's path and frames and carries a content hash: SHA-256 over every
frame's name, joint readings, timestamp and image and mask file contents, in frame order. A
result scored against other data would give confident, meaningless metrics.

    >>> import numpy as np
    >>> from dream.camera import CameraIntrinsics
    >>> from dream.sequence import Frame, Sequence
    >>> seq = Sequence("panda", CameraIntrinsics(100, 100, 49.5, 49.5, 100, 100),
    ...                ("j1",), ("k1",), (Frame("000000", np.zeros(1)),))
    >>> len(content_hash(seq))
    64
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from dream.errors import InputError
from dream.io.fields import os_reason

HASH_CHUNK_BYTES = 1 << 20


def file_digest(path: Path, cache: dict[Path, bytes]) -> bytes:
    if path not in cache:
        digest = hashlib.sha256()
        try:
            with open(path, "rb") as f:
                for chunk in iter(lambda: f.read(HASH_CHUNK_BYTES), b""):
                    digest.update(chunk)
        except OSError as exc:
            raise InputError(f"cannot read the file ({os_reason(exc)})", path,
                             "check that the data's files are readable") from None
        cache[path] = digest.digest()
    return cache[path]


def content_hash(seq) -> str:
    """SHA-256 (hex) of the frames' names, joints, timestamps, image and mask contents."""
    digest, files = hashlib.sha256(), {}
    digest.update(",".join(seq.joint_names).encode())
    for frame in seq.frames:
        digest.update(frame.name.encode())
        digest.update(np.asarray(frame.joints, dtype="<f8").tobytes())
        digest.update(b"" if frame.timestamp is None else np.float64(frame.timestamp).tobytes())
        for path in (frame.image_path, frame.mask_path):
            digest.update(b"-" if path is None else file_digest(Path(path), files))
        digest.update(str(frame.image_index).encode())
    return digest.hexdigest()


def camera_record(c) -> dict[str, Any]:
    """A camera (`dream.camera.CameraIntrinsics`) as JSON: size, fx, fy, cx, cy (pixels) and
    its distortion coefficients or None."""
    return {"width": c.width, "height": c.height, "fx": c.fx, "fy": c.fy, "cx": c.cx,
            "cy": c.cy, "distortion": None if c.distortion is None else list(c.distortion)}


def data_record(seq, data: str) -> dict[str, Any]:
    """RESULT.json's `data`: the path given, its frames, the content hash and the camera."""
    return {"path": str(Path(data).resolve()), "num_frames": len(seq.frames),
            "frames": [f.name for f in seq.frames], "content_sha256": content_hash(seq),
            "camera": camera_record(seq.camera)}


def check_same_data(result: dict[str, Any], seq, data: str, result_path: str | Path,
                    part_ok: bool = False, given_as: str = "--data") -> None:
    """Refuse to score a result made from other data than `seq` (`--data`). Results written
    before the record existed carry none and pass. With `part_ok`, a result made from some of
    `seq`'s frames passes too (`made_from_part`: a fixed camera calibrated on the first
    frames of a recording labels all of them). `given_as` names where `seq` came from in the
    message (the option, or the API's argument)."""
    record = result.get("data")
    if not isinstance(record, dict) or "content_sha256" not in record:
        return
    if record["content_sha256"] == content_hash(seq):
        return
    if part_ok and made_from_part(record, seq):
        return
    raise InputError(f"was calibrated from other data ({record.get('path')}, "
                     f"{record.get('num_frames')} frames) than {given_as} {data} "
                     f"({len(seq.frames)} frames, other content)", result_path,
                     f"give {given_as} the dataset the result was made from, or calibrate "
                     "this one")


def made_from_part(record: dict[str, Any], seq) -> bool:
    """Whether a result's data record (`data_record`) names frames of `seq` whose content, in
    the record's order, hashes as the record says: the result was made from those frames (a
    copy of them, anywhere on disk)."""
    names = record.get("frames")
    by_name = {frame.name: frame for frame in seq.frames}
    if not isinstance(names, list) or not names or not all(
            isinstance(n, str) and n in by_name for n in names):
        return False
    part = dataclasses.replace(seq, frames=tuple(by_name[n] for n in names))
    return content_hash(part) == record["content_sha256"]
