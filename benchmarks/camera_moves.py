"""Does `dream calibrate` notice a fixed camera that moved while it recorded?

Renders (or reuses) fixed-camera `real_world.yaml` scenes and runs the steadiness check
(`dream.steadiness`) on each as rendered (a steady camera: any frame called moved is a false
alarm) and knocked half way: every frame from the middle on moved in the image by a shift of
`--shifts` pixels (per 320 px of width, in a random direction), a roll of `--rolls` degrees
about the image centre, or a zoom of `--zooms` (a camera pushed along its axis), as a bump of
the tripod moves it (or, `--shakes`, a shaking mount). Prints per kind of move how many
scenes were called moved, how many split at the right frame, and the false alarms on the
scenes as rendered.

With `--calibrate N`, the first scene of N robots is also written knocked (each shift)
and calibrated without keypoints (`dream calibrate`), then with `--frame-range` over
the frames before the move, to show what the move does to the pose and its verdict.

    MUJOCO_GL=egl python benchmarks/camera_moves.py --work /tmp/moves --scenes 20
    MUJOCO_GL=egl python benchmarks/camera_moves.py --work /tmp/moves --scenes 20 --calibrate 3
"""

from __future__ import annotations

import argparse
import contextlib
import io
import shutil
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from dream.cli.calibrate import CalibrateRequest, run_calibrate
from dream.edges.background import grey
from dream.io import load_image, read_sequence
from dream.metrics import pose_errors
from dream.steadiness import SteadinessSettings, camera_motion

sys.path.insert(0, str(Path(__file__).resolve().parent))
from coarse_start import render_scene  # noqa: E402

ROBOTS = ("panda", "ur5", "xarm7")
FIRST_SEED = 1000
FRAMES = 30
WIDTH_UNIT = 320.0   # shifts are given per this many pixels of image width


def knock(image: np.ndarray, kind: str, amount: float, direction: float) -> np.ndarray:
    """`image` (H, W[, 3]) as seen after the camera moved: shifted by `amount` px per 320 px
    of width along `direction` (rad), rolled `amount` deg about the centre, or zoomed by
    `amount` (a scale)."""
    height, width = image.shape[:2]
    if kind == "shift":
        step = amount * width / WIDTH_UNIT
        M = np.float32([[1, 0, step * np.cos(direction)], [0, 1, step * np.sin(direction)]])
    elif kind == "roll":
        M = cv2.getRotationMatrix2D((width / 2, height / 2), amount, 1.0)
    else:
        M = cv2.getRotationMatrix2D((width / 2, height / 2), 0.0, amount)
    return cv2.warpAffine(image, M, (width, height), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)


def scene_frames(data: Path) -> tuple[np.ndarray, int]:
    """The compared grey frames of a scene (`SteadinessSettings.compared`) and its width."""
    seq = read_sequence(data)
    indices = SteadinessSettings().compared(len(seq))
    return np.stack([grey(load_image(seq.frames[i], seq.camera)) for i in indices]), \
        seq.camera.width


def judged(frames: np.ndarray, width: int) -> dict:
    motion = camera_motion(frames, np.arange(len(frames)), SteadinessSettings(),
                           image_width=width)
    return {"moved": int(motion.moved.sum()), "largest_px": motion.largest_px,
            "stretches": motion.stretches()}


def moves(args: argparse.Namespace) -> list[tuple[str, float]]:
    return ([("shift", s) for s in args.shifts] + [("roll", r) for r in args.rolls]
            + [("zoom", z) for z in args.zooms] + [("shake", s) for s in args.shakes])


def moved_frames(frames: np.ndarray, kind: str, amount: float, direction: float,
                 rng: np.random.Generator) -> np.ndarray:
    """`frames` (n, H, W) seen by a camera knocked before its middle frame; a shaking one
    (`shake`) shifted `amount` px per 320 px anew in a random direction in each of those."""
    half = len(frames) // 2
    out = frames.copy()
    for i in range(half, len(frames)):
        if kind == "shake":
            out[i] = knock(frames[i], "shift", amount, rng.uniform(0, 2 * np.pi))
        else:
            out[i] = knock(frames[i], kind, amount, direction)
    return out


