"""The `dream` program: its parser (the core's commands, then those of the other stages found
through the `dream.commands` entry points) and `main`, which turns every failure into one line
on stderr and an exit code."""

from __future__ import annotations

import argparse
import logging
import os
import re
import sys
from collections.abc import Sequence
from importlib.metadata import entry_points
from pathlib import Path

from dream import __version__
from dream.cli import (
    calibrate,
    demo,
    diagnose,
    eval,
    info,
    mark,
    masks,
    overlay,
    robots,
    sample,
)
from dream.errors import DreamError

log = logging.getLogger("dream")

DESCRIPTION = ("`dream` command line: thin wrappers around the library. Every failure is one "
               "line on stderr.")
ENTRY_POINT_GROUP = "dream.commands"
CORE_COMMANDS = (robots, info, overlay, masks, mark, calibrate, diagnose, eval, sample,
                 demo)  # help order
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141          # 128 + SIGPIPE, what a shell reports for a writer cut off
# a value list that starts with a minus sign: "-0.7,0.5,0.6", "-0.1,0.01,0,0", "-1e-3"
NEGATIVE_VALUES = re.compile(r"^-\.?\d[\d.eE+\-]*(,[\d.eE+\-]*)*$")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dream", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"dream {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in CORE_COMMANDS:
        command.register(sub)
    _add_stage_commands(sub)
    return parser


def _add_stage_commands(sub: argparse._SubParsersAction) -> None:
    """Commands of the other stages (synth, train, export), found through the `dream.commands`
    entry points so that the core imports none of them. Each entry point is a function
    `register(subparsers)` that adds its parser and sets `func`; it must import nothing heavy."""
    for entry in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        try:
            register = entry.load()
        except ImportError as exc:
            log.warning("command '%s' is unavailable (%s)", entry.name, exc)
            continue
        register(sub)


def joined_negative_values(argv: Sequence[str]) -> list[str]:
    """`argv` with each negative value list joined to the long option before it
    (`--look-at -0.7,0,0.4` -> `--look-at=-0.7,0,0.4`): argparse takes a value that starts
    with a minus sign and holds a comma for an option, and stops at it.

    >>> joined_negative_values(["calibrate", "--camera-guess", "-0.7,-0.5,0.6", "--seed", "-1"])
    ['calibrate', '--camera-guess=-0.7,-0.5,0.6', '--seed=-1']
    """
    out: list[str] = []
    for token in argv:
        if (out and NEGATIVE_VALUES.match(token) and out[-1].startswith("--")
                and "=" not in out[-1]):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def unrecognized_hint(extra: Sequence[str]) -> str:
    """What to do about arguments no option took: an option the command lacks is named with
    where to look; where the others are existing paths (not an unknown option's value), the
    shell most likely expanded an unquoted pattern (`--data runs/*`) into several.

    >>> unrecognized_hint(["--colour", "red"])
    ' (options this command does not take: --colour; its --help lists them)'
    """
    unknown = [token for token in extra if token.startswith("--")]
    values = {i + 1 for i, token in enumerate(extra) if token.startswith("--") and "=" not in token}
    paths = [token for i, token in enumerate(extra)
             if token and not token.startswith("-") and i not in values and Path(token).exists()]
    hints = []
    if unknown:
        hints.append(f"options this command does not take: {', '.join(unknown)}; its --help "
                     "lists them")
    if paths:
        hints.append("paths: did the shell expand an unquoted pattern? quote it, --data "
                     "'runs/*', or give one path")
    return f" ({'; '.join(hints)})" if hints else ""


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(joined_negative_values(sys.argv[1:] if argv is None
                                                                  else argv))
    if extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}{unrecognized_hint(extra)}")
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        code = args.func(args)
        sys.stdout.flush()  # a closed reader shows up here, not at interpreter exit
        return code
    except BrokenPipeError:
        # the reader of the output went away (`dream info DATA | head`): stop quietly, as
        # command-line tools do, without a second error when Python flushes stdout at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except DreamError as exc:
        print(f"dream {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"dream {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
