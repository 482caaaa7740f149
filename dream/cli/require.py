"""`--require {good,check}`: the verdict below which `dream calibrate` (exit 3) and `dream batch
calibrate` (exit 1) fail, for scripts that must not go on with a calibration to check or an
unreliable one; the result is written all the same."""

from __future__ import annotations

import argparse
import sys

from dream.quality import CHECK, GOOD, LEVELS

EXIT_BELOW_REQUIRED = 3   # `dream calibrate`: the result is written, its verdict below --require


def add_require_arg(p: argparse.ArgumentParser, help_: str) -> None:
    """`--require {good,check}` (`unreliable` is nothing to require)."""
    p.add_argument("--require", choices=(GOOD, CHECK), help=help_)


def below_required(verdict: str | None, required: str | None) -> bool:
    """Whether `verdict` ranks below `required` (`dream.quality.LEVELS`, best first; None
    requires nothing); a missing or unknown verdict is below anything required.

    >>> below_required("check", "good"), below_required("check", "check")
    (True, False)
    >>> below_required(None, "check"), below_required(None, None)
    (True, False)
    """
    if required is None:
        return False
    return verdict not in LEVELS or LEVELS.index(verdict) > LEVELS.index(required)


def required_exit(verdict: str, required: str | None, result: str) -> int:
    """`dream calibrate`'s exit code: `EXIT_BELOW_REQUIRED` with one line on stderr where
    `verdict` falls below `required`, else 0."""
    if not below_required(verdict, required):
        return 0
    print(f"dream calibrate: the verdict is {verdict}, below --require {required} ({result} "
          "is written: its quality.warnings say why and what to do)", file=sys.stderr)
    return EXIT_BELOW_REQUIRED
