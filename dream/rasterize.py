"""Triangles to pixels: which pixel centres lie inside a set of 2D triangles.

Exact with respect to the edge functions: a pixel centre on an edge counts as inside, the
same in any split of the work. Small triangles (most of a robot mesh seen from afar) have
every candidate pixel of every triangle tested in one flat pass; large ones are grouped by
box size and tested against whole boxes.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from dream.errors import InputError

MAX_BLOCK_PIXELS = 4_000_000    # candidate pixels tested at once
SMALL_BOX_PIXELS = 64           # triangles with at most this many candidates go in the flat pass


def _pixel_boxes(x: np.ndarray, y: np.ndarray, height: int, width: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Inclusive pixel-centre ranges (lx, ly, hx, hy) of triangles with corners x, y (3, T).

    NaN where a corner is NaN; an empty range (h < l) where no pixel centre is in the box.
    """
    with np.errstate(invalid="ignore"):
        lx = np.maximum(np.ceil(np.minimum(np.minimum(x[0], x[1]), x[2])), 0)
        ly = np.maximum(np.ceil(np.minimum(np.minimum(y[0], y[1]), y[2])), 0)
        hx = np.minimum(np.floor(np.maximum(np.maximum(x[0], x[1]), x[2])), width - 1)
        hy = np.minimum(np.floor(np.maximum(np.maximum(y[0], y[1]), y[2])), height - 1)
    return lx, ly, hx, hy


def _chunks(cumulative: np.ndarray, limit: int) -> Iterator[tuple[int, int]]:
    """Consecutive index ranges [lo, hi) whose counts (given as a cumulative sum) stay within
    `limit`, at least one item each."""
    lo = 0
    while lo < len(cumulative):
        before = cumulative[lo - 1] if lo else 0
        hi = max(lo + 1, int(np.searchsorted(cumulative, before + limit, side="right")))
        yield lo, hi
        lo = hi


def rasterize_triangles(uv_triangles: np.ndarray, height: int, width: int) -> np.ndarray:
    """Pixels whose centre lies inside (or on the edge of) at least one triangle.

    Every pixel centre in a triangle's bounding box is a candidate, tested with the three edge
    functions: the candidates of small triangles all at once, large triangles' boxes grouped
    by size (in chunks of `MAX_BLOCK_PIXELS` candidates).

    Args:
        uv_triangles: (T, 3, 2) triangle corners in pixels (docs/data_format.md#conventions);
            rows with a non-finite corner are skipped.
        height, width: image size in pixels.
    Returns:
        (height, width) bool.

    Example:
        >>> int(rasterize_triangles(np.array([[[0., 0.], [4., 0.], [0., 4.]]]), 5, 5).sum())
        15
    """
    tri = np.asarray(uv_triangles, dtype=float)
    if tri.ndim != 3 or tri.shape[1:] != (3, 2):
        raise InputError(f"uv_triangles has shape {tri.shape}, expected (T, 3, 2)")
    if int(height) != height or int(width) != width or height < 1 or width < 1:
        raise InputError(f"image size must be positive integers, got {width}x{height}")
    x, y = np.ascontiguousarray(tri.transpose(2, 1, 0))
    return rasterize_corners(x, y, int(height), int(width))


def rasterize_corners(x: np.ndarray, y: np.ndarray, height: int, width: int) -> np.ndarray:
    """`rasterize_triangles` of corners given as x, y (3, T) each (no input checks)."""
    mask = np.zeros(height * width, dtype=bool)
    lx, ly, hx, hy = _pixel_boxes(x, y, height, width)
    with np.errstate(invalid="ignore", over="ignore"):
        area2 = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0])
        keep = np.isfinite(area2) & (area2 != 0) & (hx >= lx) & (hy >= ly)
    lx, ly, hx, hy = (np.where(keep, a, 0).astype(np.int64) for a in (lx, ly, hx, hy))
    boxes = np.stack([lx, ly, hx - lx + 1, hy - ly + 1])               # (4, T) x, y, w, h
    small = keep & (boxes[2] * boxes[3] <= SMALL_BOX_PIXELS)
    for chosen, fill in ((small, _fill_small), (keep & ~small, _fill_large)):
        idx = np.flatnonzero(chosen)
        fill(mask, width, x[:, idx], y[:, idx], np.sign(area2[idx]), boxes[:, idx])
    return mask.reshape(height, width)


def _inside(x: np.ndarray, y: np.ndarray, sign: np.ndarray, px: np.ndarray, py: np.ndarray
            ) -> np.ndarray:
    """Whether pixel centres (px, py) lie in or on triangles x, y (3, ...) of orientation sign."""
    inside = np.ones(np.broadcast_shapes(px.shape, py.shape, sign.shape), dtype=bool)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        inside &= sign * ((x[b] - x[a]) * (py - y[a]) - (y[b] - y[a]) * (px - x[a])) >= 0
    return inside


def _fill_small(mask: np.ndarray, width: int, x: np.ndarray, y: np.ndarray, sign: np.ndarray,
                boxes: np.ndarray) -> None:
    """Test every candidate of every triangle at once, one candidate per entry."""
    count = boxes[2] * boxes[3]                                          # candidates per triangle
    cumulative = np.cumsum(count)
    for lo, hi in _chunks(cumulative, MAX_BLOCK_PIXELS):
        t = np.repeat(np.arange(lo, hi), count[lo:hi])                 # triangle of a candidate
        offset = np.arange(len(t)) - (cumulative[t] - count[t] - (cumulative[lo] - count[lo]))
        px = boxes[0, t] + offset % boxes[2, t]
        py = boxes[1, t] + offset // boxes[2, t]
        inside = _inside(x[:, t], y[:, t], sign[t], px, py)
        mask[(py * width + px)[inside]] = True


def _fill_large(mask: np.ndarray, width: int, x: np.ndarray, y: np.ndarray, sign: np.ndarray,
                boxes: np.ndarray) -> None:
    """Test triangles grouped by box size (rounded up to powers of two) against whole boxes."""
    rounded = _pow2_ceil(boxes[2:])
    keys = rounded[0] * (2 * int(rounded.max(initial=1)) + 1) + rounded[1]
    for key in np.unique(keys):
        members = np.flatnonzero(keys == key)
        bw, bh = (int(v) for v in rounded[:, members[0]])
        ox, oy = (g.reshape(-1) for g in np.meshgrid(np.arange(bw), np.arange(bh)))
        step = max(1, MAX_BLOCK_PIXELS // (bw * bh))
        for start in range(0, len(members), step):
            idx = members[start:start + step]
            px, py = boxes[0, idx, None] + ox, boxes[1, idx, None] + oy
            inside = (ox < boxes[2, idx, None]) & (oy < boxes[3, idx, None])
            inside &= _inside(x[:, idx, None], y[:, idx, None], sign[idx, None], px, py)
            mask[(py * width + px)[inside]] = True


def _pow2_ceil(n: np.ndarray) -> np.ndarray:
    return np.left_shift(1, np.ceil(np.log2(np.maximum(n, 1))).astype(np.int64))
