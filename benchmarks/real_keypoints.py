"""How a keypoint model transfers to the real Panda photos, keypoints only (no image refinement).

For each model (ONNX files, compared in the same run):

1. panda_teleop: the detections against the reference extrinsic's projection of the keypoints:
   per keypoint the median error (px) over the frames where it was found and inside the image,
   and for the wrist keypoints (link6, link7, hand) the share of frames 0-199 where it lies
   within 10 px; then the all-frames extrinsic from the keypoints alone (`dream calibrate
   --refine none`): camera position and rotation error against the reference;
2. franka_offline: the spread of the keypoint-only extrinsic over the 45 leave-two-frames-out
   subsets (median and maximum distance of the camera position from the all-frames one).

A model from which `dream calibrate` solves no extrinsic for a set is reported as such (its
error on stderr) and the comparison goes on with the next set and model.

The real sets are evaluated, never used to train or to choose anything.

    python benchmarks/real_keypoints.py MODEL.onnx [MODEL2.onnx ...] [--realdata DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import itertools
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

import dream
from dream.camera import project
from dream.cli import main as dream_cli
from dream.io import read_sequence, write_dream
from dream.metrics import pose_errors
from dream.transforms import invert_T, transform_points

REPO = Path(__file__).resolve().parents[1]
WRIST = ("panda_link6", "panda_link7", "panda_hand")
WITHIN_PX = 10.0
FIRST_FRAMES = 200
LEAVE_OUT = 2


class NotSolved(Exception):
    """`dream calibrate` found no extrinsic from a model's keypoints on a data folder."""


def _calibrate(data: Path, model: Path, out: Path) -> np.ndarray:
    with contextlib.redirect_stdout(io.StringIO()):
        code = dream_cli(["calibrate", "--data", str(data), "--model", str(model), "--refine",
                          "none", "--out", str(out)])
    if code != 0:
        raise NotSolved(f"dream calibrate failed on {data} (exit {code})")
    return np.array(json.loads(out.read_text())["T_cam_base"])


def teleop(model: Path, realdata: Path, work: Path) -> None:
    data = realdata / "panda_teleop" / "panda_1"
    seq = read_sequence(data)
    robot = dream.load_robot("panda")
    obs = dream.detect(seq, robot, dream.load_keypoint_model(model))
    uv_ref = project(seq.camera, transform_points(seq.T_cam_base_reference, obs.P_base))
    inside = (uv_ref[..., 0] >= 0) & (uv_ref[..., 0] < seq.camera.width) & \
        (uv_ref[..., 1] >= 0) & (uv_ref[..., 1] < seq.camera.height)
    error = np.linalg.norm(obs.uv - uv_ref, axis=-1)
    print("   panda_teleop, detections against the reference projection:")
    for k, name in enumerate(obs.keypoint_names):
        found = obs.found[:, k] & inside[:, k]
        line = f"     {name:12s} median {np.median(error[found, k]):6.1f} px ({found.sum()} frames)"
        if name in WRIST:
            first = slice(0, FIRST_FRAMES)
            near = np.sum(obs.found[first, k] & (error[first, k] <= WITHIN_PX))
            line += f", within {WITHIN_PX:g} px in {near} of {FIRST_FRAMES} first frames"
        print(line)
    try:
        T = _calibrate(data, model, work / "teleop.json")
    except NotSolved:
        print("   panda_teleop all frames, keypoints only: not solved")
        return
    t_err, r_err = pose_errors(T, seq.T_cam_base_reference)
    print(f"   panda_teleop all frames, keypoints only: {t_err * 1e3:.1f} mm, "
          f"{np.rad2deg(r_err):.2f} deg")


def franka(model: Path, realdata: Path, work: Path) -> None:
    data = realdata / "franka_offline"
    seq = read_sequence(data)
    try:
        centre = invert_T(_calibrate(data, model, work / "franka.json"))[:3, 3]
    except NotSolved:
        print("   franka_offline all frames, keypoints only: not solved")
        return
    subsets = list(itertools.combinations(range(len(seq)), LEAVE_OUT))
    distances = []
    for drop in subsets:
        frames = tuple(f for i, f in enumerate(seq.frames) if i not in drop)
        folder = work / "l2o" / "_".join(map(str, drop))
        write_dream(dataclasses.replace(seq, frames=frames), folder)
        try:
            T = _calibrate(folder, model, folder / "r.json")
        except NotSolved:
            continue
        distances.append(np.linalg.norm(invert_T(T)[:3, 3] - centre))
    head = (f"   franka_offline leave-two-frames-out, keypoints only ({len(distances)} of "
            f"{len(subsets)} solved)")
    if not distances:
        print(head)
        return
    print(f"{head}: spread median {np.median(distances) * 1e3:.1f} mm, max "
          f"{np.max(distances) * 1e3:.1f} mm")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", type=Path, nargs="+")
    parser.add_argument("--realdata", type=Path, default=REPO.parent / "shared" / "realdata")
    args = parser.parse_args()
    for model in args.models:
        print(model)
        with tempfile.TemporaryDirectory() as work:
            teleop(model, args.realdata, Path(work))
            franka(model, args.realdata, Path(work))
    return 0


if __name__ == "__main__":
    sys.exit(main())
