"""Checks shared by the frozen settings dataclasses: each named field is a positive integer
(stored as int), a positive number, or a number >= 0; one `InputError` line otherwise.

    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Search:
    ...     rounds: int = 3
    ...     def __post_init__(self):
    ...         check_fields(self, "search", positive_ints=("rounds",))
    >>> Search(rounds=0)
    Traceback (most recent call last):
    ...
    dream.errors.InputError: search parameter rounds must be a positive integer, got 0.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from dream.errors import InputError


def check_fields(settings: Any, what: str, *, positive_ints: Iterable[str] = (),
                 positive: Iterable[str] = (), non_negative: Iterable[str] = ()) -> None:
    """Check the named fields of a frozen dataclass `settings` (module doc); `what` names its
    parameters in the message ("polish", "edge")."""
    for name in positive_ints:
        value = getattr(settings, name)
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise InputError(f"{what} parameter {name} must be a positive integer, got {value}")
        object.__setattr__(settings, name, int(value))
    for name in positive:
        value = getattr(settings, name)
        if not (np.isfinite(value) and value > 0):
            raise InputError(f"{what} parameter {name} must be a positive number, got {value}")
    for name in non_negative:
        value = getattr(settings, name)
        if not (np.isfinite(value) and value >= 0):
            raise InputError(f"{what} parameter {name} must be a number >= 0, got {value}")
