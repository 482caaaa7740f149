"""`dream adapt` for a new arm on renders: a recipe model trained on the CPU, adapted to one
rendered fixed-camera scene from a calibration of its first frames, scored against the labels
of the frames it never saw.

1. The model (or `--model`): `dream synth` of `--train-frames` default and as many
   `real_world.yaml` renders of `--robot` (the README's new-arm recipe), `dream train` with
   `configs/train/panda_cpu.yaml` for `--train-minutes`, `dream export`.
2. The scene: a fixed-camera `real_world.yaml` sequence of `--frames` frames (`--seed`), its
   robot masks deleted (a real recording has none).
3. The teacher: the default `dream calibrate` with the model on a copy holding the first
   `--teach` frames; where it fails or is `unreliable`, the automatic search without the model
   (`dream adapt` refuses an unreliable teacher). Its error against the truth is printed; the
   labels are never given to it.
4. `dream adapt` of the whole scene with that extrinsic (a result of some of a recording's
   frames teaches all of them), `--holdout-frames TEACH:FRAMES`, for `--minutes`, with
   `--scene-renders` renders in the recording's own scene.
5. On a copy holding the last frames, for the trained and the adapted model: the detections
   against the renderer's labels (PCK@5 px of the keypoints in view, the median error, the
   share found) and the all-frames keypoint extrinsic against the truth.

    python benchmarks/adapt_render.py [--robot xarm7] [--train-minutes 45] [--minutes 10]
        [--model M.onnx] [--train-frames 4000] [--frames 90] [--teach 60] [--seed 1000]
        [--scene-renders 1000] [--adapt-seed 0] [--zoom] [--set KEY=VALUE ...] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
from adapt_teleop import run, subset  # a sibling script: `python benchmarks/...` finds it

import dream
from dream.io import read_sequence
from dream.metrics import pose_errors

REPO = Path(__file__).resolve().parents[1]
REAL_WORLD = REPO / "configs" / "synth" / "real_world.yaml"
RECIPE = REPO / "configs" / "train" / "panda_cpu.yaml"
PCK_PX = 5.0


def timed(label: str, start: float) -> None:
    print(f"{label}: {(time.perf_counter() - start) / 60:.1f} min", flush=True)


def train_model(robot: str, frames: int, minutes: float, work: Path) -> Path:
    start = time.perf_counter()
    plain, rw = work / f"{robot}_train", work / f"{robot}_train_rw"
    run(["synth", "--robot", robot, "--num", frames, "--seed", 1, "--out", plain,
         "--workers", 2])
    run(["synth", "--robot", robot, "--num", frames, "--seed", 2, "--out", rw, "--workers", 2,
         "--config", REAL_WORLD])
    timed(f"training data, 2 x {frames} renders", start)
    start = time.perf_counter()
    run(["train", "--config", RECIPE, "--out", work / "run", "--set",
         f"data.train=[{plain},{rw}]", "--set", f"trainer.time_budget_minutes={minutes}"])
    timed("dream train", start)
    model = work / f"{robot}.onnx"
    run(["export", "--checkpoint", work / "run" / "best.ckpt", "--out", model, "--overwrite"])
    return model


def scene(robot: str, frames: int, seed: int, out: Path) -> Path:
    run(["synth", "--robot", robot, "--num", frames, "--seed", seed, "--out", out,
         "--config", REAL_WORLD, "--set", "sequence.mode=fixed_camera"])
    for mask in out.glob("*.seg.png"):
        mask.unlink()
    return out


def extrinsic_error(result: Path, seq) -> str:
    m, rad = pose_errors(np.array(json.loads(result.read_text())["T_cam_base"]),
                         seq.frames[0].T_cam_base_true)
    return f"{m * 1e3:.1f} mm, {np.rad2deg(rad):.2f} deg"


def teacher(data: Path, robot: str, model: Path, work: Path) -> Path:
    start = time.perf_counter()
    out = work / "teacher.json"
    try:
        run(["calibrate", "--data", data, "--robot", robot, "--model", model, "--out", out])
        verdict = json.loads(out.read_text())["quality"]["verdict"]
    except SystemExit:
        verdict = "failed"
    how = "with the model"
    if verdict in ("unreliable", "failed"):
        run(["calibrate", "--data", data, "--robot", robot, "--out", out])
        how = f"by the automatic search (the model's calibration: {verdict})"
    doc = json.loads(out.read_text())
    print(f"teacher {how}: {extrinsic_error(out, read_sequence(data))} from the truth, "
          f"{doc['quality']['verdict']}, {time.perf_counter() - start:.0f} s", flush=True)
    return out


def score(data: Path, robot: str, model: Path, work: Path, label: str) -> str:
    seq = read_sequence(data)
    obs = dream.detect(seq, dream.load_robot(robot), dream.load_keypoint_model(model))
    labels = np.stack([f.uv_labels for f in seq.frames])
    inside = np.isfinite(labels).all(-1) & seq.camera.in_image(np.nan_to_num(labels))
    error = np.linalg.norm(obs.uv - labels, axis=-1)
    hit = obs.found & inside & (error <= PCK_PX)
    found = obs.found & inside
    line = (f"PCK@{PCK_PX:g} px {hit.sum() / inside.sum():.3f}, found "
            f"{found.sum() / inside.sum():.2f}, median {np.median(error[found]):.1f} px"
            if found.any() else "nothing found")
    result = work / f"{label}_all.json"
    try:
        run(["calibrate", "--data", data, "--robot", robot, "--model", model, "--refine",
             "none", "--out", result])
        line += f"; all-frames keypoint extrinsic {extrinsic_error(result, seq)}"
    except SystemExit:
        line += "; all-frames keypoint extrinsic not solved"
    return line


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robot", default="xarm7")
    p.add_argument("--model", type=Path, help="start from this model (default: train one)")
    p.add_argument("--train-frames", type=int, default=4000)
    p.add_argument("--train-minutes", type=float, default=45.0)
    p.add_argument("--frames", type=int, default=90)
    p.add_argument("--teach", type=int, default=60)
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--minutes", type=float, default=10.0, help="dream adapt's budget")
    p.add_argument("--scene-renders", type=int, default=1000,
                   help="dream adapt's renders in the recording's own scene (0: none)")
    p.add_argument("--adapt-seed", type=int, default=0,
                   help="dream adapt's --seed (its renders and training order)")
    p.add_argument("--zoom", action="store_true", help="dream adapt --zoom")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="dream adapt's recipe overrides (repeatable)")
    p.add_argument("--work", type=Path, help="keep the files here (default: a temporary folder)")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        model = args.model or train_model(args.robot, args.train_frames, args.train_minutes,
                                          work)
        data = scene(args.robot, args.frames, args.seed, work / "scene")
        taught = subset(data, (0, args.teach), work / "teach")
        held = subset(data, (args.teach, args.frames), work / "held")
        result = teacher(taught, args.robot, model, work)
        adapted, start = work / "adapted.onnx", time.perf_counter()
        run(["adapt", "--data", data, "--result", result, "--model", model, "--out", adapted,
             "--holdout-frames", f"{args.teach}:{args.frames}", "--minutes", args.minutes,
             "--config", RECIPE, "--scene-renders", args.scene_renders, "--seed",
             args.adapt_seed, "--overwrite", *(["--zoom"] if args.zoom else []),
             *[a for kv in args.set for a in ("--set", kv)]])
        timed("dream adapt", start)
        for label, m in (("trained", model), ("adapted", adapted)):
            line = score(held, args.robot, m, work, label)
            print(f"frames {args.teach}-{args.frames - 1}, {label}: {line}", flush=True)


if __name__ == "__main__":
    main()
