"""Small array helpers shared by the frozen dataclasses."""

from __future__ import annotations

import numpy as np


def read_only(a, dtype: type = float) -> np.ndarray:
    """A read-only copy of `a` as `dtype` (for fields of frozen dataclasses)."""
    out = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out
