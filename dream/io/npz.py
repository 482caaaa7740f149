"""Defensive reading of `.npz` archives: array headers, whole arrays and single stack items.

Arrays are read member by member straight from the zip archive, without pickles, after their
header has been checked against the member's size, so a corrupt or hostile file gives an
`InputError` and never an unbounded allocation. One image of a stack is read without loading the
others.
"""

from __future__ import annotations

import lzma
import math
import struct
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from dream.errors import InputError
from dream.io.fields import one_line, quote

NPY_SUFFIX = ".npy"
_HEADER_READERS = {
    (1, 0): np.lib.format.read_array_header_1_0,
    (2, 0): np.lib.format.read_array_header_2_0,
}
# What the zip and npy layers raise on damaged input.
_ARCHIVE_ERRORS = (OSError, EOFError, ValueError, TypeError, KeyError, IndexError,
                   zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError,
                   struct.error, lzma.LZMAError, OverflowError, UnicodeDecodeError)
STACK_NDIM = 4              # an image stack: (N, H, W, channels)
RGB_CHANNELS = 3
_FIX = "write the file with numpy.savez / numpy.savez_compressed (no pickled objects)"


@dataclass(frozen=True)
class ArrayHeader:
    """Shape and dtype of one array of an archive, and how many data bytes it holds."""

    shape: tuple[int, ...]
    dtype: np.dtype
    fortran_order: bool
    data_bytes: int

    @property
    def nbytes(self) -> int:
        return math.prod(self.shape) * self.dtype.itemsize


def members(path: Path) -> list[str]:
    """Names of the arrays stored in the archive (without `.npy`)."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except _ARCHIVE_ERRORS as exc:
        raise InputError(f"is not a readable .npz archive ({one_line(exc)})", path,
                         _FIX) from None
    return [n[: -len(NPY_SUFFIX)] for n in names if n.endswith(NPY_SUFFIX)]


def _read_header(fp: IO[bytes], member_size: int, key: str, path: Path) -> ArrayHeader:
    version = np.lib.format.read_magic(fp)
    reader = _HEADER_READERS.get(version)
    if reader is None:
        raise InputError(f'array "{key}" uses .npy format version {version}, which is not '
                         f"supported", path, _FIX)
    shape, fortran_order, dtype = reader(fp)
    if dtype.hasobject:
        raise InputError(f'array "{key}" holds Python objects', path,
                         "store plain numeric arrays")
    if any(n < 0 for n in shape):
        raise InputError(f'array "{key}" has an invalid shape {shape}', path, _FIX)
    header = ArrayHeader(tuple(shape), dtype, bool(fortran_order), member_size - fp.tell())
    if header.nbytes > header.data_bytes:
        raise InputError(f'array "{key}" is truncated: its header announces {header.nbytes} '
                         f"bytes but only {header.data_bytes} are stored", path, _FIX)
    return header


@contextmanager
def _open_member(path: Path, key: str) -> Iterator[tuple[IO[bytes], ArrayHeader]]:
    try:
        with zipfile.ZipFile(path) as zf:
            try:
                info = zf.getinfo(key + NPY_SUFFIX)
            except KeyError:
                present = ", ".join(quote(m) for m in sorted(members(path))) or "none"
                raise InputError(f'has no array "{key}" (arrays present: {present})', path,
                                 f'store the array under the name "{key}"') from None
            with zf.open(info) as fp:
                yield fp, _read_header(fp, info.file_size, key, path)
    except _ARCHIVE_ERRORS as exc:
        raise InputError(f'cannot read array "{key}" ({one_line(exc)})', path, _FIX) from None


def read_header(path: Path, key: str) -> ArrayHeader:
    """Shape and dtype of array `key`, without reading its data."""
    with _open_member(path, key) as (_, header):
        return header


def _read_exact(fp: IO[bytes], count: int, key: str, path: Path) -> bytes:
    data = fp.read(count)
    if len(data) != count:
        raise InputError(f'array "{key}" is truncated', path, _FIX)
    return data


def read_array(path: Path, key: str) -> np.ndarray:
    """The whole array `key` (a fresh, writable copy in native byte order)."""
    with _open_member(path, key) as (fp, header):
        data = _read_exact(fp, header.nbytes, key, path)
    flat = np.frombuffer(data, dtype=header.dtype)
    order = "F" if header.fortran_order else "C"
    return flat.reshape(header.shape, order=order).astype(header.dtype.newbyteorder("="))


def read_stack_item(path: Path, key: str, index: int) -> np.ndarray:
    """Item `index` along the first axis of array `key`, reading only that item when possible."""
    with _open_member(path, key) as (fp, header):
        if len(header.shape) < 1 or not 0 <= index < header.shape[0]:
            raise InputError(f'index {index} is out of range for array "{key}" of shape '
                             f"{header.shape}", path, "use an index within the stack")
        if header.fortran_order:
            data = _read_exact(fp, header.nbytes, key, path)
            whole = np.frombuffer(data, dtype=header.dtype).reshape(header.shape, order="F")
            return np.ascontiguousarray(whole[index])
        item_shape = header.shape[1:]
        item_bytes = math.prod(item_shape) * header.dtype.itemsize
        fp.seek(index * item_bytes, 1)
        data = _read_exact(fp, item_bytes, key, path)
    return np.frombuffer(data, dtype=header.dtype).reshape(item_shape).copy()


def check_rgb_stack(header: ArrayHeader, key: str, path: Path) -> None:
    """Refuse an image stack that is not (N, H, W, 3) uint8, with the fixes its shape and its
    type ask for (channels first, RGBA, one channel, a single image; floats, 16 bits). A
    channels-first uint8 stack of images 3 pixels wide cannot be told from the right layout.

    >>> check_rgb_stack(ArrayHeader((2, 3, 4, 5), np.dtype(np.uint8), False, 120), "x",
    ...                 Path("a.npz"))
    Traceback (most recent call last):
    ...
    dream.errors.InputError: a.npz: "x" must be an (N, H, W, 3) uint8 array, got (2, 3, 4, 5) \
