"""Atomic writes: a file or a folder appears complete or not at all.

`write_json_atomic` writes a temporary sibling file and renames it over the target;
`write_files_atomic` / `replacing_files` do so for several files that belong together (all
or none, the files they replace restored on a failure);
`atomic_directory` hands out a temporary sibling folder and renames it into place on success;
`staged_directory` hands one out whose files join an output folder on success.
`check_output_file` / `check_output_folder` check an output location before any work, and
`make_output_dir` creates a folder; each failure is an `InputError` naming the path.
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import shutil
from collections.abc import Iterator, Mapping
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


_FIX_FILE = "check that the folder exists, is writable and the disk has space"


def _write_temporary(path: Path, data: bytes, durable: bool) -> Path:
    """`data` in a new temporary sibling of `path` (fsynced when `durable`); returns its path.
    On a failure the temporary is removed and the `OSError` raised."""
    tmp = _temporary_sibling(path, "tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


def write_bytes_atomic(path: str | Path, data: bytes, durable: bool = True) -> Path:
    """Write `data` to `path` atomically (temporary sibling file, `os.replace`).

    The rename makes a killed process leave either the old file or the new one. `durable`
    also fsyncs before the rename (survives a power cut; slow on some disks)."""
    path = Path(path)
    tmp = None
    try:
        tmp = _write_temporary(path, data, durable)
        os.replace(tmp, path)
    except OSError as exc:
        raise InputError(f"cannot write the file ({os_reason(exc)})", path, _FIX_FILE) from None
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
    return path


def is_temporary(path: Path) -> bool:
    """True for a leftover temporary of `write_*_atomic` or `atomic_directory` (a process that
    was killed mid-write leaves these behind; they are safe to delete)."""
    name = Path(path).name
    return name.startswith(".") and any(f".{kind}-" in name for kind in TEMPORARY_KINDS)


def remove_temporaries(folder: str | Path) -> int:
    """Delete the leftover temporaries (files and folders, `is_temporary`) directly in
    `folder`, which a killed writer left behind; returns how many."""
    folder = Path(folder)
    stale = [p for p in folder.iterdir() if is_temporary(p)] if folder.is_dir() else []
    for path in stale:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    return len(stale)


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


_FIX_OUTPUT = "choose another output location, or move the file out of the way"
_FIX_WRITABLE = "check that the parent folder is writable and the disk has space"


def _check_ancestors(path: Path) -> None:
    """Refuse an output `path` that cannot be created because a file stands where one of its
    parent folders should be, or whose nearest existing parent folder is not writable."""
    for parent in path.parents:
        if parent.is_dir():
            if not os.access(parent, os.W_OK | os.X_OK):
                raise InputError(f"cannot create it: the folder {parent} is not writable", path,
                                 "choose a writable output location")
            return
        if os.path.lexists(parent):
            raise InputError(f"cannot create it: {parent} is a file, not a folder", path,
                             _FIX_OUTPUT)


def check_output_file(path: str | Path, parents_made: bool = False) -> Path:
    """Check, before any work, that the output file `path` can be written: it is not a folder
    and its folder exists (or, with `parents_made`, can be created) and is writable. Returns
    `path` as a `Path`."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder, expected a file to write", path,
                         "give a file name, or remove the folder")
    _check_ancestors(path)
    if not parents_made and not path.parent.is_dir():
        raise InputError(f"the folder {path.parent} does not exist", path,
                         "create the folder first, or choose another output file")
    return path


def check_output_folder(path: str | Path) -> Path:
    """Check, before any work, that the output folder `path` exists or can be created (no file
    stands at it or at one of its parents). Returns `path` as a `Path`."""
    path = Path(path)
    if path.is_dir():
        if not os.access(path, os.W_OK | os.X_OK):
            raise InputError("the output folder is not writable", path,
                             "choose a writable output folder")
        return path
    if os.path.lexists(path):
        raise InputError("exists and is a file, expected a folder", path, _FIX_OUTPUT)
    _check_ancestors(path)
    return path


