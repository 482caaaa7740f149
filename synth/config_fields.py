"""Checks of a recipe's fields (`synth.config`): each raises an `InputError` that names the
field, and those that convert return the value in its stored type.

    >>> value_range("camera.radius_m", [1, 2.5], 1e-3)
    (1.0, 2.5)
    >>> probability("distractors.person_prob", 1.5)
    Traceback (most recent call last):
    ...
    dream.errors.InputError: distractors.person_prob is a probability in [0, 1], got 1.5.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dream.errors import InputError
from dream.transforms import is_rigid
from synth.scene_settings import MAX_IMAGE_SIZE_PX

Range = tuple[float, float]


def value_range(name: str, value: Any, lo_limit: float = -np.inf,
                hi_limit: float = np.inf) -> Range:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a [low, high] pair of numbers, got {value!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
        raise InputError(f"{name} must satisfy low <= high, got [{lo}, {hi}]")
    if lo < lo_limit or hi > hi_limit:
        raise InputError(f"{name} must lie within [{lo_limit}, {hi_limit}], got [{lo}, {hi}]")
    return lo, hi


def whole_number(name: str, value: Any, fix: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InputError(f"{name} must be a whole number >= 1, got {value!r}", fix=fix)


def non_negative(name: str, value: float) -> float:
    if not (np.isfinite(float(value)) and float(value) >= 0.0):
        raise InputError(f"{name} must be a finite number >= 0, got {value}")
    return float(value)


def finite_number(name: str, value: Any, fix: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = np.nan
    if isinstance(value, bool) or not np.isfinite(number):
        raise InputError(f"{name} must be a finite number, got {value!r}", fix=fix)
    return number


def image_side(name: str, value: Any) -> int:
    try:
        whole = not isinstance(value, bool) and int(value) == value
    except (TypeError, ValueError, OverflowError):
        whole = False
    if not whole or not 1 <= value <= MAX_IMAGE_SIZE_PX:
        raise InputError(f"{name} must be a whole number of pixels from 1 to "
                         f"{MAX_IMAGE_SIZE_PX}, got {value!r}",
                         fix=f"set {name} between 1 and {MAX_IMAGE_SIZE_PX} (MuJoCo's offscreen "
                             "OpenGL buffer cannot render larger images with every camera model)")
    return int(value)


def rigid_rows(name: str, value) -> tuple[tuple[float, ...], ...]:
    """A 4x4 rigid transform given as rows, as a tuple of 4 tuples of floats."""
    fix = f"give {name} as 4 rows of 4 numbers: a rotation, a translation in metres"
    try:
        T = np.array(value, dtype=float)
    except (TypeError, ValueError):
        T = np.zeros(0)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"{name} must be a finite 4x4 matrix, got {value!r}", fix=fix)
    if not is_rigid(T):
        raise InputError(f"{name} is not a rigid transform (its rotation must be orthonormal "
                         "with determinant 1, its last row 0 0 0 1)", fix=fix)
    return tuple(tuple(float(v) for v in row) for row in T)


def probability(name: str, value: float) -> float:
    if not 0.0 <= float(value) <= 1.0:
        raise InputError(f"{name} is a probability in [0, 1], got {value}")
    return float(value)
