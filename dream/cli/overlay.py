"""`dream overlay`: the robot's outline, projected keypoints and skeleton drawn on the images of
a dataset, at its reference extrinsic or at the poses a RESULT.json wrote."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dream.cli.options import (
    ROBOT_HELP,
    DataOptions,
    add_command,
    add_data_positional,
    add_intrinsics_args,
    add_keypoints_arg,
    read_data,
    request_from,
    with_data,
)
from dream.errors import InputError


@dataclass(frozen=True)
class OverlayRequest(DataOptions):
    """What `dream overlay` does: the options of its command line."""

    data: str
    out: str
    extrinsic: str | None = None
    limit: int | None = None

    def __post_init__(self) -> None:
        from dream.overlay import check_limit

        check_limit(self.limit)


def run_overlay(request: OverlayRequest) -> int:
    """The overlays of `request.data` drawn with `request.extrinsic` (default: the data's
    reference) into `request.out`; returns how many were written."""
    from dream.coarse.timing import with_lag
    from dream.io import check_output_folder
    from dream.overlay import write_skeleton_overlays
    from dream.readings import solved_readings
    from dream.result import read_result

    check_output_folder(request.out)  # before any reading or drawing
    seq = read_data(request)
    robot, skeleton = _robot(seq, request)
    carried = away = None
    if request.extrinsic is not None:
        doc = read_result(request.extrinsic)
        seq = solved_readings(seq, doc)
        poses = _result_poses(doc, seq)
        seq = _with_result_intrinsics(doc, seq)
        seq = with_lag(seq, _result_lag(doc))
        carried = _carried(doc, robot)
        away = _away(doc, seq, robot)
    else:
        from dream.pipeline import truth_poses

        if not seq.has_ground_truth:
            raise InputError("the data has no reference extrinsic", request.data,
                             "pass --extrinsic RESULT.json")
        poses = truth_poses(seq)
    n = write_skeleton_overlays(seq, robot, poses, Path(request.out), limit=request.limit,
                                skeleton=skeleton, carried=carried, away=away)
    print(f"wrote {n} overlay images to {request.out}")
    return n


def _robot(seq, request: OverlayRequest):
    """The robot to draw, and whether with its keypoints: a user URDF without `--keypoints`
    is drawn as its outline alone (no keypoints are needed for it; meshes that cannot be
    loaded are then an error, not overlays with nothing drawn)."""
    from dream.errors import RobotError
    from dream.pipeline import robot_for

    try:
        return robot_for(seq, request.robot, option_keypoints=request.keypoint_links), True
    except RobotError:
        if request.keypoint_links is not None:
            raise
    from dream.cli.search_robot import robot_for_search
    from dream.silhouette import load_robot_meshes

    robot = robot_for_search(seq, request)
    load_robot_meshes(robot)        # the outline is all there is to draw: its meshes must load
    print("no --keypoints for this URDF: drawing the outline alone")
    return robot, False


def _carried(doc: dict, robot) -> dict | None:
    """The result's box around something the URDF lacks (RESULT.json `start.carried`), where
    its search named one on a link of `robot`; says so, since the box is drawn in magenta."""
    from dream.overlay import names_box

    carried = (doc.get("start") or {}).get("carried") or {}
    if not names_box(carried, robot):
        return None
    print(f"magenta box: something the URDF lacks moving with {carried['named']}, as the "
          f"calibration sized it")
    return carried


def _away(doc: dict, seq, robot) -> dict | None:
    """The moving pixels away from the robot in the frames the result's search compared, where
    its verdict counted them (`dream.overlay_search.away_pixels`); says so, since they are
    tinted orange."""
    from dream.overlay_search import away_pixels

    if doc.get("start") is None:
        return None
    away = away_pixels(seq, robot, doc)
    if away:
        print(f"orange: moving pixels away from the robot in the {len(away)} frames the search "
              f"compared, not counted as robot")
    return away


def _result_lag(doc: dict) -> float:
    """The joint log's lag a result's search adopted (RESULT.json `start.timing`; s), or 0."""
    timing = (doc.get("start") or {}).get("timing")
    return float(timing["seconds"]) if timing and timing.get("adopted") else 0.0


def _with_result_intrinsics(doc: dict, seq):
    """The sequence through the intrinsics the result's calibration fitted and adopted
    (`dream.result.adopted_intrinsics`): its pose was found with them."""
    from dream.result import adopted_intrinsics

    used = adopted_intrinsics(doc)
    if not used:
        return seq
    def shown(value) -> str:
        return (f"({', '.join(f'{c:.3f}' for c in value)})" if isinstance(value, tuple)
                else f"{value:.2f}")

    camera = seq.camera
    data = ", ".join(shown(tuple(camera.dist_coeffs)) if k == "distortion"
                     else shown(getattr(camera, k)) for k in used)
    print(f"drawn with {', '.join(used)} {', '.join(shown(v) for v in used.values())}: "
          f"fitted by the calibration (the data's {data})")
    return seq.with_fixed_camera(replace(camera, **used))


def _result_poses(doc: dict, seq) -> np.ndarray:
    """(F, 4, 4) the pose a RESULT.json wrote for each frame of `seq`: its one extrinsic, or,
    for a per-frame result (`--frames each`), each frame's own by name (the reported pose for
    frames it does not list or did not solve)."""
    from dream.result import written_poses

    poses = np.array(np.broadcast_to(doc["T_cam_base"], (len(seq), 4, 4)), dtype=float)
    by_name = dict(zip((e["frame"] for e in doc["per_frame"]), written_poses(doc),
                       strict=True))
    for i, frame in enumerate(seq.frames):
        T = by_name.get(frame.name)
        if T is not None and np.all(np.isfinite(T)):
            poses[i] = T
    return poses


def cmd_overlay(args: argparse.Namespace) -> int:
    run_overlay(request_from(OverlayRequest, with_data(args)))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream overlay` parser."""
    p = add_command(sub, "overlay", cmd_overlay,
                    "draw the robot's outline, projected keypoints and skeleton on the images")
    add_data_positional(p)
    p.add_argument("--out", required=True, help="folder for the overlay PNGs")
    p.add_argument("--extrinsic", "--result", dest="extrinsic",
                   help="RESULT.json to draw with (default: the data's reference)")
    p.add_argument("--robot", help=ROBOT_HELP)
    add_keypoints_arg(p)
    add_intrinsics_args(p)
    p.add_argument("--limit", type=int, default=None, help="draw at most this many frames")