def make_output_dir(path: str | Path) -> Path:
    """Create the output folder `path` and its parents (an existing folder is fine); an
    `InputError` naming it when that is not possible."""
    path = check_output_folder(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except (OSError, ValueError) as exc:  # ValueError: a path with a NUL character
        raise InputError(f"cannot create the output folder ({os_reason(exc)})", path,
                         _FIX_WRITABLE) from None
    return path


def _missing_folders(path: Path) -> list[Path]:
    """`path` and those of its parents that do not exist yet, deepest first."""
    missing = []
    for p in (path, *path.parents):
        if os.path.lexists(p):
            break
        missing.append(p)
    return missing


def outermost_missing(path: str | Path) -> Path | None:
    """The outermost of `path` and its parents that does not exist yet (the folder that
    creating `path` creates first, and that a failed run removes); None when `path` exists."""
    missing = _missing_folders(Path(path))
    return missing[-1] if missing else None


def _keep_aside(target: Path) -> Path:
    """A temporary sibling holding `target`'s present content (a hard link, else a copy)."""
    backup = _temporary_sibling(target, "old")
    try:
        os.link(target, backup)
    except OSError:  # a file system without hard links
        shutil.copy2(target, backup)
    return backup


def _put_back(placed: list[Path], backups: dict[Path, Path]) -> None:
    """Undo `replacing_files`: each placed file's previous content back, or the file removed
    where there was none."""
    for target in reversed(placed):
        try:
            if target in backups:
                os.replace(backups.pop(target), target)
            else:
                target.unlink(missing_ok=True)
        except OSError as exc:
            logger.warning("could not restore %s: %s", target, os_reason(exc))


@contextmanager
def replacing_files(files: Mapping[str | Path, bytes], durable: bool = True
                    ) -> Iterator[list[Path]]:
    """Write several files that belong together, kept only if the `with` block succeeds.

    Each file is written to a temporary sibling; when all are written they are renamed into
    place, an existing file being kept aside first. If a rename or the block fails, the files
    are put back as they were (previous content, or absent): all the new files remain, or none.
    Yields the paths written. A path that cannot be written is an `InputError` before any
    file is touched."""
    targets = [Path(p) for p in files]
    for path in targets:
        check_output_file(path)
    temps: list[Path] = []
    backups: dict[Path, Path] = {}
    placed: list[Path] = []
    committed = False
    current = targets[0] if targets else Path()
    try:
        try:
            for target, data in zip(targets, files.values(), strict=True):
                current = target
                temps.append(_write_temporary(target, data, durable))
            for target, tmp in zip(targets, temps, strict=True):
                current = target
                if os.path.lexists(target):
                    backups[target] = _keep_aside(target)
                os.replace(tmp, target)
                placed.append(target)
        except OSError as exc:
            raise InputError(f"cannot write the file ({os_reason(exc)})", current,
                             _FIX_FILE) from None
        yield targets
        committed = True
    finally:
        if not committed:
            _put_back(placed, backups)
        for path in (*temps, *backups.values()):
            path.unlink(missing_ok=True)


def write_files_atomic(files: Mapping[str | Path, bytes], durable: bool = True) -> list[Path]:
    """Write several files that belong together: all appear, or none does (and files they
    would replace keep their content). Returns the paths written. See `replacing_files`."""
    with replacing_files(files, durable) as written:
        return written


def check_output_dir(out_dir: Path, overwrite: bool) -> None:
    """Refuse a file (also one where a parent folder should be), or a non-empty folder unless
    `overwrite`."""
    check_output_folder(out_dir)
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
    fix = _FIX_WRITABLE
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


def _publish(tmp: Path, out_dir: Path) -> None:
    """The files of the finished `tmp` folder into `out_dir`: renamed into place when it does
    not exist yet, else moved into it one by one (replacing files of the same name, keeping
    the others)."""
    if not os.path.lexists(out_dir):
        os.replace(tmp, out_dir)
        return
    for entry in sorted(tmp.iterdir()):
        os.replace(entry, out_dir / entry.name)
    tmp.rmdir()


@contextmanager
def staged_directory(out_dir: str | Path) -> Iterator[Path]:
    """Yield a temporary folder to write an output folder's files into (a sibling of
    `out_dir`, or a hidden folder inside it when it exists).

    On success its files join `out_dir` (created when missing; files of the same name are
    replaced, others kept); on any failure it is deleted, with the parent folders this call
    created, so that a failed command leaves nothing behind. A file standing where the folder
    or one of its parents should be is an `InputError` before anything is written.
    """
    out_dir = check_output_folder(out_dir)
    if out_dir.is_dir():  # stage inside it (its parent may not be writable; "." has no name)
        created: list[Path] = []
        tmp = _temporary_sibling(out_dir / "staged", "tmp")
    else:
        created = _missing_folders(out_dir.parent)
        make_output_dir(out_dir.parent)
        tmp = _temporary_sibling(out_dir, "tmp")
    finished = False
    try:
        try:
            tmp.mkdir()
        except OSError as exc:
            raise InputError(f"cannot create the output folder ({os_reason(exc)})", out_dir,
                             _FIX_WRITABLE) from None
        yield tmp
        _publish(tmp, out_dir)
        finished = True
        logger.debug("wrote %s", out_dir)
    except OSError as exc:
        raise InputError(f"cannot write the output folder ({os_reason(exc)})", out_dir,
                         _FIX_WRITABLE) from None
    finally:
        if not finished:
            shutil.rmtree(tmp, ignore_errors=True)
            for folder in created:  # deepest first; only if still empty
                try:
                    folder.rmdir()
                except OSError:
                    break
