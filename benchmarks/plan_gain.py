"""Planned poses against random valid poses, closed loop in simulation.

For `--placements` camera placements around the robot (1-2 m away, aimed near the robot, as
`dream sample` draws them; a camera that sees the robot whole in no pose is drawn again),
`--num` poses are planned (`dream plan`'s code) with the true camera stated, and as many are
drawn at random from the same valid candidates. Both sets are then
calibrated (one extrinsic from all frames, `dream calibrate --frames all`'s solver):

- predicted: the worst-direction 1-sigma of the camera position from the Fisher information;
- labels: the true projections plus `--noise-px` Gaussian noise, `--noise-trials` draws;
- detector: the poses rendered from the true camera (plain scene, grey background) and
  detected by `--model`;
- offset: the plan made with a stated camera `--offset-m` and `--offset-deg` away from the truth
  (random directions; one in which it sees the robot whole in no pose is drawn again), measured
  with noisy labels at the true camera against the plan made with the true camera.

Prints one row per placement and the medians over placements, with the ratios random / planned.

    python benchmarks/plan_gain.py [--placements 20] [--num 12] [--noise-px 1]
        [--noise-trials 20] [--model dream/models/panda_cpu.onnx | --no-detector]
        [--offset-m 0.1] [--offset-deg 5] [--margin-px 20] [--max-cut 0.2] [--seed 0]
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import numpy as np

from dream.calibration import Observations, calibrate_all
from dream.camera import project
from dream.detection import detect_keypoints, load_keypoint_model
from dream.errors import DreamError, InputError
from dream.io.images import encode_png
from dream.robot import load_robot
from dream.sample import SampleSettings, random_camera_pose
from dream.sequence import Frame, Sequence
from dream.transforms import R_from_rotvec, invert_T, transform_points
from plan.camera_prior import CameraPrior
from plan.design import information_table, predicted_sigmas
from plan.feasibility import Feasibility
from plan.output import render_poses
from plan.planner import PlanSettings, choose_poses, find_candidates, joint_ranges

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MODEL = REPO / "dream" / "models" / "panda_cpu.onnx"
STATED_POSITION_SIGMA_M = 0.05    # the stated camera's uncertainty when it is the truth
STATED_ROTATION_SIGMA_DEG = 3.0
MAX_REDRAWS = 20


def camera_error_mm(T: np.ndarray, T_true: np.ndarray) -> float:
    return 1e3 * float(np.linalg.norm(invert_T(T)[:3, 3] - invert_T(T_true)[:3, 3]))


def offset_pose(T_cam_base: np.ndarray, rng: np.random.Generator, offset_m: float,
                offset_rad: float) -> np.ndarray:
    """The camera moved `offset_m` and turned `offset_rad`, each in a random direction."""
    T = invert_T(T_cam_base)
    axis, shift = rng.normal(size=3), rng.normal(size=3)
    T[:3, :3] = T[:3, :3] @ R_from_rotvec(axis / np.linalg.norm(axis) * offset_rad)
    T[:3, 3] += shift / np.linalg.norm(shift) * offset_m
    return invert_T(T)


def label_errors(robot, joints, camera, T_true, noise_px, trials, rng) -> list[float]:
    """Camera-position errors (mm) of calibrations from noisy labels of `joints`; keypoints
    outside the image are not observed."""
    P_base = robot.forward_kinematics(joints)
    uv_true = project(camera, transform_points(T_true, P_base))
    seen = camera.in_image(uv_true)[..., None]
    names = tuple(f"{i:06d}" for i in range(len(joints)))
    errors = []
    for _ in range(trials):
        uv = np.where(seen, uv_true + rng.normal(0, noise_px, uv_true.shape), np.nan)
        obs = Observations(P_base, uv, np.ones(uv.shape[:2]), names, robot.keypoint_names)
        errors.append(camera_error_mm(calibrate_all(obs, camera).fit.T_cam_base, T_true))
    return errors


def detector_error(robot, model, joints, camera, T_true, work: Path) -> float:
    """Camera-position error (mm) of a calibration from `model`'s detections on renders."""
    frames = []
    for i, rgb in enumerate(render_poses(robot, joints, camera, T_true)):
        path = work / f"{i:06d}.png"
        path.write_bytes(encode_png(rgb, path))
        frames.append(Frame(name=f"{i:06d}", joints=joints[i], image_path=path))
    sequence = Sequence(robot=robot.name, camera=camera, joint_names=robot.joint_names,
                        keypoint_names=robot.keypoint_names, frames=tuple(frames))
    obs = detect_keypoints(sequence, robot, model)
    return camera_error_mm(calibrate_all(obs, camera).fit.T_cam_base, T_true)


