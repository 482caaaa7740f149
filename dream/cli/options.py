"""Option helpers shared by the `dream` commands: parsing and checking option values, reading
the `--data` of a command, adding a command's parser and turning its Namespace into a request."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, TextIO, TypeVar

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError

FIX_INTRINSICS = "give --intrinsics fx,fy,cx,cy or fx,fy,cx,cy,width,height (pixels)"
INTRINSICS_HELP = ("fx,fy,cx,cy[,width,height] in pixels, for data without intrinsics (data with "
                   "its own needs --override-intrinsics as well)")
OVERRIDE_HELP = "let --intrinsics or --camera-info replace the data's own camera"
ROBOT_HELP = "built-in robot name or URDF path (default: the data's)"
KEYPOINTS_HELP = ("comma-separated keypoint links, which a user URDF needs (dream robots --urdf "
                  "FILE suggests them; default: the model's, the labels' or the built-in "
                  "robot's)")
DATA_FILE_HELP = "dataset folder or .npz"
INTERPOLATE, AS_LOGGED = "interpolate", "as-logged"
JOINT_READINGS = (INTERPOLATE, AS_LOGGED)  # what --joint-readings does with a held joint log
INTRINSICS_RTOL = 1e-6   # --intrinsics this close to the data's own agree with them
INTRINSICS_ATOL = 1e-9   # (distortion coefficients: this close to zero)

Request = TypeVar("Request")

AUTO, EDGES, NONE = "auto", "edges", "none"
REFINE_CHOICES = (AUTO, EDGES, NONE)   # --refine of dream calibrate: what refines the pose
POLISH = "polish"   # what `--refine auto` does on data with masks: the silhouette polish


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


def camera_argument(intrinsics: str | None, camera_info: str | None = None,
                    distortion: str | None = None):
    """The readers' `intrinsics` argument from `--intrinsics`, `--camera-info` and
    `--distortion` (None when none is given)."""
    if camera_info is not None:
        if intrinsics is not None or distortion is not None:
            raise InputError("--camera-info gives the whole camera; --intrinsics and "
                             "--distortion would contradict it", fix="give one of them")
        from dream.io.camera_info import read_camera_info

        return read_camera_info(camera_info)
    given = parse_intrinsics(intrinsics)
    if distortion is None:
        return given
    if given is None:
        raise InputError("--distortion goes with --intrinsics (the camera it belongs to)",
                         fix="add --intrinsics fx,fy,cx,cy, or give --camera-info FILE")
    coeffs = _parse_distortion(distortion)
    if isinstance(given, CameraIntrinsics):
        return CameraIntrinsics(given.fx, given.fy, given.cx, given.cy, given.width,
                                given.height, coeffs)
    return tuple(given) + coeffs


def parse_numbers(text: str, counts: tuple[int, ...], option: str, fix: str
                  ) -> tuple[float, ...]:
    """The comma-separated finite numbers of an option's value, as many as one of `counts`;
    anything else is one `InputError` line naming `option`, with `fix`."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"{option} '{text}' must be comma-separated numbers", fix=fix) from None
    if len(values) not in counts or not np.all(np.isfinite(values)):
        allowed = " or ".join(str(c) for c in counts)
        raise InputError(f"{option} '{text}' must be {allowed} finite numbers", fix=fix)
    return values


def parse_frame_bounds(text: str, option: str) -> tuple[int, int]:
    """(START, STOP) of an option's `START:STOP`, its form alone (`parse_frame_range` checks
    them against a recording); anything else is one `InputError` line naming `option`.

    >>> parse_frame_bounds("2:5", "--frame-range")
    (2, 5)
    """
    try:
        start, stop = (int(v) for v in text.split(":"))
    except ValueError:
        raise InputError(f"{option} {text!r} must be START:STOP (frame indices, STOP "
                         "excluded)", fix="e.g. 10:20 (frames 10 to 19)") from None
    return start, stop


def parse_frame_range(text: str, count: int, option: str) -> range:
    """`START:STOP` of an option naming frames of a recording of `count` (indices in time
    order, STOP excluded); anything else is one `InputError` line naming `option`.

    >>> parse_frame_range("2:5", 9, "--frame-range")
    range(2, 5)
    """
    start, stop = parse_frame_bounds(text, option)
    if not 0 <= start < stop <= count:
        where = ("holds no frame (STOP must exceed START)" if 0 <= stop <= start <= count
                 else f"lies outside the {count} frames")
        raise InputError(f"{option} {text} {where}", fix=f"give 0 <= START < STOP <= {count}")
    return range(start, stop)


