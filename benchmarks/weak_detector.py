"""A weak detector on a second arm: does `--polish` keep the masks' optimum, and is a wrong
per-frame result ever called `good`?

Renders fixed-camera scenes of an arm other than the Panda (`synth.demo`'s scene recipe with
`--robot` and a 960x540 camera, `--frames` random arm poses, seeds from `--first-seed`; robot
masks included), then
moves every keypoint label by its own fixed offset of `--offset-px` pixels (a random direction
per keypoint and scene, the same in every frame, plus `--noise-px` of fresh noise): a detector
biased on these images, as a network trained for minutes is. Each scene is calibrated from
those labels as `dream calibrate` does:

- all frames with `--polish` (the data's masks): the pose written is "the mask optimum" when it
  lies within `--optimum-mm` of the truth;
- `--frames each` with `--refine auto` (which polishes each frame with its mask) and with
  `--refine none`: how many reported results lie more than `--wrong-mm` / `--wrong-deg` from the
  truth, and how many of those were called `good`.

It also prints how often the truth lies inside the 95 % ellipsoid of the 1-sigma written with
the polished all-frames pose (the link jackknife of `dream.refined_uncertainty`).

    python benchmarks/weak_detector.py [--robot ur5] [--scenes 20] [--first-seed 500]
        [--frames 12] [--offset-px 15 30] [--noise-px 1] [--out DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from dream.cli.calibrate import CalibrateRequest, run_calibrate
from dream.errors import DreamError
from dream.io import read_sequence
from dream.metrics import pose_errors
from dream.pnp import increment_between

CHI2_6DOF_95 = 12.592     # 95 % quantile of the chi-square distribution with 6 degrees of freedom
# a 960x540 camera, so that the label offsets are those of a detector on ordinary photos of
# the whole arm
INTRINSICS = {"width": 960, "height": 540, "fx": 700.0, "fy": 700.0, "cx": 479.5, "cy": 269.5}


def render_scene(robot: str, out: Path, seed: int, frames: int) -> Path:
    """A fixed-camera scene of `robot` with the demo's recipe (`synth.demo.DEMO_SCENE`) seen by
    a 960x540 camera (`INTRINSICS`)."""
    from synth.config import config_from_dict
    from synth.demo import DEMO_SCENE
    from synth.generate import SynthJob, generate

    job = SynthJob(robot=robot, out_dir=out, num_frames=frames,
                   config=config_from_dict({
                       **DEMO_SCENE, "intrinsics": INTRINSICS}),
                   seed=seed)
    generate(job, overwrite=True, on_progress=lambda done: None)
    return out


def weaken_labels(folder: Path, offset_px: tuple[float, float], noise_px: float,
                  rng: np.random.Generator) -> None:
    """Move every keypoint label of the scene by its own fixed offset (a magnitude drawn in
    `offset_px`, a random direction) plus fresh Gaussian noise of `noise_px` per frame."""
    files = sorted(folder.glob("[0-9]*.json"))
    names = [k["name"] for k in json.loads(files[0].read_text())["objects"][0]["keypoints"]]
    angle = rng.uniform(0.0, 2 * np.pi, len(names))
    length = rng.uniform(*offset_px, len(names))
    offsets = dict(zip(names, np.stack([np.cos(angle), np.sin(angle)], 1) * length[:, None],
                       strict=True))
    for path in files:
        doc = json.loads(path.read_text())
        for kp in doc["objects"][0]["keypoints"]:
            uv = np.asarray(kp["projected_location"], dtype=float)
            kp["projected_location"] = (uv + offsets[kp["name"]]
                                        + rng.normal(0.0, noise_px, 2)).tolist()
        path.write_text(json.dumps(doc))


def calibrate(folder: Path, out: Path, robot: str, **options) -> dict | None:
    """RESULT.json's document of `dream calibrate --use-labels` with `options` (quietly); None
    where it solves nothing (its one-line error printed)."""
    request = CalibrateRequest(data=str(folder), out=str(out), robot=robot, use_labels=True,
                               **options)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            return run_calibrate(request, out=io.StringIO())
    except DreamError as exc:
        print(f"  {folder.name} {options}: no result: {exc}", flush=True)
        return None


def inside_95(doc: dict, T_true: np.ndarray) -> bool:
    """Whether the truth lies inside the 95 % ellipsoid of the written pose's covariance."""
    xi = increment_between(np.asarray(doc["T_cam_base"], dtype=float), T_true)
    cov = np.asarray(doc["covariance_xi"], dtype=float)
    return float(xi @ np.linalg.solve(cov, xi)) <= CHI2_6DOF_95