def draw_placement(robot, feasibility, settings, ranges, rng):
    """(the true camera stated, its valid candidates, cameras redrawn before it): cameras are
    drawn until one sees every keypoint in some pose (a camera 1 m from the robot cannot see
    its base and its raised hand at once)."""
    spec = SampleSettings()
    for redrawn in range(MAX_REDRAWS):
        truth = CameraPrior(spec.camera, random_camera_pose(rng, spec), STATED_POSITION_SIGMA_M,
                            np.deg2rad(STATED_ROTATION_SIGMA_DEG))
        try:
            return truth, find_candidates(robot, truth, feasibility, settings, ranges), redrawn
        except InputError as exc:
            logging.getLogger("plan_gain").info("camera redrawn: %s", exc)
    raise InputError(f"no camera of {MAX_REDRAWS} drawn sees the robot whole")


def offset_placement(T_true, args, robot, feasibility, settings, ranges, rng):
    """(a stated camera `--offset-m` / `--offset-deg` off the truth, its valid candidates,
    directions redrawn before it): a direction in which the stated camera sees the robot whole
    in no pose (its base leaves the view) is drawn again."""
    camera = SampleSettings().camera
    for redrawn in range(MAX_REDRAWS):
        stated = CameraPrior(camera, offset_pose(T_true, rng, args.offset_m,
                                                 np.deg2rad(args.offset_deg)),
                             args.offset_m / np.sqrt(3), np.deg2rad(args.offset_deg) / np.sqrt(3))
        try:
            return stated, find_candidates(robot, stated, feasibility, settings, ranges), redrawn
        except InputError as exc:
            logging.getLogger("plan_gain").info("offset redrawn: %s", exc)
    raise InputError(f"no stated camera of {MAX_REDRAWS} drawn sees the robot whole")