def check_scenes(scenes: list[Path], args: argparse.Namespace) -> None:
    rng = np.random.default_rng(args.seed)
    tally: dict[str, list[int]] = {"as rendered": [0, 0]}
    for data in scenes:
        frames, width = scene_frames(data)
        half = len(frames) // 2
        steady = judged(frames, width)
        tally["as rendered"][0] += steady["moved"] > 0
        print(f"{data.name}: as rendered {steady['moved']} moved "
              f"({steady['largest_px']:.2f} px)", flush=True)
        for kind, amount in moves(args):
            direction = rng.uniform(0, 2 * np.pi)
            found = judged(moved_frames(frames, kind, amount, direction, rng), width)
            stretches = found["stretches"]
            split = (len(stretches) == 2 and stretches[0][1] < half <= stretches[1][0])
            counts = tally.setdefault(f"{kind} {amount:g}", [0, 0])
            counts[0] += found["moved"] > 0
            counts[1] += split
            print(f"  {kind} {amount:g}: {found['moved']} of {len(frames) - half} moved, "
                  f"{found['largest_px']:.2f} px, split {'right' if split else 'wrong'}",
                  flush=True)
    print(f"\n{len(scenes)} scenes: false alarms as rendered {tally.pop('as rendered')[0]}")
    for name, (called, split) in tally.items():
        print(f"  {name}: called moved {called}, split at the move {split}")


def calibrate_knocked(data: Path, shift: float, work: Path) -> None:
    """The scene knocked by `shift` px at its middle frame, written to disk and calibrated
    without keypoints, then its first still stretch alone."""
    knocked = work / f"{data.name}_knocked{shift:g}"
    shutil.rmtree(knocked, ignore_errors=True)
    shutil.copytree(data, knocked)
    images = sorted(knocked.glob("*.rgb.png"))
    half = len(images) // 2
    for path in images[half:]:
        cv2.imwrite(str(path), knock(cv2.imread(str(path)), "shift", shift, 0.6))
    truth = read_sequence(data).frames[0].T_cam_base_true
    for label, frame_range in (("all frames", None), ("--frame-range", f"0:{half}")):
        out = work / f"{knocked.name}_{'range' if frame_range else 'all'}.json"
        start = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()), \
                contextlib.redirect_stderr(io.StringIO()):
            doc = run_calibrate(CalibrateRequest(data=str(knocked), out=str(out),
                                                 frame_range=frame_range))
        mm, deg = (float(v) for v in pose_errors(np.asarray(doc["T_cam_base"]), truth))
        moved = doc.get("steadiness", {}).get("moved", 0)
        print(f"{knocked.name} {label}: {mm * 1e3:.1f} mm, {np.rad2deg(deg):.2f} deg from the "
              f"camera before the move, {doc['quality']['verdict']}, {moved} frames moved, "
              f"{time.perf_counter() - start:.0f} s", flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--work", type=Path, required=True, help="scenes are rendered (or reused) here")
    p.add_argument("--scenes", type=int, default=20, help="seeds per robot")
    p.add_argument("--robots", default=",".join(ROBOTS))
    p.add_argument("--shifts", type=float, nargs="*", default=[1.0, 2.0, 4.0])
    p.add_argument("--rolls", type=float, nargs="*", default=[0.5, 1.0])
    p.add_argument("--zooms", type=float, nargs="*", default=[1.01])
    p.add_argument("--shakes", type=float, nargs="*", default=[],
                   help="a shaking mount: from the middle frame on each frame shifted this "
                        "many px per 320 px in a direction of its own (its split is not "
                        "scored)")
    p.add_argument("--seed", type=int, default=0, help="draws the shifts' directions")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a randomisation key of the scenes (repeatable), e.g. "
                        "sensor.gain_sigma=0.05 output.image_format=jpg")
    p.add_argument("--calibrate", type=int, default=0, metavar="N",
                   help="also calibrate the first scene of N robots knocked by each shift")
    args = p.parse_args()
    scenes = []
    for robot in args.robots.split(","):
        for seed in range(FIRST_SEED, FIRST_SEED + args.scenes):
            out = args.work / f"{robot}_{seed}"
            scenes.append(render_scene(robot, out, seed, FRAMES, overrides=tuple(args.set),
                                       reuse=True))
    check_scenes(scenes, args)
    for k in range(0, len(scenes), args.scenes)[:args.calibrate]:   # each robot's first
        for shift in args.shifts:
            calibrate_knocked(scenes[k], shift, args.work)


if __name__ == "__main__":
    main()
