"""`dream diagnose`: residual analysis, effect catalog, cross-validated model selection."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dream.cli.observe import observe
from dream.cli.options import (
    DataOptions,
    add_command,
    add_data_args,
    add_model_source,
    read_data,
    request_from,
)
from dream.errors import InputError

TIMED_EFFECTS = ("time_offset", "held_readings")   # effects that read the frames' timestamps
NOT_TESTABLE = "not testable"      # an effect's evidence when the data cannot test it


@dataclass(frozen=True)
class DiagnoseRequest(DataOptions):
    """What `dream diagnose` does: the options of its command line."""

    data: str
    out: str
    model: str | None = None
    use_labels: bool = False
    effects: str | None = None
    folds: int = 5
    threads: int | None = None
    batch: int | None = None

    def effect_names(self) -> tuple[str, ...] | None:
        """The effects of the comma-separated `--effects` (None: the catalog's default)."""
        return tuple(e.strip() for e in self.effects.split(",")) if self.effects else None


def run_diagnose(request: DiagnoseRequest) -> dict:
    """The diagnosis of `request.data`: REPORT_DIR written, the verdict printed; returns
    diagnosis.json's document."""
    from dream.diagnosis.run import run_diagnosis
    from dream.diagnosis.select import DiagnoseSettings
    from dream.io import check_output_folder

    check_output_folder(request.out)  # before the analysis, which takes a while
    seq = read_data(request)
    if Path(request.out).resolve() == Path(request.data).resolve():
        raise InputError("--out is the recording's folder: the report would mix with it",
                         request.out, "give --out a folder of its own, e.g. report")
    effects = request.effect_names()
    timed = sorted(set(effects or ()) & set(TIMED_EFFECTS))
    if timed and any(f.timestamp is None for f in seq.frames):
        raise InputError(f"--effects names {', '.join(timed)}, which need every frame's "
                         "timestamp, and some frames have none", request.data,
                         "give data with timestamps (seconds), or leave those effects out")
    settings = DiagnoseSettings(**({"effects": effects} if effects else {}),
                                folds=request.folds)
    if len(seq) <= settings.folds:
        raise InputError(f"{len(seq)} frame(s) are too few to diagnose: each of the "
                         f"{settings.folds} cross-validation folds needs frames to fit and "
                         "others to predict", request.data,
                         f"record more than {settings.folds} frames (20 or more give a useful "
                         "diagnosis), or lower --folds")
    robot, obs, _ = observe(seq, request.robot, request.model, request.use_labels, sys.stdout,
                            threads=request.threads, batch=request.batch,
                            keypoints=request.keypoint_links)
    doc = run_diagnosis(seq, robot, obs, request.out, settings,
                        progress=lambda message: print(message, file=sys.stderr))
    _print_diagnosis(doc, request.out)
    return doc


def _print_diagnosis(doc: dict, out_dir: str) -> None:
    gain = doc["gain"]
    print(f"baseline: held-out RMSE {gain['heldout_rmse_px_before']:.3f} px")
    print(f"verdict: {', '.join(doc['verdict']) or 'no significant effect'}")
    for effect in doc["effects"]:
        if effect["name"] in doc["verdict"]:
            print(f"  {effect['name']}: {effect['params']}")
        elif str(effect.get("evidence", "")).startswith(NOT_TESTABLE):   # not silently
            print(f"  {effect['name']} {effect['evidence']}")
    for name, found in (doc.get("image_findings") or {}).items():
        for link, params in found.items():
            size = " x ".join(f"{100 * s:.0f}" for s in params["size_m"])
            centre = ", ".join(str(round(100 * c)) for c in params["position_m"])
            print(f"  {name}: a box of {size} cm at ({centre}) cm in the frame of {link} "
                  f"(found in the images)")
    print(f"extended model: held-out RMSE {gain['heldout_rmse_px_after']:.3f} px")
    remaining = doc.get("remaining") or {}
    if remaining.get("unexplained_share") is not None:
        print(f"unexplained: {remaining['unexplained_share']:.0%} of the baseline's held-out "
              f"mean squared error; the remaining misfit looks like {remaining['looks_like']}")
    evidence = doc.get("image_evidence")
    if evidence:
        steps = ", ".join(f"{s['model']} {s['agreement']:.1%}" for s in evidence["steps"])
        print(f"image evidence (robot outline on image edges, extrinsic aligned to them): "
              f"{steps}; supported by the "
              f"keypoints only: {', '.join(evidence['unsupported']) or 'none'}; links whose "
              f"outline disagrees: {', '.join(evidence['mismatched_links']) or 'none'}")
    search = doc.get("attached_search")
    if search and not search.get("named"):
        print(f"link_geometry: not named: {search['reason']}")
    truth = doc.get("truth")
    if truth:
        for label in ("before", "after"):
            t = truth[label]
            print(f"vs ground truth {label}: camera position {1000 * t['translation_error_m']:.2f}"
                  f" mm, rotation {np.rad2deg(t['rotation_error_rad']):.3f} deg, ADD "
                  f"{1000 * t['add_mean_m']:.2f} mm")
        if truth.get("steps"):
            print("vs ground truth after each accepted effect: " + ", ".join(
                f"{s['model']} {1000 * s['translation_error_m']:.1f} mm"
                for s in truth["steps"]))
    print(f"wrote {Path(out_dir) / 'diagnosis.json'}, {doc['extended_model']} and "
          f"{Path(out_dir) / 'report.md'} ({doc['seconds']:.1f} s)")


def cmd_diagnose(args: argparse.Namespace) -> int:
    run_diagnose(request_from(DiagnoseRequest, args))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream diagnose` parser."""
    p = add_command(sub, "diagnose", cmd_diagnose, "find what the robot-and-camera model gets "
                    "wrong on measured data, extend it and measure the gain")
    add_data_args(p)
    add_model_source(p, "detect the keypoints with this network (onnxruntime, no torch)")
    p.add_argument("--out", required=True, metavar="REPORT_DIR",
                   help="folder for diagnosis.json, extended_model.yaml, report.md and plots")
    p.add_argument("--effects", help="comma-separated effects to test (default: all of "
                   "joint_offset, lens_distortion, intrinsics_error, time_offset, link_length, "
                   "camera_moved, keypoint_bias)")
    p.add_argument("--folds", type=int, default=5,
                   help="cross-validation folds over frames (default: %(default)s)")
    p.add_argument("--threads", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--batch", type=int, default=None, help=argparse.SUPPRESS)
