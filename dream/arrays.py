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


def finite_list_or_none(a: np.ndarray) -> list | None:
    """`a` as nested lists, or None where any entry is NaN or infinite (JSON has no NaN).

    >>> finite_list_or_none(np.array([1.0, 2.0])), finite_list_or_none(np.full(2, np.nan))
    ([1.0, 2.0], None)
    """
    a = np.asarray(a, dtype=float)
    return a.tolist() if np.all(np.isfinite(a)) else None
