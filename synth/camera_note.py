"""The one-line note `dream synth` gives when fixed intrinsics override a random field of view.

`intrinsics.fx, fy, cx, cy` fix the camera; a recipe that also draws a random horizontal field
of view (`intrinsics.hfov_rad`: the built-in recipe, `real_world.yaml`, or any recipe that gives
`hfov_rad` with fixed intrinsics) then renders that one lens only, and the randomisation is not
used. The note says so and how to randomise around the fixed camera instead: leave fx..cy out
and give `hfov_rad` a range around the camera's own field of view (square pixels, centred
principal point: how a random field of view is drawn).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from dream.recipe import merge, parse_override
from synth.config import Intrinsics, SynthConfig, load_config

FIXED_KEYS = ("fx", "fy", "cx", "cy")
HFOV_KEY = "hfov_rad"
HFOV_SPREAD_FRACTION = 0.1   # the suggested range: the camera's field of view +-10 %
SUGGESTION_DECIMALS = 2      # radians in the suggested --set


def _given_intrinsics(path: str | Path | None, overrides: Sequence[str]) -> dict[str, Any]:
    """The `intrinsics` keys the recipe file and the overrides give (before defaults)."""
    doc: dict[str, Any] = {}
    if path is not None:
        doc = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    for text in overrides:
        doc = merge(doc, parse_override(text))
    given = doc.get("intrinsics")
    return given if isinstance(given, dict) else {}


def _recipe_draws_lenses(path: str | Path | None, overrides: Sequence[str]) -> bool:
    """True when the recipe, without the overrides, draws a random field of view, or when it
    gives `hfov_rad` explicitly (in the file or an override)."""
    return not load_config(path).intrinsics.fixed or HFOV_KEY in _given_intrinsics(path,
                                                                                    overrides)


def camera_hfov_rad(intrinsics: Intrinsics) -> float:
    """The horizontal field of view of fixed intrinsics (pinhole, principal point ignored)."""
    return 2.0 * math.atan(intrinsics.width / (2.0 * intrinsics.fx))


def fixed_camera_note(config: SynthConfig, path: str | Path | None,
                      overrides: Sequence[str] = ()) -> str | None:
    """One line when fixed intrinsics override the recipe's random field of view, else None.

    Args:
        config: the loaded recipe (`load_config(path, overrides)`).
        path: the recipe file (None: the built-in recipe).
        overrides: the `KEY=VALUE` overrides it was loaded with.
    """
    c = config.intrinsics
    if not c.fixed or not _recipe_draws_lenses(path, overrides):
        return None
    lo, hi = c.hfov_rad
    hfov = camera_hfov_rad(c)
    low = round(hfov * (1.0 - HFOV_SPREAD_FRACTION), SUGGESTION_DECIMALS)
    high = round(hfov * (1.0 + HFOV_SPREAD_FRACTION), SUGGESTION_DECIMALS)
    return (f"intrinsics.{', '.join(FIXED_KEYS)} fix the camera (horizontal field of view "
            f"{math.degrees(hfov):.1f} deg at width {c.width}), so the recipe's random field of "
            f"view (intrinsics.{HFOV_KEY} {math.degrees(lo):.0f}-{math.degrees(hi):.0f} deg) is "
            f"not used; to randomise around this camera instead, leave fx, fy, cx, cy out and "
            f"give --set \"intrinsics.{HFOV_KEY}=[{low},{high}]\" (square pixels, centred "
            "principal point)")
