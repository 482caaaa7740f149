"""Throughput of `dream synth` against the raw MuJoCo render rate, measured in one run.

raw:        the same scene and renderer, the same passes the generator needs (RGB and link
            segmentation at the recipe's resolution), random joints and camera per frame and
            nothing else: no randomisation, labels, background or files.
generator:  `synth.generate.generate` writing a dataset, with 1 and then 2 worker processes.
            Rates are steady state: timed from the first finished chunk of frames to the last
            (process start and scene loading excluded; printed separately).

Targets: generator (1 worker) / raw >= 0.7; 2 workers / 1 worker >= 1.7.

    python benchmarks/synth_throughput.py [--robot panda] [--frames 240] [--config YAML]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from dream.robot import load_robot
from synth.config import load_config
from synth.frames import FrameMaker
from synth.generate import SynthJob, generate
from synth.randomize import sample_camera_pose, sample_joints


def raw_rate(robot_name: str, config, frames: int) -> float:
    robot = load_robot(robot_name)
    maker = FrameMaker(robot, config, seed=0)   # the generator's scene and renderer
    rng = np.random.default_rng(0)
    states = [(sample_joints(rng, robot, config, None), sample_camera_pose(rng, config))
              for _ in range(frames)]
    try:
        maker.renderer.set_state(*states[0])
        maker.renderer.render(rgb=True, segmentation=True)   # warm-up
        start = time.perf_counter()
        for q, T in states:
            maker.renderer.set_state(q, T)
            maker.renderer.render(rgb=True, segmentation=True)
        return frames / (time.perf_counter() - start)
    finally:
        maker.close()


def generator_rate(robot_name: str, config, frames: int, workers: int) -> tuple[float, float]:
    """(steady-state frames/s, whole-run seconds)."""
    stamps: list[tuple[float, int]] = []
    with tempfile.TemporaryDirectory() as tmp:
        job = SynthJob(robot_name, Path(tmp) / "out", frames, config, seed=1, workers=workers)
        start = time.perf_counter()
        generate(job, on_progress=lambda n: stamps.append((time.perf_counter(), n)))
        total = time.perf_counter() - start
    (t0, _), (t1, _) = stamps[0], stamps[-1]
    steady_frames = sum(n for _, n in stamps[1:])
    return steady_frames / (t1 - t0), total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="panda")
    parser.add_argument("--frames", type=int, default=240)
    parser.add_argument("--config", default="configs/synth/default.yaml")
    args = parser.parse_args()
    config = load_config(args.config)
    c = config.intrinsics
    print(f"{args.robot}, {c.width}x{c.height}, recipe {args.config}, {args.frames} frames")
    raw = raw_rate(args.robot, config, args.frames)
    print(f"raw MuJoCo render (RGB + segmentation):  {raw:6.1f} frames/s")
    one, one_total = generator_rate(args.robot, config, args.frames, 1)
    print(f"generator, 1 worker:                     {one:6.1f} frames/s "
          f"(whole run {one_total:.1f} s)   ratio to raw {one / raw:.2f}  (target >= 0.7)")
    two, two_total = generator_rate(args.robot, config, args.frames, 2)
    print(f"generator, 2 workers:                    {two:6.1f} frames/s "
          f"(whole run {two_total:.1f} s)   speed-up {two / one:.2f}x  (target >= 1.7x)")


if __name__ == "__main__":
    main()
