"""How far the edge alignment takes a keypoint extrinsic on rendered fixed-camera scenes.

Renders `--scenes` fixed-camera scenes (`synth.demo` recipe: 30 random arm poses at 320x240,
lights, colours, backgrounds and distractors randomised; every other scene with an object held
at the flange that the URDF lacks, a tool, a part or a board), calibrates each with the bundled
detector (`dream calibrate --model`, all frames) with `--refine none`, with `--refine edges`
(the scenes' masks are never read) and with `--polish --motion-masks` (the scenes' masks
deleted first), and prints the camera position and rotation error of each per scene and their
medians, overall and per variant, and the time of the alignment. With `--each`, every scene is
also calibrated frame by frame (`--frames each`, `--refine none` and `--refine edges`) and the
single-frame ADD AUC (0-0.1 m) of both over all scenes' frames is printed.

    python benchmarks/edge_align.py [--scenes 20] [--first-seed 300] [--frames 30] [--each]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dream.cli import main as dream_main
from dream.io import read_sequence
from dream.metrics import ADD_AUC_STEP_M, ADD_AUC_THRESHOLD_M, add_per_frame, auc, pose_errors
from dream.models import BUNDLED_MODEL
from dream.pipeline import joints_in_robot_order, robot_for, truth_poses
from synth.demo import render_demo_scene


def calibrated(folder: Path, out: Path, *options: str) -> tuple[float, float, dict]:
    """(position error m, rotation error rad, RESULT.json) of `dream calibrate` with
    `options`."""
    with contextlib.redirect_stdout(io.StringIO()):
        code = dream_main(["calibrate", "--data", str(folder), "--model", str(BUNDLED_MODEL),
                           *options, "--out", str(out)])
    if code != 0:
        sys.exit(f"dream calibrate {' '.join(options)} failed on {folder}")
    doc = json.loads(out.read_text())
    T_true = truth_poses(read_sequence(folder))[0]
    t, r = pose_errors(np.asarray(doc["T_cam_base"])[None], T_true[None])
    return float(t[0]), float(r[0]), doc


def frame_adds(folder: Path, out: Path, refine: str) -> np.ndarray:
    """(F,) single-frame ADD (m, inf without a pose) of `dream calibrate --frames each
    --refine REFINE`."""
    calibrated(folder, out, "--frames", "each", "--refine", refine)
    seq = read_sequence(folder)
    robot = robot_for(seq)
    doc = json.loads(out.read_text())
    T = np.stack([np.full((4, 4), np.nan) if f["T_cam_base"] is None
                  else np.asarray(f["T_cam_base"]) for f in doc["per_frame"]])
    P = robot.forward_kinematics(joints_in_robot_order(seq, robot))
    return add_per_frame(P, T, truth_poses(seq))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", type=int, default=20)
    p.add_argument("--first-seed", type=int, default=300)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--each", action="store_true",
                   help="also calibrate each frame alone, with and without edges")
    args = p.parse_args()
    start = time.perf_counter()
    print(f"{args.scenes} rendered fixed-camera scenes of {args.frames} frames, seeds "
          f"{args.first_seed}..{args.first_seed + args.scenes - 1}; H: an object held at the "
          "flange")
    print("seed     keypoints only          + edge alignment       kept  align s   "
          "+ motion-mask polish   kept")
    rows, adds = [], {"none": [], "edges": []}
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        held = (seed - args.first_seed) % 2 == 1
        with tempfile.TemporaryDirectory() as tmp:
            folder = render_demo_scene(Path(tmp) / "scene", seed, args.frames, held)
            t0, r0, _ = calibrated(folder, Path(tmp) / "none.json", "--refine", "none")
            t1, r1, doc = calibrated(folder, Path(tmp) / "edges.json", "--refine", "edges")
            for mask in folder.glob("*.seg.png"):
                mask.unlink()
            t2, r2, motion = calibrated(folder, Path(tmp) / "motion.json", "--polish",
                                        "--motion-masks")
            if args.each:
                for refine in adds:
                    adds[refine].append(frame_adds(folder, Path(tmp) / f"each_{refine}.json",
                                                   refine))
        edges = doc["edges"]
        rows.append((held, t0, r0, t1, r1, t2, r2))
        print(f"{seed:4d} {'H' if held else ' '}  {t0 * 1e3:7.2f} mm {np.rad2deg(r0):6.3f} deg  "
              f"{t1 * 1e3:7.2f} mm {np.rad2deg(r1):6.3f} deg  {str(edges['kept']):5s} "
              f"{edges['seconds']:6.1f}  {t2 * 1e3:7.2f} mm {np.rad2deg(r2):6.3f} deg  "
              f"{motion['polish']['kept']}", flush=True)
    table = np.array([r[1:] for r in rows])
    held = np.array([r[0] for r in rows])
    for name, pick in (("all", np.ones(len(rows), bool)), ("plain", ~held), ("held", held)):
        if pick.any():
            m = np.median(table[pick], axis=0)
            print(f"median {name:5s} ({pick.sum():2d}): keypoints {m[0] * 1e3:.2f} mm "
                  f"{np.rad2deg(m[1]):.3f} deg -> edges {m[2] * 1e3:.2f} mm "
                  f"{np.rad2deg(m[3]):.3f} deg; motion-mask polish {m[4] * 1e3:.2f} mm "
                  f"{np.rad2deg(m[5]):.3f} deg")
    if args.each:
        a0, a1 = (np.concatenate(adds[k]) for k in ("none", "edges"))
        print(f"each frame alone ({len(a0)} frames): single-frame ADD AUC keypoints "
              f"{100 * auc(a0, ADD_AUC_THRESHOLD_M, ADD_AUC_STEP_M):.1f} -> edges "
              f"{100 * auc(a1, ADD_AUC_THRESHOLD_M, ADD_AUC_STEP_M):.1f}; median ADD "
              f"{1e3 * np.median(a0):.1f} -> {1e3 * np.median(a1):.1f} mm")
    print(f"({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
