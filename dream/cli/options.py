"""Option helpers shared by the `dream` commands: parsing and checking option values, reading
the `--data` of a command, adding a command's parser and turning its Namespace into a request."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import fields
from typing import Any, TextIO, TypeVar

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError

FIX_INTRINSICS = "give --intrinsics fx,fy,cx,cy or fx,fy,cx,cy,width,height (pixels)"
INTRINSICS_HELP = ("fx,fy,cx,cy[,width,height] in pixels, for data without intrinsics (data with "
                   "its own needs --override-intrinsics as well)")
OVERRIDE_HELP = "let --intrinsics replace the data's own intrinsics"
ROBOT_HELP = "built-in robot name or URDF path (default: the data's)"
DATA_FILE_HELP = "dataset folder or .npz"
INTERPOLATE, AS_LOGGED = "interpolate", "as-logged"
JOINT_READINGS = (INTERPOLATE, AS_LOGGED)  # what --joint-readings does with a held joint log
INTRINSICS_RTOL = 1e-6   # --intrinsics this close to the data's own agree with them

Request = TypeVar("Request")


def parse_intrinsics(text: str | None) -> CameraIntrinsics | tuple[float, ...] | None:
    """'fx,fy,cx,cy' (size from the images) or 'fx,fy,cx,cy,width,height'; a bad value is an
    `InputError` naming the option (not the data's camera file)."""
    if text is None:
        return None
    from dream.io import parse_intrinsics_text

    parts = text.split(",")
    if len(parts) != 6:
        return parse_intrinsics_text(text, "--intrinsics")
    try:
        w, h = int(parts[4]), int(parts[5])
    except ValueError:
        raise InputError(f"--intrinsics '{text}': width and height must be integers",
                         fix=FIX_INTRINSICS) from None
    fx_fy_cx_cy = parse_intrinsics_text(",".join(parts[:4]), "--intrinsics")
    try:
        return CameraIntrinsics(*fx_fy_cx_cy, w, h)
    except InputError as exc:
        raise InputError(f"--intrinsics '{text}': {exc.problem}", fix=FIX_INTRINSICS) from None


def check_positive(value: int | None, option: str, fix: str) -> None:
    """A whole-number option that must be >= 1 when given (None: its default)."""
    if value is not None and value < 1:
        raise InputError(f"{option} must be 1 or more, got {value}", fix=fix)


def check_seed(seed: int | None) -> None:
    """`--seed`: a whole number >= 0 when given (None: the command's default)."""
    if seed is not None and seed < 0:
        raise InputError(f"--seed must be a whole number >= 0, got {seed}",
                         fix="give --seed 0 or a positive integer")


def read_data(data: str, intrinsics: str | None = None, robot: str | None = None,
              override_intrinsics: bool = False):
    """The `Sequence` of `--data`, with the camera of `--intrinsics` where given, its cameras
    checked for plausibility (`dream.plausibility`). `--intrinsics` that differ from the data's
    own are refused unless `override_intrinsics`."""
    from dream.io import read_sequence
    from dream.plausibility import check_sequence_cameras

    if not data or not data.strip():
        raise InputError("--data is empty", fix="give --data the dataset folder or file")
    given = parse_intrinsics(intrinsics)
    if given is not None and not override_intrinsics:
        _refuse_conflicting_intrinsics(data, given, robot)
    seq = read_sequence(data, intrinsics=given, robot=robot)
    check_sequence_cameras(seq)
    return seq


def _refuse_conflicting_intrinsics(data: str, given, robot: str | None) -> None:
    """Refuse `--intrinsics` that differ from intrinsics the data has itself."""
    from dream.io import read_sequence

    try:
        own = read_sequence(data, robot=robot)
    except InputError:  # no intrinsics of its own (or an error the real read reports)
        return
    mine = tuple(given[:4]) if not isinstance(given, CameraIntrinsics) else \
        (given.fx, given.fy, given.cx, given.cy)
    theirs = (own.camera.fx, own.camera.fy, own.camera.cx, own.camera.cy)
    if not np.allclose(mine, theirs, rtol=INTRINSICS_RTOL, atol=0.0):
        raise InputError(f"--intrinsics {','.join(f'{v:g}' for v in mine)} differ from the "
                         f"data's own (fx {theirs[0]:g}, fy {theirs[1]:g}, cx {theirs[2]:g}, "
                         f"cy {theirs[3]:g})", own.source,
                         "drop --intrinsics to use the data's camera, or add "
                         "--override-intrinsics to replace it")


def joint_readings(seq: Any, interpolate: bool, out: TextIO | None = None
                   ) -> tuple[Any, dict | None]:
    """(the sequence, RESULT.json's `joint_readings` or None without timestamps): with a held
    joint log, the readings interpolated in time when `interpolate`, said on `out`."""
    from dream.readings import sequence_updates, with_interpolated_readings

    updates = sequence_updates(seq)
    if updates is None or not updates.held:
        return seq, None if updates is None else updates.to_dict(interpolated=False)
    if interpolate:
        seq, _ = with_interpolated_readings(seq)
    if out is not None:
        done = (f"interpolated in time between the updates (--joint-readings {AS_LOGGED} keeps "
                "them)" if interpolate else "kept as logged")
        print(f"joint readings: {len(updates.update_index)} updates in {len(seq)} frames, one "
              f"every {updates.period_s:.3f} s ({updates.repeat_fraction:.0%} of the frames "
              f"repeat the previous reading): {done}", file=out)
    return seq, updates.to_dict(interpolated=interpolate)


def request_from(cls: type[Request], args: argparse.Namespace) -> Request:
    """The request dataclass `cls` made of the options of `args` that are its fields (the
    others keep the field's default)."""
    names = {f.name for f in fields(cls)}
    return cls(**{k: v for k, v in vars(args).items() if k in names})


def add_command(sub: argparse._SubParsersAction, name: str,
                fn: Callable[[argparse.Namespace], int], help_: str) -> argparse.ArgumentParser:
    """A command's parser, whose handler `fn` `dream.cli.app.main` calls."""
    p = sub.add_parser(name, help=help_, description=help_)
    p.set_defaults(func=fn)
    return p


def add_data_args(p: argparse.ArgumentParser, required: bool = True) -> None:
    """`--data`, `--robot` and `--intrinsics`, of the commands that read a dataset."""
    p.add_argument("--data", required=required, help="dataset folder (DREAM layout, "
                   "panda_teleop, franka_offline) or ManiUniCon .npz")
    p.add_argument("--robot", help=ROBOT_HELP)
    add_intrinsics_args(p)


def add_intrinsics_args(p: argparse.ArgumentParser) -> None:
    """`--intrinsics` and `--override-intrinsics`."""
    p.add_argument("--intrinsics", help=INTRINSICS_HELP)
    p.add_argument("--override-intrinsics", action="store_true", help=OVERRIDE_HELP)


def add_model_source(p: argparse.ArgumentParser, model_help: str) -> None:
    """`--model MODEL.onnx` or `--use-labels`, one of them required."""
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--model", metavar="MODEL.onnx", help=model_help)
    source.add_argument("--use-labels", action="store_true",
                        help="take 2D observations from the labels (projected_location)")