uint8. Fix: store the channels last: x = numpy.moveaxis(x, 1, -1)
    """
    shape, dtype = tuple(header.shape), np.dtype(header.dtype)
    if dtype == np.uint8 and len(shape) == STACK_NDIM and shape[-1] == RGB_CHANNELS:
        return
    fixes = [fix for fix in (_shape_fix(shape, key), _dtype_fix(dtype, key)) if fix]
    raise InputError(f'"{key}" must be an (N, H, W, 3) uint8 array, got {shape} {dtype}', path,
                     "; then ".join(fixes) or f"store the images as one (N, H, W, 3) uint8 RGB "
                     f"array under {key!r}")


def _shape_fix(shape: tuple[int, ...], key: str) -> str | None:
    """How to bring `shape` to (N, H, W, 3); None where it is that already."""
    if len(shape) == STACK_NDIM and shape[-1] == RGB_CHANNELS:
        return None
    if len(shape) == STACK_NDIM and shape[1] == RGB_CHANNELS:
        return f"store the channels last: {key} = numpy.moveaxis({key}, 1, -1)"
    if len(shape) == STACK_NDIM and shape[-1] == RGB_CHANNELS + 1:
        return f"drop the alpha channel: {key} = {key}[..., :3]"
    if len(shape) == STACK_NDIM and shape[-1] == 1 or len(shape) == STACK_NDIM - 1 \
            and shape[-1] != RGB_CHANNELS:
        return f"repeat the one channel: {key} = numpy.repeat({key}.reshape({key}.shape[:3] " \
               "+ (1,)), 3, axis=-1)"
    if len(shape) == STACK_NDIM - 1:
        return f"store a stack, not one image: {key} = {key}[None]"
    return f"store the images as one (N, H, W, 3) array under {key!r}"


def _dtype_fix(dtype: np.dtype, key: str) -> str | None:
    """How to bring `dtype` to uint8 colours; None where it is uint8."""
    if dtype == np.uint8:
        return None
    if dtype.kind == "f":
        return (f"store 8-bit colours: (numpy.clip({key}, 0, 1) * 255).round()"
                f".astype(numpy.uint8) for values in 0..1, numpy.clip({key}, 0, 255).round()"
                ".astype(numpy.uint8) for 0..255")
    if dtype.kind in "ui" and dtype.itemsize == 2:
        return f"store 8-bit colours: ({key} >> 8).astype(numpy.uint8) for 16-bit values"
    return f"store 8-bit colours (numpy.uint8, 0..255), not {dtype}"
