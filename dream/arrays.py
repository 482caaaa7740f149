"""Small array helpers shared by the frozen dataclasses and the JSON documents."""

from __future__ import annotations

import numpy as np


def read_only(a, dtype: type = float) -> np.ndarray:
    """A read-only copy of `a` as `dtype` (for fields of frozen dataclasses)."""
    out = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out


def finite_or_none(x: float | None) -> float | None:
    """`x` as a float, or None where it is None, NaN or infinite (JSON has no NaN).

    >>> finite_or_none(np.float64(2.5)), finite_or_none(float("nan")), finite_or_none(None)
    (2.5, None, None)
    """
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None
