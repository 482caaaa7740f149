"""`dream info`: a summary of a dataset (frames, robot, camera, labels, truth, joints)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from dream.cli.options import (
    DataOptions,
    add_command,
    add_data_positional,
    add_intrinsics_args,
    read_data,
    request_from,
    with_data,
)


@dataclass(frozen=True)
class InfoRequest(DataOptions):
    """What `dream info` does: the options of its command line."""

    data: str


def run_info(request: InfoRequest) -> None:
    """The summary of `request.data`, printed."""
    seq = read_data(request)
    robot = _load_robot(seq)
    cam = seq.camera
    print(f"data:      {request.data} ({len(seq)} frames)")
    print(f"robot:     {_robot_words(seq, robot)}")
    dist = "none" if cam.distortion is None else ", ".join(f"{c:.4g}" for c in cam.distortion)
    print(f"camera:    {cam.width}x{cam.height} fx={cam.fx:.2f} fy={cam.fy:.2f} cx={cam.cx:.2f} "
          f"cy={cam.cy:.2f} distortion: {dist}")
    if seq.has_frame_cameras:
        fx = [seq.frame_camera(i).fx for i in range(len(seq))]
        print(f"           frames carry their own intrinsics: fx {min(fx):.2f} to {max(fx):.2f} "
              "(solve them with --frames each)")
    frames = seq.frames
    print(f"images:    {sum(f.image_path is not None for f in frames)}   masks: "
          f"{sum(f.mask_path is not None for f in frames)}   timestamps: "
          f"{sum(f.timestamp is not None for f in frames)}")
    labelled = sum(f.uv_labels is not None for f in frames)
    print(f"labels:    {labelled} frames with 2D keypoint labels "
          f"({', '.join(seq.keypoint_names) or 'none'})")
    truth = sum(f.T_cam_base_true is not None for f in frames)
    print(f"truth:     {truth} frames with ground-truth pose; reference extrinsic: "
          f"{'yes' if seq.T_cam_base_reference is not None else 'no'}")
    if frames[0].timestamp is not None and len(frames) > 1:
        t = np.array([f.timestamp for f in frames if f.timestamp is not None])
        print(f"time:      {t[-1] - t[0]:.3f} s, median period {np.median(np.diff(t)):.4f} s")
    q = seq.joints
    print("joints (min .. max):")
    for name, lo, hi in zip(seq.joint_names, q.min(0), q.max(0), strict=True):
        print(f"  {name:24s} {lo:+.4f} .. {hi:+.4f}")
    problem = None if isinstance(robot, str) else _readings_problem(seq, robot)
    if problem:
        print(f"warning:   {problem} (dream calibrate refuses them)")


def _load_robot(seq):
    """The robot the data names (or its layout's default), or why it cannot be loaded."""
    from dream.errors import DreamError
    from dream.robot import load_robot

    try:
        return load_robot(seq.robot)
    except DreamError as exc:
        return str(exc)


def _readings_problem(seq, robot) -> str | None:
    """Why the joint readings do not fit `robot` (degrees...), None where they fit or the
    data lacks some of its joints (`_robot_words` says so)."""
    from dream.errors import DreamError
    from dream.plausibility import check_robot_readings

    if any(n not in seq.joint_names for n in robot.joint_names):
        return None
    try:
        check_robot_readings(seq, robot)
    except DreamError as exc:
        return str(exc.problem)
    return None


def _robot_words(seq, robot) -> str:
    """The robot's name, and whether the data's joints fit it (`robot`: the loaded robot, or
    why it could not be loaded)."""
    if isinstance(robot, str):
        return f"{seq.robot} (cannot be loaded: {robot})"
    missing = [n for n in robot.joint_names if n not in seq.joint_names]
    if not missing:
        return seq.robot
    return (f"{seq.robot}, but the data has no joint {missing[0]}: give the commands --robot "
            "with the arm (or its URDF file) the data was recorded on")


def cmd_info(args: argparse.Namespace) -> int:
    run_info(request_from(InfoRequest, with_data(args)))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream info` parser."""
    p = add_command(sub, "info", cmd_info,
                    "summarise a dataset: frames, robot, camera, labels, truth")
    add_data_positional(p)
    add_intrinsics_args(p)
    p.add_argument("--robot", help="the arm the data was recorded on (built-in name or URDF "
                   "path; default: the data's): says whether the joints fit it")
