"""`dream adapt` on the real `panda_teleop` recording, scored against its reference extrinsic.

1. The teacher: the default `dream calibrate` of all frames with the bundled model (the edge
   alignment; never the reference), or `--result` where it was made already.
2. `dream adapt` of the bundled model with `--holdout-frames 92:183` (frames 0-91 and 183-274
   teach) for `--minutes`, with `--scene-renders` renders in the recording's own scene.
3. On copies of the recording holding only frames 92-182 (never seen in adapting) and only
   183-274 (taught, the hand close to the camera), for the bundled and the adapted model:
   each frame alone, keypoints only (`--frames each --refine none`), `dream eval` against the
   reference (single-frame ADD AUC); per keypoint the median distance of the detections from
   the reference's projection, and the wrist keypoints' share within 10 px; the all-frames
   keypoint extrinsic of the copy (`--refine none`) against the reference.

The reference is read only to score. Prints the figures and the time of each step.

    python benchmarks/adapt_teleop.py [--realdata ../shared/realdata] [--minutes 20]
        [--result TEACHER.json] [--scene-renders 1000] [--work DIR] [--zoom]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np

import dream
from dream.camera import project
from dream.cli import main as dream_cli
from dream.io import read_sequence, write_dream
from dream.metrics import pose_errors
from dream.models import BUNDLED_MODEL
from dream.transforms import transform_points

REPO = Path(__file__).resolve().parents[1]
HOLDOUT = (92, 183)
TAUGHT_CLOSE = (183, 275)
WRIST = ("panda_link6", "panda_link7", "panda_hand")
WITHIN_PX = 10.0


def run(args: list) -> None:
    with contextlib.redirect_stdout(io.StringIO()) as out:
        code = dream_cli([str(a) for a in args])
    if code != 0:
        raise SystemExit(f"dream {args[0]} failed (exit {code}):\n{out.getvalue()}")


def subset(data: Path, frames: tuple[int, int], out: Path) -> Path:
    seq = read_sequence(data)
    return write_dream(dataclasses.replace(seq, frames=seq.frames[frames[0]:frames[1]]), out,
                       overwrite=True)


def score(data: Path, model: Path, work: Path, label: str) -> str:
    each = work / f"{label}_each.json"
    run(["calibrate", "--data", data, "--model", model, "--frames", "each", "--refine", "none",
         "--out", each])
    run(["eval", "--data", data, "--result", each, "--out", work / f"{label}.metrics.json"])
    auc = json.loads((work / f"{label}.metrics.json").read_text())["add_auc"] * 100
    seq = read_sequence(data)
    robot = dream.load_robot("panda")
    obs = dream.detect(seq, robot, dream.load_keypoint_model(model))
    uv_ref = project(seq.camera, transform_points(seq.T_cam_base_reference, obs.P_base))
    inside = seq.camera.in_image(uv_ref)
    error = np.linalg.norm(obs.uv - uv_ref, axis=-1)
    medians, wrist = [], []
    for k, name in enumerate(obs.keypoint_names):
        found = obs.found[:, k] & inside[:, k]
        medians.append(f"{np.median(error[found, k]):.1f}" if found.any() else "-")
        if name in WRIST:
            wrist.append(f"{np.mean(obs.found[:, k] & (error[:, k] <= WITHIN_PX)):.0%}")
    allf = work / f"{label}_all.json"
    try:
        run(["calibrate", "--data", data, "--model", model, "--refine", "none", "--out", allf])
        m, rad = pose_errors(np.array(json.loads(allf.read_text())["T_cam_base"]),
                             seq.T_cam_base_reference)
        extrinsic = f"{m * 1e3:.1f} mm, {np.rad2deg(rad):.2f} deg"
    except SystemExit:
        extrinsic = "not solved"
    return (f"single-frame ADD AUC {auc:.1f}; keypoint medians (link0, 2, 3, 4, 6, 7, hand) "
            f"{' / '.join(medians)} px; wrist within {WITHIN_PX:g} px {' / '.join(wrist)}; "
            f"all-frames keypoint extrinsic {extrinsic}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--realdata", type=Path, default=REPO.parent / "shared" / "realdata")
    p.add_argument("--minutes", type=float, default=20.0)
    p.add_argument("--result", type=Path, help="the teacher RESULT.json (default: made here)")
    p.add_argument("--scene-renders", type=int, default=1000,
                   help="dream adapt's renders in the recording's own scene (0: none)")
    p.add_argument("--work", type=Path, help="keep the files here (default: a temporary folder)")
    p.add_argument("--zoom", action="store_true", help="dream adapt --zoom")
    args = p.parse_args()
    data = args.realdata / "panda_teleop"
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        teacher = args.result
        if teacher is None:
            teacher, start = work / "teacher.json", time.perf_counter()
            run(["calibrate", "--data", data, "--model", BUNDLED_MODEL, "--out", teacher])
            print(f"teacher: default dream calibrate, {time.perf_counter() - start:.0f} s")
        adapted, start = work / "adapted.onnx", time.perf_counter()
        run(["adapt", "--data", data, "--result", teacher, "--model", BUNDLED_MODEL, "--out",
             adapted, "--holdout-frames", f"{HOLDOUT[0]}:{HOLDOUT[1]}", "--minutes",
             args.minutes, "--config", REPO / "configs" / "train" / "panda_cpu.yaml",
             "--scene-renders", args.scene_renders, "--overwrite",
             *(["--zoom"] if args.zoom else [])])
        print(f"dream adapt: {(time.perf_counter() - start) / 60:.1f} minutes in all")
        print(adapted.with_suffix(".md").read_text())
        for frames in (HOLDOUT, TAUGHT_CLOSE):
            copy = subset(data, frames, work / f"frames_{frames[0]}_{frames[1]}")
            for label, model in (("bundled", BUNDLED_MODEL), ("adapted", adapted)):
                line = score(copy, model, work, f"{label}_{frames[0]}")
                print(f"frames {frames[0]}-{frames[1] - 1}, {label}: {line}", flush=True)


if __name__ == "__main__":
    main()
