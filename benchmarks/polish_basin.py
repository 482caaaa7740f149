"""How far off may the keypoint extrinsic be for the all-frames silhouette polish to converge?

Renders fixed-camera scenes (`synth.demo` recipe: `--frames` random arm poses, seeds from
`--first-seed`), and polishes each one's extrinsic against its own robot masks (`*.seg.png`),
with the frames, masks and meshes `dream calibrate --polish` uses (`dream.polish.
silhouette_inputs`, `dream.polish.polish`), but from the true extrinsic
moved by each `--offsets` distance: the camera centre by that many metres in a random direction
and the camera turned by `--turn-per-m` rad per metre about a random axis. No keypoint guard:
this measures the silhouette search alone. A polish has converged when the polished camera lies
within `--converged-mm` of the truth. Prints, per offset, the share of scenes that converged,
the median error after the polish, and how well the final IoU tells convergence apart.

    python benchmarks/polish_basin.py [--scenes 10] [--first-seed 100] [--frames 30]
        [--offsets 0.02 0.05 0.1 0.2 0.3 0.5] [--turn-per-m 0.33] [--seed 0] [--out DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from dream.io import read_sequence
from dream.metrics import pose_errors
from dream.pipeline import robot_for
from dream.polish import PolishSettings, polish, silhouette_inputs
from dream.transforms import T_from_rotvec_t, invert_T

IOU_CONVERGED = 0.95   # the IoU the report splits at (PolishSettings.frame_restart_below_iou)


def random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def moved_start(T_cam_base: np.ndarray, offset_m: float, turn_rad: float,
                rng: np.random.Generator) -> np.ndarray:
    """`T_cam_base` with the camera centre moved by `offset_m` (base frame) and the camera
    turned by `turn_rad` about its own axes, both in random directions."""
    T_base_cam = invert_T(T_cam_base)
    T_base_cam[:3, 3] += offset_m * random_unit(rng)
    return T_from_rotvec_t(turn_rad * random_unit(rng), np.zeros(3)) @ invert_T(T_base_cam)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=100)
    parser.add_argument("--frames", type=int, default=30, help="frames per scene")
    parser.add_argument("--offsets", type=float, nargs="+",
                        default=[0.02, 0.05, 0.1, 0.2, 0.3, 0.5],
                        help="camera-centre offsets of the starts, m")
    parser.add_argument("--turn-per-m", type=float, default=0.33,
                        help="rotation of the start per metre of offset, rad")
    parser.add_argument("--converged-mm", type=float, default=3.0)
    parser.add_argument("--seed", type=int, default=0, help="seed of the start directions")
    parser.add_argument("--out", type=Path, help="folder for the rendered scenes")
    args = parser.parse_args()
    if args.scenes < 1 or args.frames < 1 or not args.offsets:
        parser.error("--scenes and --frames must be >= 1, with at least one offset")
    from synth.demo import render_demo_scene

    work = args.out or Path(tempfile.mkdtemp(prefix="dream-polish-basin-"))
    rng = np.random.default_rng(args.seed)
    params = PolishSettings()
    rows = {m: [] for m in args.offsets}       # (error after mm, IoU after) per offset
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        data = render_demo_scene(work / f"scene_{seed}", seed=seed, num_frames=args.frames)
        seq = read_sequence(data)
        T_true = seq.frames[0].T_cam_base_true
        inputs = silhouette_inputs(seq, robot_for(seq), params)    # as `dream calibrate`
        line = []
        for m in args.offsets:
            start = moved_start(T_true, m, args.turn_per_m * m, rng)
            res = polish(inputs.meshes, inputs.joints, inputs.masks, seq.camera, start, None,
                         params, inputs.frame_names)
            error_mm = 1000 * float(pose_errors(res.T_polished, T_true)[0])
            rows[m].append((error_mm, res.iou_after_mean))
            line.append(f"{1000 * m:.0f} mm -> {error_mm:.1f} mm (IoU {res.iou_after_mean:.3f})")
        print(f"scene seed {seed}: " + "; ".join(line), flush=True)
    print(f"{args.scenes} scenes x {args.frames} frames (seeds {args.first_seed}-"
          f"{args.first_seed + args.scenes - 1}), the scenes' own masks, starts turned "
          f"{args.turn_per_m:g} rad per metre of offset:")
    for m in args.offsets:
        error, iou = np.array(rows[m]).T
        converged = error < args.converged_mm
        high = iou >= IOU_CONVERGED
        print(f"   start {1000 * m:4.0f} mm off ({np.rad2deg(args.turn_per_m * m):.1f} deg): "
              f"converged (< {args.converged_mm:g} mm) in {int(converged.sum())} of "
              f"{len(error)}, median error after {np.median(error):.1f} mm; IoU >= "
              f"{IOU_CONVERGED} in {int(high.sum())}, of which converged "
              f"{int((high & converged).sum())}; converged below it "
              f"{int((~high & converged).sum())}", flush=True)
    print(f"(scenes in {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
