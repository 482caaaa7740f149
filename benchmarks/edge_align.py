"""How far the edge alignment takes a keypoint extrinsic on rendered fixed-camera scenes.

Renders `--scenes` fixed-camera scenes (`synth.demo` recipe: 30 random arm poses at 320x240,
lights, colours, backgrounds and distractors randomised; every other scene with an object held
at the flange that the URDF lacks, a tool, a part or a board), calibrates each with the bundled
detector (`dream calibrate --model`, all frames) with `--refine none` and with `--refine edges`
(the scenes' masks are never read), and prints the camera position and rotation error of both
per scene and their medians, overall and per variant, and the time of the alignment.

    python benchmarks/edge_align.py [--scenes 20] [--first-seed 300] [--frames 30]
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
from dream.metrics import pose_errors
from dream.models import BUNDLED_MODEL
from dream.pipeline import truth_poses
from synth.demo import render_demo_scene


def calibrated(folder: Path, refine: str, out: Path) -> tuple[float, float, dict]:
    """(position error m, rotation error rad, RESULT.json) of `dream calibrate --refine`."""
    with contextlib.redirect_stdout(io.StringIO()):
        code = dream_main(["calibrate", "--data", str(folder), "--model", str(BUNDLED_MODEL),
                           "--refine", refine, "--out", str(out)])
    if code != 0:
        sys.exit(f"dream calibrate --refine {refine} failed on {folder}")
    doc = json.loads(out.read_text())
    T_true = truth_poses(read_sequence(folder))[0]
    t, r = pose_errors(np.asarray(doc["T_cam_base"])[None], T_true[None])
    return float(t[0]), float(r[0]), doc


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", type=int, default=20)
    p.add_argument("--first-seed", type=int, default=300)
    p.add_argument("--frames", type=int, default=30)
    args = p.parse_args()
    start = time.perf_counter()
    print(f"{args.scenes} rendered fixed-camera scenes of {args.frames} frames, seeds "
          f"{args.first_seed}..{args.first_seed + args.scenes - 1}; H: an object held at the "
          "flange")
    print("seed     keypoints only          + edge alignment       kept  align s")
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        held = (seed - args.first_seed) % 2 == 1
        with tempfile.TemporaryDirectory() as tmp:
            folder = render_demo_scene(Path(tmp) / "scene", seed, args.frames, held)
            t0, r0, _ = calibrated(folder, "none", Path(tmp) / "none.json")
            t1, r1, doc = calibrated(folder, "edges", Path(tmp) / "edges.json")
        edges = doc["edges"]
        rows.append((held, t0, r0, t1, r1))
        print(f"{seed:4d} {'H' if held else ' '}  {t0 * 1e3:7.2f} mm {np.rad2deg(r0):6.3f} deg  "
              f"{t1 * 1e3:7.2f} mm {np.rad2deg(r1):6.3f} deg  {str(edges['kept']):5s} "
              f"{edges['seconds']:6.1f}", flush=True)
    table = np.array([r[1:] for r in rows])
    held = np.array([r[0] for r in rows])
    for name, pick in (("all", np.ones(len(rows), bool)), ("plain", ~held), ("held", held)):
        if pick.any():
            m = np.median(table[pick], axis=0)
            print(f"median {name:5s} ({pick.sum():2d}): keypoints {m[0] * 1e3:.2f} mm "
                  f"{np.rad2deg(m[1]):.3f} deg -> edges {m[2] * 1e3:.2f} mm "
                  f"{np.rad2deg(m[3]):.3f} deg")
    print(f"({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