def frames_in_range(seq: Any, text: str | None) -> Any:
    """The frames of `seq` that `--frame-range START:STOP` names (all without it)."""
    if text is None:
        return seq
    chosen = parse_frame_range(text, len(seq), "--frame-range")
    keep = np.zeros(len(seq), bool)
    keep[chosen.start:chosen.stop] = True
    return seq.subset(keep)


def _parse_distortion(text: str) -> tuple[float, ...]:
    values = parse_numbers(text, (4, 5), "--distortion",
                           "give --distortion k1,k2,p1,p2[,k3] (OpenCV's plumb_bob order)")
    return values + (0.0,) * (5 - len(values))


def parse_keypoints(text: str | None) -> tuple[str, ...] | None:
    """The link names of `--keypoints a,b,c` (None when not given); an empty or repeated name
    is one `InputError` line."""
    if text is None:
        return None
    names = tuple(name.strip() for name in text.split(","))
    fix = "give --keypoints LINK,LINK,... (dream robots --urdf FILE suggests them)"
    if not all(names):
        raise InputError(f"--keypoints '{text}' has an empty link name", fix=fix)
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InputError(f"--keypoints '{text}' names {', '.join(repeated)} twice", fix=fix)
    return names


@dataclass(frozen=True, kw_only=True)
class DataOptions:
    """The options of the commands that read a dataset, besides `--data` itself: `--robot`
    and its `--keypoints`, the camera (`--intrinsics`, `--distortion`, `--camera-info`,
    `--override-intrinsics`) and a ROS bag's topics. The commands' requests derive from it."""

    robot: str | None = None
    keypoints: str | None = None
    intrinsics: str | None = None
    override_intrinsics: bool = False
    camera_info: str | None = None
    distortion: str | None = None
    image_topic: str | None = None
    joint_topic: str | None = None
    camera_info_topic: str | None = None

    @property
    def keypoint_links(self) -> tuple[str, ...] | None:
        """The links of `--keypoints` (None when not given)."""
        return parse_keypoints(self.keypoints)

    def topics(self):
        from dream.io.rosbag import BagTopics

        return BagTopics(self.image_topic, self.joint_topic, self.camera_info_topic)


def read_data(request: Any):
    """The `Sequence` of a request's `data` under its `DataOptions`: the camera of
    `--intrinsics` (and `--distortion`) or `--camera-info` where given, the cameras checked for
    plausibility (`dream.plausibility`). A camera given that differs from the data's own is
    refused unless `--override-intrinsics`."""
    from dream.api import read_sequence  # the reader with the cameras and times checked

    data = request.data
    if not data or not data.strip():
        raise InputError("--data is empty", fix="give --data the dataset folder or file")
    given = camera_argument(request.intrinsics, request.camera_info, request.distortion)
    topics = request.topics()
    if given is not None and not request.override_intrinsics:
        _refuse_conflicting_intrinsics(data, given, request.robot, topics)
    return read_sequence(data, intrinsics=given, robot=request.robot, topics=topics)


def _refuse_conflicting_intrinsics(data: str, given, robot: str | None, topics) -> None:
    """Refuse `--intrinsics` that differ from intrinsics the data has itself."""
    from dream.io import read_sequence

    try:
        own = read_sequence(data, robot=robot, topics=topics)
    except InputError:  # no intrinsics of its own (or an error the real read reports)
        return
    c = own.camera
    theirs = (c.fx, c.fy, c.cx, c.cy, *(c.distortion or (0.0,) * 5))
    if isinstance(given, CameraIntrinsics):
        mine = (given.fx, given.fy, given.cx, given.cy, *(given.distortion or (0.0,) * 5))
    else:
        mine = tuple(given) + (0.0,) * (len(theirs) - len(given))
    if not np.allclose(mine, theirs, rtol=INTRINSICS_RTOL, atol=INTRINSICS_ATOL):
        raise InputError(f"the camera given ({_camera_text(mine)}) differs from the data's own "
                         f"({_camera_text(theirs)})", own.source,
                         "drop --intrinsics / --camera-info to use the data's camera, or add "
                         "--override-intrinsics to replace it")


def _camera_text(values: tuple[float, ...]) -> str:
    text = ", ".join(f"{k} {v:g}" for k, v in zip(("fx", "fy", "cx", "cy"), values[:4],
                                                    strict=True))
    return text + (f", distortion {list(values[4:])}" if any(values[4:]) else "")


