"""Triangles to pixels: which pixel centres lie inside a set of 2D triangles.

Exact with respect to the edge functions: a pixel centre on an edge counts as inside. Every
pixel centre in a triangle's bounding box is tested with its three edge functions, in one
compiled loop over the triangles (numba, without the GIL: frames render in parallel threads).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from dream.errors import InputError


def rasterize_triangles(uv_triangles: np.ndarray, height: int, width: int) -> np.ndarray:
    """Pixels whose centre lies inside (or on the edge of) at least one triangle.

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
    corners = tri.reshape(-1, 2)
    return rasterize_faces(corners[:, 0], corners[:, 1],
                           np.arange(len(corners)).reshape(-1, 3), int(height), int(width))


def rasterize_faces(u: np.ndarray, v: np.ndarray, faces: np.ndarray, height: int,
                    width: int) -> np.ndarray:
    """`rasterize_triangles` of triangles `faces` (T, 3) over vertex pixels u, v (V,) each (no
    input checks): the corners read in the compiled loop, not gathered into (T, 3, 2) first."""
    return _fill(np.ascontiguousarray(u, dtype=np.float64),
                 np.ascontiguousarray(v, dtype=np.float64),
                 np.ascontiguousarray(faces, dtype=np.int64), int(height), int(width))


@numba.njit(cache=True, nogil=True)
def _fill(u: np.ndarray, v: np.ndarray, faces: np.ndarray, height: int, width: int
          ) -> np.ndarray:
    mask = np.zeros((height, width), dtype=np.bool_)
    for t in range(faces.shape[0]):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        x0, x1, x2 = u[a], u[b], u[c]
        y0, y1, y2 = v[a], v[b], v[c]
        area2 = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if not math.isfinite(area2) or area2 == 0.0:
            continue                       # a corner not finite, or no area
        lx = max(math.ceil(min(min(x0, x1), x2)), 0.0)
        ly = max(math.ceil(min(min(y0, y1), y2)), 0.0)
        hx = min(math.floor(max(max(x0, x1), x2)), width - 1.0)
        hy = min(math.floor(max(max(y0, y1), y2)), height - 1.0)
        if hx < lx or hy < ly:
            continue                       # no pixel centre in the box
        sign = 1.0 if area2 > 0.0 else -1.0
        for row in range(int(ly), int(hy) + 1):
            pv = float(row)
            for col in range(int(lx), int(hx) + 1):
                pu = float(col)
                if (sign * ((x1 - x0) * (pv - y0) - (y1 - y0) * (pu - x0)) >= 0.0
                        and sign * ((x2 - x1) * (pv - y1) - (y2 - y1) * (pu - x1)) >= 0.0
                        and sign * ((x0 - x2) * (pv - y2) - (y0 - y2) * (pu - x2)) >= 0.0):
                    mask[row, col] = True
    return mask