def run_placement(index: int, args, robot, model, rng) -> dict[str, float]:
    camera = SampleSettings().camera
    settings = PlanSettings(num_poses=args.num, candidates=args.candidates,
                            noise_px=args.noise_px, seed=args.seed + index)
    feasibility = Feasibility(margin_px=args.margin_px, max_cut=args.max_cut)
    ranges = joint_ranges(robot)
    truth, candidates, redrawn = draw_placement(robot, feasibility, settings, ranges, rng)
    T_true = truth.T_cam_base
    planned = choose_poses(robot, truth, candidates, settings).joints
    random = candidates.joints[rng.choice(len(candidates.joints), args.num, replace=False)]
    F = information_table(robot.forward_kinematics(np.concatenate([planned, random])), camera,
                          T_true[None], args.noise_px)[0]
    row = {"redrawn": redrawn, "planned_sigma": 1e3 * predicted_sigmas(F[:args.num].sum(0),
                                                   T_true)["position_worst_m"],
           "random_sigma": 1e3 * predicted_sigmas(F[args.num:].sum(0),
                                                  T_true)["position_worst_m"]}
    row["planned_labels"] = float(np.median(label_errors(
        robot, planned, camera, T_true, args.noise_px, args.noise_trials, rng)))
    row["random_labels"] = float(np.median(label_errors(
        robot, random, camera, T_true, args.noise_px, args.noise_trials, rng)))
    stated, offset_candidates, row["offset_redrawn"] = offset_placement(
        T_true, args, robot, feasibility, settings, ranges, rng)
    offset = choose_poses(robot, stated, offset_candidates, settings).joints
    row["offset_labels"] = float(np.median(label_errors(
        robot, offset, camera, T_true, args.noise_px, args.noise_trials, rng)))
    if model is not None:
        with tempfile.TemporaryDirectory() as work:
            row["planned_detector"] = detector_error(robot, model, planned, camera, T_true,
                                                     Path(work))
            row["random_detector"] = detector_error(robot, model, random, camera, T_true,
                                                    Path(work))
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--placements", type=int, default=20)
    p.add_argument("--num", type=int, default=12)
    p.add_argument("--candidates", type=int, default=600)
    p.add_argument("--noise-px", type=float, default=1.0)
    p.add_argument("--noise-trials", type=int, default=20)
    p.add_argument("--model", default=str(DEFAULT_MODEL))
    p.add_argument("--no-detector", action="store_true")
    p.add_argument("--offset-m", type=float, default=0.1)
    p.add_argument("--offset-deg", type=float, default=5.0)
    p.add_argument("--margin-px", type=float, default=Feasibility.margin_px)
    p.add_argument("--max-cut", type=float, default=Feasibility.max_cut)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)
    robot = load_robot("panda")
    model = None if args.no_detector else load_keypoint_model(args.model)
    if model is not None:
        robot = robot.with_keypoints(model.keypoint_names)
    rng = np.random.default_rng(args.seed)
    rows, start = [], time.perf_counter()
    columns = ["planned_sigma", "random_sigma", "planned_labels", "random_labels",
               "offset_labels"] + ([] if model is None else ["planned_detector",
                                                             "random_detector"])
    print("camera-position error, mm (sigma: predicted worst-direction 1-sigma; labels: "
          f"median over {args.noise_trials} draws of {args.noise_px:g} px noise)")
    print(f"{'placement':>9} " + " ".join(f"{c:>16}" for c in columns))
    for i in range(args.placements):
        try:
            row = run_placement(i, args, robot, model, rng)
        except DreamError as exc:
            print(f"{i:>9} failed: {exc}")
            continue
        rows.append(row)
        print(f"{i:>9} " + " ".join(f"{row[c]:>16.2f}" for c in columns), flush=True)
    median = {c: float(np.median([r[c] for r in rows])) for c in columns}
    print(f"{'median':>9} " + " ".join(f"{median[c]:>16.2f}" for c in columns))
    print(f"ratios random / planned: predicted sigma "
          f"{median['random_sigma'] / median['planned_sigma']:.2f}, labels "
          f"{median['random_labels'] / median['planned_labels']:.2f}"
          + ("" if model is None else ", detector "
             f"{median['random_detector'] / median['planned_detector']:.2f}"))
    print(f"stated camera {args.offset_m:g} m / {args.offset_deg:g} deg off: labels error "
          f"{median['offset_labels']:.2f} mm against {median['planned_labels']:.2f} mm "
          f"({median['offset_labels'] / median['planned_labels'] - 1:+.0%})")
    redrawn = sum(int(r["redrawn"]) for r in rows)
    offsets = sum(int(r["offset_redrawn"]) for r in rows)
    print(f"redrawn because they saw no pose whole: {redrawn} true cameras, {offsets} offset "
          "directions")
    per_placement = np.array([[r["random_sigma"] / r["planned_sigma"],
                               r["random_labels"] / r["planned_labels"]] for r in rows])
    print(f"per-placement ratio medians: predicted {np.median(per_placement[:, 0]):.2f}, "
          f"labels {np.median(per_placement[:, 1]):.2f}; {len(rows)} placements in "
          f"{time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