def joint_readings(seq: Any, interpolate: bool, out: TextIO | None = None
                   ) -> tuple[Any, dict | None]:
    """(the sequence, RESULT.json's `joint_readings` or None without timestamps): with a held
    joint log and `interpolate`, the readings interpolated in time and the frames after the
    log's last update left out (their joints are not known), said on `out`."""
    from dream.readings import (
        sequence_updates,
        with_interpolated_readings,
        without_frames_after_last_update,
    )

    updates = sequence_updates(seq)
    if updates is None or not updates.held:
        return seq, None if updates is None else updates.to_dict(interpolated=False)
    frames, late = len(seq), ()
    if interpolate:
        seq, _ = with_interpolated_readings(seq)
        seq, late = without_frames_after_last_update(seq, updates)
    if out is not None:
        done = (f"interpolated in time between the updates (--joint-readings {AS_LOGGED} keeps "
                "them)" if interpolate else "kept as logged")
        print(f"joint readings: {len(updates.update_index)} updates in {frames} frames, one "
              f"every {updates.period_s:.3f} s ({updates.repeat_fraction:.0%} of the frames "
              f"repeat the previous reading): {done}", file=out)
        if late:
            print(f"  {len(late)} frames after the log's last update left out (the last reading "
                  f"lags the arm there by up to {updates.period_s:.3f} s): {', '.join(late)}",
                  file=out)
    doc = updates.to_dict(interpolated=interpolate)
    if interpolate:
        doc["frames_left_out"] = list(late)
    return seq, doc


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


def add_data_positional(p: argparse.ArgumentParser, data_help: str = DATA_FILE_HELP) -> None:
    """The recording as the command's first argument (`dream info DATA`) or as `--data DATA`,
    as every other command takes it; `with_data` reads the one given."""
    p.add_argument("data_arg", nargs="?", metavar="DATA", help=f"{data_help} (or --data DATA)")
    p.add_argument("--data", help="the same as DATA")


def with_data(args: argparse.Namespace) -> argparse.Namespace:
    """`args` with `data` the recording given first or as `--data` (`add_data_positional`).

    >>> with_data(argparse.Namespace(command="info", data_arg=None, data="rec")).data
    'rec'

    Raises:
        InputError: neither given, or two different ones.
    """
    first, option = args.data_arg, args.data
    if first is None and option is None:
        raise InputError("no recording given",
                         fix=f"name it first, dream {args.command} DATA, or give --data DATA")
    if first is not None and option is not None and first != option:
        raise InputError(f"two recordings given, {first} and --data {option}", fix="give one")
    args.data = option if option is not None else first
    return args


DATA_HELP = ("the recording: a dataset folder (DREAM layout, panda_teleop, franka_offline, "
             "images + joints.csv), a ROS bag, or a ManiUniCon .npz")


def add_data_args(p: argparse.ArgumentParser, required: bool = True,
                  data_help: str = DATA_HELP) -> None:
    """`--data`, `--robot`, `--keypoints` and `--intrinsics`, of the commands that read a
    dataset (`data_help`: what `--data` names, for a command that reads many)."""
    p.add_argument("--data", required=required, help=data_help)
    p.add_argument("--robot", help=ROBOT_HELP)
    add_keypoints_arg(p)
    add_intrinsics_args(p)


def add_keypoints_arg(p: argparse.ArgumentParser) -> None:
    """`--keypoints LINK,LINK,...`, the keypoint links of `--robot`."""
    p.add_argument("--keypoints", metavar="LINK,LINK,...", help=KEYPOINTS_HELP)


def add_intrinsics_args(p: argparse.ArgumentParser) -> None:
    """`--intrinsics`, `--distortion`, `--camera-info`, `--override-intrinsics` and a ROS
    bag's topics."""
    p.add_argument("--image-topic", help="ROS bag: the image topic (Image or CompressedImage; "
                   "default: the bag's one image topic)")
    p.add_argument("--joint-topic", help="ROS bag: the JointState topic (default: the bag's "
                   "one); each image takes the message nearest in time")
    p.add_argument("--camera-info-topic", help="ROS bag: the CameraInfo topic (default: the "
                   "bag's one, if any)")
    p.add_argument("--intrinsics", help=INTRINSICS_HELP)
    p.add_argument("--distortion", metavar="K1,K2,P1,P2[,K3]",
                   help="plumb_bob distortion coefficients of the --intrinsics camera (OpenCV "
                        "order)")
    p.add_argument("--camera-info", metavar="FILE",
                   help="the camera from a ROS CameraInfo YAML (camera_calibration's file or an "
                        "echoed message)")
    p.add_argument("--override-intrinsics", action="store_true", help=OVERRIDE_HELP)


def add_model_source(p: argparse.ArgumentParser, model_help: str,
                     required: bool = True) -> None:
    """`--model MODEL.onnx` or `--use-labels`, one of them `required`."""
    source = p.add_mutually_exclusive_group(required=required)
    source.add_argument("--model", metavar="MODEL.onnx", help=model_help)
    source.add_argument("--use-labels", action="store_true",
                        help="take 2D observations from the labels (projected_location)")

