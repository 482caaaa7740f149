"""`dream eval`: a RESULT.json scored against the data's ground truth -> METRICS.json."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dream.cli.options import (
    DataOptions,
    add_command,
    add_data_args,
    read_data,
    request_from,
)
from dream.errors import InputError


@dataclass(frozen=True)
class EvalRequest(DataOptions):
    """What `dream eval` does: the options of its command line."""

    data: str
    result: str
    out: str


def run_eval(request: EvalRequest) -> dict:
    """The metrics of `request.result` on `request.data`, written to `request.out` and
    summarised on stdout; returns METRICS.json's document."""
    from dream.io import check_output_file, write_json_atomic
    from dream.io.recording_files import check_spares_recording
    from dream.pipeline import evaluate, robot_for
    from dream.provenance import check_same_data
    from dream.readings import solved_readings
    from dream.result import read_result

    check_output_file(request.out)
    if Path(request.out).resolve() == Path(request.result).resolve():
        raise InputError("--out is the --result it scores: writing it would replace the result",
                         request.out, "choose another --out, e.g. METRICS.json")
    doc = read_result(request.result)
    seq = read_data(request)
    check_spares_recording([request.out], seq, request.data)
    check_same_data(doc, seq, request.data, request.result)
    seq = solved_readings(seq, doc)
    names = [k["name"] for f in doc["per_frame"][:1] for k in f.get("keypoints") or []]
    robot_from = request.result if not request.robot and doc.get("robot") else None
    # the keypoints scored: the result's, else the labels' (a result without keypoints)
    robot = robot_for(seq, request.robot or doc.get("robot"),
                      tuple(names) or seq.keypoint_names or None,
                      robot_from=robot_from, keypoints_from=request.result,
                      option_keypoints=request.keypoint_links)
    metrics = evaluate(seq, robot, doc)
    write_json_atomic(request.out, metrics)
    _print_metrics(metrics)
    print(f"wrote {request.out}")
    return metrics


def _print_metrics(metrics: dict) -> None:
    add, t, r = metrics["add_m"], metrics["translation_error_m"], metrics["rotation_error_rad"]
    fmt = lambda v, s=1.0: "n/a" if v is None else f"{v * s:.3f}"  # noqa: E731
    print(f"ADD mean {fmt(add['mean'], 1e3)} mm, median {fmt(add['median'], 1e3)} mm, "
          f"ADD AUC {metrics['add_auc']:.4f} (0-{metrics['add_auc_threshold_m']} m, "
          f"{metrics['frames_in_add_auc']} frames)")
    kp = metrics["keypoint_l2_px"]
    if kp is None:
        print("keypoints: none in the result (calibrated without keypoints)")
    else:
        print(f"keypoint L2 mean {fmt(kp['mean'])} px, median {fmt(kp['median'])} px, PCK AUC "
              f"{metrics['pck_auc']:.4f} (0-{metrics['pck_auc_threshold_px']:g} px)")
    print(f"camera position error median {fmt(t['median'], 1e3)} mm, rotation error median "
          f"{fmt(r['median'], np.rad2deg(1))} deg")


def cmd_eval(args: argparse.Namespace) -> int:
    run_eval(request_from(EvalRequest, args))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream eval` parser."""
    p = add_command(sub, "eval", cmd_eval, "score a RESULT.json against the data's ground truth")
    add_data_args(p)
    p.add_argument("--result", required=True, help="RESULT.json of dream calibrate")
    p.add_argument("--out", required=True, help="METRICS.json to write")
