"""Numbers and text of the report: significant digits, 'n/a' for missing values, Markdown-safe
table cells, and the parts of diagnosis.json that the text and the plots both read."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any


def num(x: Any) -> float | None:
    """A finite float, or None (also for text such as a frame name "000012")."""
    if isinstance(x, (bool, str)) or x is None:
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def fmt(x: Any, digits: int = 3) -> str:
    """A number with `digits` significant digits, 'n/a' for missing ones, text as is."""
    v = num(x)
    if v is None:
        return "n/a" if x is None or isinstance(x, (int, float)) else cell(str(x))
    if v == 0:
        return "0"
    if abs(v) >= 1e5 or abs(v) < 1e-3:
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}" if abs(v) < 10 ** digits else f"{v:.0f}"


def fmt_p(p: Any) -> str:
    v = num(p)
    if v is None:
        return "n/a"
    return "< 1e-12" if v < 1e-12 else fmt(v, 2)


def cell(text: Any) -> str:
    """Text safe inside a Markdown table cell."""
    return re.sub(r"\s+", " ", str(text)).replace("|", "\\|").strip()


def effect_entries(diagnosis: Mapping) -> list[Mapping]:
    effects = diagnosis.get("effects") or []
    return [e for e in effects if isinstance(e, Mapping)]


def verdict_names(diagnosis: Mapping) -> list[str]:
    return [str(v) for v in (diagnosis.get("verdict") or [])]
