"""A contact sheet of a written dataset: the first frames side by side, keypoint labels drawn.

What a recipe's randomisation does is easiest to judge by eye; `dream synth --contact-sheet
FILE` writes one after rendering.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from dream.errors import InputError
from dream.io import read_sequence, write_bytes_atomic
from dream.io.images import encode_png, load_image
from dream.overlay import draw_skeleton

SHEET_FRAMES = 16     # frames on a sheet
SHEET_COLUMNS = 4
TILE_WIDTH_PX = 320   # each frame is scaled to this width (its aspect kept)


def contact_sheet(folder: str | Path, num_frames: int = SHEET_FRAMES,
                  columns: int = SHEET_COLUMNS) -> np.ndarray:
    """(H, W, 3) uint8 RGB: the first `num_frames` frames of the dataset in `folder`, in rows of
    `columns`, each with its in-image keypoint labels as dots.

    Raises:
        InputError: not a dataset folder, or `num_frames` / `columns` below 1.
    """
    if num_frames < 1 or columns < 1:
        raise InputError(f"a contact sheet needs at least one frame and one column, got "
                         f"{num_frames} frames in {columns} columns")
    sequence = read_sequence(folder)
    images = []
    for frame in sequence.frames[:num_frames]:
        rgb = load_image(frame)
        if frame.uv_labels is not None:
            rgb = draw_skeleton(rgb, frame.uv_labels, ())
        images.append(rgb)
    return tile(images, columns)


def tile(images: list[np.ndarray], columns: int = SHEET_COLUMNS,
         tile_width_px: int = TILE_WIDTH_PX) -> np.ndarray:
    """(H, W, 3) uint8 RGB: `images` (each (h, w, 3) uint8) scaled to `tile_width_px` wide
    (aspect kept) in rows of `columns`, the last row padded with black.

    >>> sheet = tile([np.zeros((48, 64, 3), np.uint8)] * 3, columns=2, tile_width_px=32)
    >>> sheet.shape
    (48, 64, 3)
    """
    if not images or columns < 1:
        raise InputError(f"a sheet needs at least one image and one column, got {len(images)} "
                         f"images in {columns} columns")
    tiles = []
    for rgb in images:
        height = round(rgb.shape[0] * tile_width_px / rgb.shape[1])
        tiles.append(cv2.resize(rgb, (tile_width_px, height), interpolation=cv2.INTER_AREA))
    height = max(t.shape[0] for t in tiles)
    blank = np.zeros((height, tile_width_px, 3), np.uint8)
    tiles = [np.pad(t, ((0, height - t.shape[0]), (0, 0), (0, 0))) for t in tiles]
    tiles += [blank] * (-len(tiles) % columns)
    rows = [np.hstack(tiles[i:i + columns]) for i in range(0, len(tiles), columns)]
    return np.vstack(rows)


def write_contact_sheet(folder: str | Path, out_path: str | Path,
                        num_frames: int = SHEET_FRAMES) -> Path:
    """Write `contact_sheet(folder, num_frames)` as a PNG at `out_path` (atomically)."""
    out_path = Path(out_path)
    if out_path.suffix.lower() != ".png":
        raise InputError("the contact sheet is written as PNG", out_path,
                         "give a file name ending in .png")
    write_bytes_atomic(out_path, encode_png(contact_sheet(folder, num_frames), out_path))
    return out_path
