"""Does the all-frames polish leave out the frames whose joint readings do not match their images?

Renders `--scenes` fixed-camera scenes (`synth.demo` recipe, `--frames` random arm poses at
320x240, every other one with an object held at the flange), calibrates each with the bundled
detector (`dream calibrate`, all frames, `--refine none`), then moves the joint readings of
`--wrong` of the frames (one or two of joints 1-4 by 0.1-0.4 rad, a random sign: readings
logged at another instant) and polishes the keypoint extrinsic against the scene's own masks
with and without the frame check (`dream.polish.frames`), and once more with the true readings.
Prints per scene and as medians the camera position error of each, how many of the moved
frames were left out and how many good ones, and the time of the polish.

    python benchmarks/polish_frames.py [--scenes 20] [--first-seed 300] [--frames 30]
        [--wrong 0.3] [--seed 0]
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
from dream.pipeline import robot_for
from dream.polish import PolishSettings, polish, silhouette_inputs
from synth.demo import render_demo_scene

MOVED_JOINTS = 4                  # readings are moved on joints 1..4
READING_ERROR_RAD = (0.1, 0.4)    # by this much


def keypoint_extrinsic(folder: Path, out: Path) -> np.ndarray:
    with contextlib.redirect_stdout(io.StringIO()):
        code = dream_main(["calibrate", "--data", str(folder), "--model", str(BUNDLED_MODEL),
                           "--refine", "none", "--out", str(out)])
    if code != 0:
        sys.exit(f"dream calibrate failed on {folder}")
    return np.asarray(json.loads(out.read_text())["T_cam_base"])


def wrong_readings(joints: np.ndarray, share: float, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(the joints with the readings of `share` of the frames moved, those frames' indices)."""
    moved = joints.copy()
    bad = rng.choice(len(joints), int(round(share * len(joints))), replace=False)
    for b in bad:
        which = rng.choice(MOVED_JOINTS, rng.integers(1, 3), replace=False)
        moved[b, which] += rng.choice([-1, 1], len(which)) * rng.uniform(
            *READING_ERROR_RAD, len(which))
    return moved, bad


def polished(inputs, camera, joints: np.ndarray, T0: np.ndarray, T_true: np.ndarray,
             params: PolishSettings, check: bool):
    """(camera position error mm, `PolishResult`) of the polish from T0 with these joints."""
    res = polish(inputs.meshes, joints, inputs.masks, camera, T0, None, params,
                 check_frames=check)
    return 1e3 * float(pose_errors(res.T_polished, T_true)[0]), res


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", type=int, default=20)
    p.add_argument("--first-seed", type=int, default=300)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--wrong", type=float, default=0.3, help="share of frames with wrong readings")
    p.add_argument("--seed", type=int, default=0, help="seed of the wrong readings")
    args = p.parse_args()
    rng = np.random.default_rng(args.seed)
    params = PolishSettings()
    start = time.perf_counter()
    print("seed     wrong readings: no check / frame check    left out: wrong, good   "
          "true readings   polish s (check)")
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        held = (seed - args.first_seed) % 2 == 1
        with tempfile.TemporaryDirectory() as tmp:
            folder = render_demo_scene(Path(tmp) / "scene", seed, args.frames, held)
            T0 = keypoint_extrinsic(folder, Path(tmp) / "r.json")
            seq = read_sequence(folder)
            inputs = silhouette_inputs(seq, robot_for(seq), params)
        T_true = seq.frames[0].T_cam_base_true
        joints, bad = wrong_readings(inputs.joints, args.wrong, rng)
        plain, _ = polished(inputs, seq.camera, joints, T0, T_true, params, False)
        checked, res = polished(inputs, seq.camera, joints, T0, T_true, params, True)
        true, _ = polished(inputs, seq.camera, inputs.joints, T0, T_true, params, True)
        left = set(res.agreement.left_out.tolist())
        found, good = len(left & set(bad.tolist())), len(left - set(bad.tolist()))
        rows.append((plain, checked, true, found, good, len(bad)))
        print(f"{seed:4d} {'H' if held else ' '}  {plain:8.2f} mm / {checked:6.2f} mm"
              f"{'':18s}{found:3d} of {len(bad)}, {good:2d}{'':10s}{true:6.2f} mm"
              f"{res.seconds:10.1f}", flush=True)
    table = np.array(rows)
    print(f"median: no check {np.median(table[:, 0]):.2f} mm (max {table[:, 0].max():.2f}), "
          f"frame check {np.median(table[:, 1]):.2f} mm (max {table[:, 1].max():.2f}), true "
          f"readings {np.median(table[:, 2]):.2f} mm; wrong frames left out "
          f"{int(table[:, 3].sum())} of {int(table[:, 5].sum())}, good frames left out "
          f"{int(table[:, 4].sum())} of {args.scenes * args.frames - int(table[:, 5].sum())}")
    print(f"({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
