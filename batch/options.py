"""The `dream calibrate` options of a batch: the batch's own and a list line's, checked before
any work, with the files they name made absolute for workers that run elsewhere."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from batch.recordings import Listed
from dream.errors import InputError

RESULT_NAME = "RESULT.json"
ONE_THREAD = 1        # onnxruntime threads of a worker without --threads: one core each
# the options that name files whose bytes a result depends on
FILE_OPTIONS = ("model", "camera_guess", "mark", "model_extension", "camera_info", "robot")
KEYPOINT_SOURCES = ("model", "use_labels")   # `dream calibrate` takes one of them
URDF_SUFFIXES = (".urdf", ".xml")
BATCH_OPTIONS = ("data",)  # set by the batch for each recording, never by a list line
FIX_LINE_FILE = "name the file relative to the list's folder, or give its absolute path"
FIX_OPTION_FILE = ("give the path of an existing file (a relative one from the working "
                   "folder)")
FIX_LINE = ("give a list line the recording's path, then dream calibrate options of its own "
            "(dream calibrate --help lists them; the batch sets --data, --out, --overlays "
            "and --require)")


def option_files(options: Mapping[str, Any]) -> list[Path]:
    """The files the options name (a model, a guess RESULT.json, marks, an extension...)."""
    files = []
    for name in FILE_OPTIONS:
        value = options.get(name)
        if isinstance(value, str) and Path(value).is_file():
            files.append(Path(value))
    return files


def absolute_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """The options with the files they name made absolute (workers run elsewhere), and one
    onnxruntime thread per worker unless --threads says otherwise."""
    out = _files_resolved(options, Path.cwd())
    if out.get("threads") is None:
        out["threads"] = ONE_THREAD
    return out


def check_options(options: Mapping[str, Any], recording: Path, where: str = "") -> None:
    """The calibrate options checked before any work (as `dream calibrate` checks its own
    before reading the data); `where` (a list line) leads the error."""
    from dream.cli.calibrate import CalibrateRequest

    try:
        CalibrateRequest(**options, data=str(recording), out=RESULT_NAME)
    except InputError as exc:
        if not where:
            raise
        raise InputError(f"{where}: {exc.problem}", exc.path, exc.fix) from None


class _LineParser(argparse.ArgumentParser):
    """The `dream calibrate` parser of a list line: raises instead of exiting."""

    def error(self, message: str):
        raise argparse.ArgumentError(None, message)


def line_options(entry: Listed) -> dict[str, Any]:
    """The `dream calibrate` options of a list line (`Listed.argv`) as request fields, only
    those the line gives; the relative files they name taken from the list's folder.

    Raises:
        InputError: naming the line: an option `dream calibrate` lacks, a bad value, or an
            option the batch sets itself.
    """
    from dream.cli.app import joined_negative_values

    if not entry.argv or entry.source is None:     # options come only from a list's lines
        return {}
    parser = calibrate_parser(_LineParser(prog="a list line", add_help=False,
                                           allow_abbrev=False))
    for action in parser._actions:
        action.default = argparse.SUPPRESS
    try:
        options = vars(parser.parse_args(joined_negative_values(entry.argv)))
    except argparse.ArgumentError as exc:
        raise InputError(f"{entry.where}: {exc}", fix=FIX_LINE) from None
    fixed = sorted(set(options) & set(BATCH_OPTIONS))
    if fixed:
        raise InputError(f"{entry.where}: --{fixed[0]} is the batch's to set", fix=FIX_LINE)
    folder = entry.source.parent
    options = _files_resolved(options, folder)
    check_option_files(options, folder, entry.where, FIX_LINE_FILE)
    return options


def check_option_files(options: Mapping[str, Any], folder: Path, where: str = "",
                       fix: str = FIX_OPTION_FILE) -> None:
    """Each file the options name exists (relative names from `folder`, absolute ones as
    given), checked before any work; `where` (a list line) leads the error.

    Raises:
        InputError: naming the option and its file.
    """
    for name, value in options.items():
        if _names_a_file(name, value) and not (folder / value).is_file():
            relative = "" if Path(value).is_absolute() else f" in {folder}"
            lead = f"{where}: " if where else ""
            raise InputError(f"{lead}--{name.replace('_', '-')} {value}: no such file"
                             f"{relative}", fix=fix)


def _names_a_file(name: str, value: Any) -> bool:
    """Whether an option's value names a file (not a position `--camera-guess X,Y,Z` or a
    built-in robot `--robot panda`)."""
    if name not in FILE_OPTIONS or not isinstance(value, str):
        return False
    suffix = Path(value).suffix.lower()
    return {"camera_guess": suffix == ".json",
            "robot": suffix in URDF_SUFFIXES or "/" in value}.get(name, True)


def calibrate_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """`parser` given the options of `dream calibrate` (`--data` not required)."""
    from dream.cli.calibrate import add_calibrate_args
    from dream.cli.options import add_data_args

    add_data_args(parser, required=False)
    add_calibrate_args(parser)
    return parser


def _files_resolved(options: Mapping[str, Any], folder: Path) -> dict[str, Any]:
    """The options with each file they name that exists (relative names from `folder`) made
    absolute; the others as given."""
    out = dict(options)
    for name in FILE_OPTIONS:
        value = out.get(name)
        if isinstance(value, str) and (folder / value).is_file():
            out[name] = str((folder / value).resolve())
    return out
