"""Strict JSON and text reading with typed field access.

Every failure is an `InputError` that names the file, the field and the fix. JSON is parsed
strictly: `NaN`, `Infinity`, duplicate keys and numbers that overflow to infinity are refused.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from dream.errors import InputError

MAX_REPR_CHARS = 40  # how much of an offending value a message quotes
MAX_MESSAGE_CHARS = 200  # how much of a parser's own message a message quotes


def one_line(exc: BaseException) -> str:
    """A short, single-line description of an exception for an error message."""
    text = str(exc).strip().splitlines()
    first = text[0] if text else type(exc).__name__
    return first[:MAX_MESSAGE_CHARS]


def os_reason(exc: BaseException) -> str:
    """Why an OS call failed, without repeating the path (e.g. "Permission denied")."""
    return getattr(exc, "strerror", None) or one_line(exc)


def quote(text: str) -> str:
    """A name from the input, quoted and escaped so that a message stays on one line."""
    short = text if len(text) <= MAX_REPR_CHARS else text[:MAX_REPR_CHARS] + "..."
    return json.dumps(short, ensure_ascii=False)


def describe(value: Any) -> str:
    """A short description of a JSON value for an error message, e.g. 'a string "abc"'."""
    kinds = {dict: "an object", list: "a list", str: "a string", bool: "a boolean",
             int: "a number", float: "a number", type(None): "null"}
    kind = kinds.get(type(value), type(value).__name__)
    if isinstance(value, (dict, list)) or value is None:
        return kind
    text = repr(value)
    if len(text) > MAX_REPR_CHARS:
        text = text[:MAX_REPR_CHARS] + "..."
    return f"{kind} {text}"


@contextmanager
def errors_name(path: Path | None, fix: str | None = None) -> Iterator[None]:
    """Give an `InputError` raised without a file (e.g. by `CameraIntrinsics`) this file."""
    try:
        yield
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(exc.problem, path, exc.fix or fix) from None


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not a finite number")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f'duplicate key "{key}"')
        out[key] = value
    return out


def read_bytes(path: Path, fix: str | None = None) -> bytes:
    """The bytes of a file; a missing or unreadable file is an `InputError`."""
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise InputError("file not found", path, fix) from None
    except IsADirectoryError:
        raise InputError("is a folder, expected a file", path, fix) from None
    except (OSError, ValueError) as exc:  # ValueError: a path with a NUL character
        raise InputError(f"cannot read the file ({os_reason(exc)})", path, fix) from None


def load_json(path: Path, fix: str | None = None) -> Any:
    """Parse a JSON file strictly (no NaN/Infinity literals, no duplicate keys)."""
    data = read_bytes(path, fix)
    try:
        return json.loads(data, parse_constant=_reject_constant, object_pairs_hook=_unique_keys)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeError included
        raise InputError(f"is not valid JSON ({one_line(exc)})", path,
                         fix or "write valid UTF-8 JSON with finite numbers") from None


def read_text(path: Path, fix: str | None = None) -> str:
    """A UTF-8 text file's content (without the byte-order mark a spreadsheet may write)."""
    data = read_bytes(path, fix)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise InputError("is not UTF-8 text", path, fix) from None


def parse_numbers(text: str, path: Path, count: int | None = None, minimum: int | None = None,
                  fix: str | None = None) -> np.ndarray:
    """Whitespace-separated finite numbers of a text file, as a float array."""
    values = []
    for token in text.split():
        try:
            value = float(token)
        except ValueError:
            raise InputError(f"{quote(token)} is not a number", path, fix) from None
        if not math.isfinite(value):
            raise InputError(f"{quote(token)} is not a finite number", path, fix)
        values.append(value)
    if count is not None and len(values) != count:
        raise InputError(f"has {len(values)} numbers, expected {count}", path, fix)
    if minimum is not None and len(values) < minimum:
        raise InputError(f"has {len(values)} numbers, expected at least {minimum}", path, fix)
    return np.array(values, dtype=float)


def as_dict(value: Any, what: str, path: Path, fix: str | None = None) -> dict[str, Any]:
    """`value` if it is a JSON object."""
    if not isinstance(value, dict):
        raise InputError(f"{what} must be an object, got {describe(value)}", path, fix)
    return value


def as_list(value: Any, what: str, path: Path, fix: str | None = None,
            length: int | None = None) -> list[Any]:
    """`value` if it is a JSON list (of `length` items when given)."""
    if not isinstance(value, list):
        raise InputError(f"{what} must be a list, got {describe(value)}", path, fix)
    if length is not None and len(value) != length:
        raise InputError(f"{what} has {len(value)} items, expected {length}", path, fix)
    return value


def require(obj: dict[str, Any], key: str, what: str, path: Path,
            fix: str | None = None) -> Any:
    """`obj[key]`, or an `InputError` saying that `what` is missing."""
    if key not in obj:
        raise InputError(f"{what} is missing", path, fix)
    return obj[key]


def as_number(value: Any, what: str, path: Path, fix: str | None = None) -> float:
    """`value` as a finite float (booleans are not numbers)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{what} must be a number, got {describe(value)}", path, fix)
    try:
        number = float(value)
    except OverflowError:
        raise InputError(f"{what} is too large", path, fix) from None
    if not math.isfinite(number):
        raise InputError(f"{what} is not finite", path, fix)
    return number


def as_int(value: Any, what: str, path: Path, fix: str | None = None,
           minimum: int | None = None) -> int:
    """`value` as an integer (an integral float such as 640.0 is accepted)."""
    number = as_number(value, what, path, fix)
    if not number.is_integer():
        raise InputError(f"{what} must be a whole number, got {describe(value)}", path, fix)
    if minimum is not None and number < minimum:
        raise InputError(f"{what} must be at least {minimum}, got {describe(value)}", path, fix)
    return int(number)


def as_str(value: Any, what: str, path: Path, fix: str | None = None) -> str:
    """`value` if it is a non-empty JSON string."""
    if not isinstance(value, str) or not value:
        raise InputError(f"{what} must be a non-empty string, got {describe(value)}", path, fix)
    return value


def as_vector(value: Any, what: str, path: Path, length: int,
              fix: str | None = None) -> np.ndarray:
    """`value` as a (length,) float array of finite numbers."""
    items = as_list(value, what, path, fix, length)
    return np.array([as_number(v, f"{what}[{i}]", path, fix) for i, v in enumerate(items)])


def as_matrix(value: Any, what: str, path: Path, rows: int, cols: int,
              fix: str | None = None) -> np.ndarray:
    """`value` as a (rows, cols) float array of finite numbers (a list of rows)."""
    items = as_list(value, what, path, fix, rows)
    return np.stack([as_vector(row, f"{what}[{i}]", path, cols, fix)
                     for i, row in enumerate(items)])
