"""Motion masks against the rendered robot, with and without cast shadows in the scene, with and
without the shadow test (`dream.edges.shadow`).

Each `--robots` arm gets `--scenes` fixed-camera `real_world.yaml` scenes of `--frames` frames
(seeds from `--first-seed`), rendered twice: as the recipe draws them and with the first light
casting shadows (`lights.shadow_prob=1`; every other draw the same). For each, the motion masks
(`dream.edges.motion`) are compared with the rendered robot masks over all frames: precision
(the share of mask pixels on the robot: a shadow lowers it) and recall (the share of robot
pixels in the mask; the links that never move are not in the masks, so it stays below 1).
`--set KEY=VALUE` changes the shadow test (`ShadowSettings`) for a second row.

    python benchmarks/shadow_masks.py [--robots panda,ur5,xarm7] [--scenes 5] [--frames 30]
        [--first-seed 1000] [--work DIR] [--set max_spread=0.2 ...]
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
from coarse_start import randomisation, robot_keypoints  # a sibling script: `python benchmarks/...`

from dream.edges.motion import MotionSettings, motion_masks, sequence_motion_model
from dream.edges.shadow import ShadowSettings
from dream.io import load_image, load_mask, read_sequence

SHADOWS = "lights.shadow_prob=1"


def render(robot: str, seed: int, frames: int, shadows: bool, out: Path) -> Path:
    """A fixed-camera `real_world.yaml` scene with its robot masks (taken as it is where `out`
    already holds one)."""
    from synth.generate import SynthJob, generate

    if not (out / "_synth.json").is_file():
        overrides = (SHADOWS,) if shadows else ()
        generate(SynthJob(robot=robot, out_dir=out, num_frames=frames,
                          config=randomisation(robot, False, overrides), seed=seed,
                          keypoints=robot_keypoints(robot)),
                 overwrite=True, on_progress=lambda done: None)
    return out


def counts(data: Path, variants: dict[str, ShadowSettings | None]) -> dict[str, np.ndarray]:
    """For each variant of the shadow test (None: none), (true positives, false positives,
    false negatives) of the motion masks of every frame of `data` against its robot masks; the
    background model (which the test does not change) and the images read once."""
    seq = read_sequence(data)
    background, settings = sequence_motion_model(seq, MotionSettings())
    out = {name: np.zeros(3, np.int64) for name in variants}
    for frame in seq.frames:
        image = load_image(frame, seq.camera)[None]
        robot = load_mask(frame, seq.camera) > 0
        for name, shadow in variants.items():
            mask = motion_masks(image, background, replace(settings, shadow=shadow))[0]
            out[name] += (np.count_nonzero(mask & robot), np.count_nonzero(mask & ~robot),
                          np.count_nonzero(~mask & robot))
    return out


def shares(c: np.ndarray) -> str:
    tp, fp, fn = c
    return f"precision {tp / max(tp + fp, 1):.3f} recall {tp / max(tp + fn, 1):.3f}"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", default="panda,ur5,xarm7")
    p.add_argument("--scenes", type=int, default=5)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--first-seed", type=int, default=1000)
    p.add_argument("--work", type=Path, help="keep the scenes here (and reuse them)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a ShadowSettings field for a second variant of the test")
    args = p.parse_args()
    variants = {"without the test": None, "with the test": ShadowSettings()}
    if args.set:
        changed = {k: float(v) for k, v in (item.split("=", 1) for item in args.set)}
        variants[f"with {', '.join(args.set)}"] = replace(ShadowSettings(), **changed)
    totals = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = args.work or Path(tmp)
        for robot in args.robots.split(","):
            for seed in range(args.first_seed, args.first_seed + args.scenes):
                for shadows in (False, True):
                    data = render(robot, seed, args.frames, shadows,
                                  root / f"{robot}_{seed}{'_shadows' if shadows else ''}")
                    line = f"{robot} {seed} {'shadows' if shadows else 'plain  '}"
                    for name, c in counts(data, variants).items():
                        totals[(shadows, name)] = totals.get((shadows, name), 0) + c
                        line += f" | {name}: {shares(c)}"
                    print(line, flush=True)
    for (shadows, name), c in totals.items():
        print(f"all, {'with' if shadows else 'without'} shadows, {name}: {shares(c)}")


if __name__ == "__main__":
    main()
