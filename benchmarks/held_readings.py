"""What a joint log slower than the camera costs a fixed-camera calibration, and what
interpolating its readings in time gives back.

Draws keypoint-only measured-like sequences (`dream.inject`: a fixed camera, a smooth random arm
trajectory at `--fps`, labels with `--noise-px` Gaussian noise), records their joints as a log
updating every `--hold-frames` frames (`dream.readings.held_log`: each reading sampled at a
random instant between two frames, then held) or, with `--log-period-s`, by a log with a
regular clock of that period and a random phase (`dream.inject`'s `held_readings`: a controller
logging at a fixed rate), and solves the all-frames extrinsic from the
labels (`dream calibrate --use-labels`) four ways: the readings as logged; interpolated in time
with every update at the midpoint of the frame interval where it appears (no log clock fitted);
interpolated as `dream calibrate` does (`--joint-readings interpolate`, the default: the updates
on the log's clock where one fits); and, for reference, the true joints. Prints the
camera position and rotation error of each per sequence and their medians.

    python benchmarks/held_readings.py [--sequences 10] [--frames 120] [--fps 30]
        [--hold-frames 6 | --log-period-s 0.17] [--noise-px 1.0] [--seed 0]
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
from dream.extension import HeldReadings, ModelExtension
from dream.inject import InjectionSettings, make_injected_sequence
from dream.io import write_dream
from dream.metrics import pose_errors
from dream.readings import held_log, with_interpolated_readings

WAYS = (("as logged", "held", "as-logged"), ("midpoints", "midpoints", "as-logged"),
        ("interpolated", "held", "interpolate"), ("true joints", "true", "as-logged"))


def errors_of(folder: Path, way: tuple[str, str, str], T_true: np.ndarray) -> tuple[float, float]:
    """(camera position error m, rotation error rad) of one way to calibrate."""
    name, data, readings = way
    out = folder / f"{name.replace(' ', '_')}.json"
    with contextlib.redirect_stdout(io.StringIO()):
        code = dream_main(["calibrate", "--data", str(folder / data), "--use-labels",
                           "--joint-readings", readings, "--out", str(out)])
    if code != 0:
        sys.exit(f"dream calibrate failed on {folder / data}")
    T = np.array(json.loads(out.read_text())["T_cam_base"])
    t_err, r_err = pose_errors(T[None], T_true[None])
    return float(t_err[0]), float(r_err[0])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sequences", type=int, default=10)
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--fps", type=float, default=30.0)
    logs = p.add_mutually_exclusive_group()
    logs.add_argument("--hold-frames", type=int, default=6)
    logs.add_argument("--log-period-s", type=float,
                     help="a log with a regular clock of this period instead of --hold-frames")
    p.add_argument("--noise-px", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    start = time.perf_counter()
    clocked = args.log_period_s is not None
    log = (f"a joint log clocked every {args.log_period_s:g} s" if clocked
           else f"a joint log updating every {args.hold_frames} frames")
    print(f"{args.sequences} sequences of {args.frames} frames at {args.fps:g} Hz, {log}, "
          f"labels with {args.noise_px:g} px noise")
    print("seed  " + "  ".join(f"{name:>22}" for name, _, _ in WAYS))
    table = []
    for seed in range(args.seed, args.seed + args.sequences):
        spec = InjectionSettings(num_frames=args.frames, frame_period_s=1.0 / args.fps,
                                 pixel_noise_px=args.noise_px, seed=seed)
        seq = make_injected_sequence(spec)
        if clocked:  # the same camera, motion and labels; the joints as logged
            held = make_injected_sequence(spec, ModelExtension(
                held_readings=HeldReadings(args.log_period_s)))
        else:
            held = held_log(seq, args.hold_frames, np.random.default_rng(seed))
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            write_dream(held, folder / "held")
            # every update at its frame interval's midpoint, no log clock fitted
            write_dream(with_interpolated_readings(held, use_clock=False)[0],
                        folder / "midpoints")
            write_dream(seq, folder / "true")
            row = [errors_of(folder, way, seq.frames[0].T_cam_base_true) for way in WAYS]
        table.append(row)
        print(f"{seed:4d}  " + "  ".join(f"{t * 1e3:8.2f} mm {np.rad2deg(r):6.3f} deg"
                                         for t, r in row))
    med = np.median(np.array(table), axis=0)
    print("median" + "  ".join(f"{t * 1e3:8.2f} mm {np.rad2deg(r):6.3f} deg" for t, r in med))
    print(f"({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