def errors(doc: dict, T_true: np.ndarray) -> tuple[float, float]:
    """(mm, deg) of the written pose against the truth."""
    t, r = pose_errors(np.asarray(doc["T_cam_base"], dtype=float), T_true)
    return 1000 * float(t), float(np.rad2deg(r))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--scenes", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=500)
    parser.add_argument("--frames", type=int, default=12, help="frames per scene")
    parser.add_argument("--offset-px", type=float, nargs=2, default=[15.0, 30.0])
    parser.add_argument("--noise-px", type=float, default=1.0)
    parser.add_argument("--optimum-mm", type=float, default=2.0)
    parser.add_argument("--wrong-mm", type=float, default=50.0)
    parser.add_argument("--wrong-deg", type=float, default=5.0)
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the label offsets (with each scene's seed)")
    parser.add_argument("--out", type=Path, help="folder for the scenes and results")
    args = parser.parse_args()
    if args.scenes < 1 or args.frames < 2:
        parser.error("--scenes must be >= 1 and --frames >= 2")
    work = args.out or Path(tempfile.mkdtemp(prefix="dream-weak-detector-"))
    optimum, covered, keypoint_mm = 0, 0, []
    each = {"auto": [], "none": []}     # (wrong, verdict) per scene
    for seed in range(args.first_seed, args.first_seed + args.scenes):
        folder = render_scene(args.robot, work / f"scene_{seed}", seed, args.frames)
        weaken_labels(folder, tuple(args.offset_px), args.noise_px,
                      np.random.default_rng([args.seed, seed]))
        T_true = read_sequence(folder).frames[0].T_cam_base_true
        doc = calibrate(folder, work / f"polish_{seed}.json", args.robot, polish=True)
        if doc is None:
            line = ["--polish: no result"]
        else:
            mm, deg = errors(doc, T_true)
            kp_mm = 1000 * float(pose_errors(
                np.asarray(doc["polish"]["T_cam_base_keypoints"]), T_true)[0])
            keypoint_mm.append(kp_mm)
            optimum += mm <= args.optimum_mm
            covered += inside_95(doc, T_true)
            line = [f"keypoints {kp_mm:.1f} mm -> polish {mm:.2f} mm {deg:.3f} deg "
                    f"({'kept' if doc['polish']['kept'] else 'not kept'}, "
                    f"{doc['quality']['verdict']})"]
        for refine in each:
            frame_doc = calibrate(folder, work / f"each_{refine}_{seed}.json", args.robot,
                                  frames="each", refine=refine)
            if frame_doc is None:
                each[refine].append((False, "no result"))
                line.append(f"each/{refine}: no result")
                continue
            mm, deg = errors(frame_doc, T_true)
            wrong = mm > args.wrong_mm or deg > args.wrong_deg
            each[refine].append((wrong, frame_doc["quality"]["verdict"]))
            line.append(f"each/{refine}: {mm:.1f} mm {deg:.2f} deg "
                        f"{frame_doc['quality']['verdict']}")
        print(f"scene seed {seed}: " + "; ".join(line), flush=True)
    n = args.scenes
    print(f"{n} scenes of {args.robot} x {args.frames} frames (seeds {args.first_seed}-"
          f"{args.first_seed + n - 1}), labels moved {args.offset_px[0]:g}-"
          f"{args.offset_px[1]:g} px per keypoint (+{args.noise_px:g} px noise):")
    print(f"  keypoint pose: median {np.median(keypoint_mm):.1f} mm from the truth")
    print(f"  --polish: the mask optimum (within {args.optimum_mm:g} mm) kept in {optimum} of "
          f"{n}; truth inside the written 95 % ellipsoid in {covered} of {n}")
    for refine, rows in each.items():
        wrong = [v for w, v in rows if w]
        print(f"  --frames each --refine {refine}: {len(wrong)} of {n} reported results more "
              f"than {args.wrong_mm:g} mm / {args.wrong_deg:g} deg off, {wrong.count('good')} "
              f"of them called good; verdicts: " + ", ".join(
                  f"{level} {sum(v == level for _, v in rows)}"
                  for level in ("good", "check", "unreliable", "no result")))
    print(f"(scenes in {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
