"""Atomic writes: a file or a folder appears complete or not at all.

`write_json_atomic` writes a temporary sibling file and renames it over the target;
`atomic_directory` hands out a temporary sibling folder and renames it into place on success.
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from dream.errors import InputError
from dream.io.fields import one_line, os_reason

logger = logging.getLogger(__name__)

JSON_INDENT = 2
TEMPORARY_KINDS = ("tmp", "old")  # the `kind` part of temporary sibling names
_TOKEN_BYTES = 4  # random suffix of temporary names, so concurrent writers never collide


def _temporary_sibling(path: Path, kind: str) -> Path:
    return path.with_name(f".{path.name}.{kind}-{os.getpid()}-{secrets.token_hex(_TOKEN_BYTES)}")


def to_jsonable(value: Any) -> Any:
    """`json.dumps` fallback: numpy arrays and scalars become lists and numbers, paths strings."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} cannot be written as JSON")


def dumps(obj: Any, indent: int | None = JSON_INDENT) -> str:
    """JSON text of `obj` with exact (repr) floats; NaN or infinity is an `InputError`."""
    try:
        return json.dumps(obj, indent=indent, allow_nan=False, default=to_jsonable) + "\n"
    except ValueError as exc:
        raise InputError(f"cannot write JSON ({one_line(exc)})",
                         fix="write null instead of NaN or infinity") from None


def write_json_atomic(path: str | Path, obj: Any, indent: int | None = JSON_INDENT,
                      durable: bool = True) -> Path:
    """Write `obj` as JSON to `path` atomically (see `write_bytes_atomic` for `durable`).

    Floats are written with Python's repr, so reading them back gives the same values.
    Raises `InputError` when the value holds NaN/infinity or the file cannot be written.
    """
    return write_bytes_atomic(path, dumps(obj, indent).encode("utf-8"), durable)


def write_bytes_atomic(path: str | Path, data: bytes, durable: bool = True) -> Path:
    """Write `data` to `path` atomically (temporary sibling file, `os.replace`).

    The rename makes a killed process leave either the old file or the new one. `durable`
    also fsyncs before the rename (survives a power cut; slow on some disks)."""
    path = Path(path)
    tmp = _temporary_sibling(path, "tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        raise InputError(f"cannot write the file ({os_reason(exc)})", path,
                         "check that the folder exists, is writable and the disk has space"
                         ) from None
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def is_temporary(path: Path) -> bool:
    """True for a leftover temporary of `write_*_atomic` or `atomic_directory` (a process that
    was killed mid-write leaves these behind; they are safe to delete)."""
    name = Path(path).name
    return name.startswith(".") and any(f".{kind}-" in name for kind in TEMPORARY_KINDS)


def _is_empty_dir(path: Path) -> bool:
    return path.is_dir() and not any(path.iterdir())


def _move_into_place(tmp: Path, out_dir: Path) -> None:
    """Rename the finished `tmp` folder to `out_dir`, replacing an existing one."""
    if not out_dir.exists() or _is_empty_dir(out_dir):
        if out_dir.exists():
            out_dir.rmdir()
        os.replace(tmp, out_dir)
        return
    old = _temporary_sibling(out_dir, "old")
    os.replace(out_dir, old)
    try:
        os.replace(tmp, out_dir)
    except OSError:
        os.replace(old, out_dir)
        raise
    shutil.rmtree(old, ignore_errors=True)


def check_output_dir(out_dir: Path, overwrite: bool) -> None:
    """Refuse a file, or a non-empty folder unless `overwrite`."""
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError("exists and is a file, expected a folder", out_dir,
                         "choose another output folder")
    if out_dir.is_dir() and not _is_empty_dir(out_dir) and not overwrite:
        raise InputError("the output folder exists and is not empty", out_dir,
                         "choose another output folder, empty it, or ask to overwrite it")


@contextmanager
def atomic_directory(out_dir: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary sibling folder; on success it replaces `out_dir`, else it is deleted.

    An existing non-empty `out_dir` is refused unless `overwrite`. OS failures become
    `InputError`s naming the folder.
    """
    out_dir = Path(out_dir)
    check_output_dir(out_dir, overwrite)
    tmp = _temporary_sibling(out_dir, "tmp")
    fix = "check that the parent folder is writable and the disk has space"
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
    except OSError as exc:
        raise InputError(f"cannot create the output folder ({os_reason(exc)})",
                         out_dir, fix) from None
    finished = False
    try:
        yield tmp
        _move_into_place(tmp, out_dir)
        finished = True
        logger.debug("wrote %s atomically", out_dir)
    except OSError as exc:
        raise InputError(f"cannot write the output folder ({os_reason(exc)})",
                         out_dir, fix) from None
    finally:
        if not finished:
            shutil.rmtree(tmp, ignore_errors=True)
