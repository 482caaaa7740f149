"""Efficiency of the extrinsic solver against the Cramer-Rao bound.

Random Panda scenes: camera 1-2 m away aimed at the robot, random joints, 1 px Gaussian noise on
every in-image keypoint. For 1 and 20 frames, solve with `calibrate_all` and print the achieved
RMS translation and rotation errors divided by the RMS of the bound (target for 20 frames:
<= 1.10; 1.00 is an efficient estimator).

    python benchmarks/pnp_efficiency.py [--trials 200] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from dream.calibration import Observations, calibrate_all
from dream.camera import project
from dream.crb import extrinsic_crb
from dream.errors import CalibrationError
from dream.robot import load_robot
from dream.sample import SampleSettings, random_camera_pose, random_joints
from dream.transforms import rotvec_from_R, transform_points

NOISE_PX = 1.0


def trial(rng: np.random.Generator, robot, spec: SampleSettings, frames: int):
    """One random scene solved; returns (xi error, CRB) or None when it cannot be solved."""
    camera = spec.camera
    T = random_camera_pose(rng, spec)
    q = random_joints(rng, robot, frames, spec.joint_range_fraction)
    P_base = robot.forward_kinematics(q)
    uv_true = project(camera, transform_points(T, P_base))
    visible = camera.in_image(uv_true) & np.all(np.isfinite(uv_true), -1)
    if visible.sum() < 6:
        return None
    uv = np.where(visible[..., None], uv_true + rng.normal(0, NOISE_PX, uv_true.shape), np.nan)
    obs = Observations(P_base, uv, visible.astype(float), tuple(map(str, range(frames))),
                       robot.keypoint_names)
    try:
        crb = extrinsic_crb(P_base[visible], camera, T, NOISE_PX)
        fit = calibrate_all(obs, camera).fit
    except CalibrationError:
        return None
    e = np.concatenate([rotvec_from_R(T[:3, :3] @ fit.T_cam_base[:3, :3].T),
                        T[:3, 3] - fit.T_cam_base[:3, 3]])
    return e, crb


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    robot = load_robot("panda")
    spec = SampleSettings()
    print(f"Panda, {NOISE_PX:g} px noise, camera {spec.distance_m[0]:g}-{spec.distance_m[1]:g} m, "
          f"{args.trials} trials per row")
    print(f"{'frames':>6} {'solved':>7} {'rms_t_mm':>9} {'crb_t_mm':>9} {'ratio_t':>8} "
          f"{'rms_r_deg':>10} {'crb_r_deg':>10} {'ratio_r':>8} {'s/solve':>8}")
    for frames in (1, 20):
        rng = np.random.default_rng(args.seed + frames)
        errors, bounds = [], []
        start = time.perf_counter()
        for _ in range(args.trials):
            out = trial(rng, robot, spec, frames)
            if out is not None:
                errors.append(out[0])
                bounds.append(out[1])
        seconds = (time.perf_counter() - start) / args.trials
        e, b = np.array(errors), np.array(bounds)
        rms_t = np.sqrt(np.mean(np.sum(e[:, 3:] ** 2, 1)))
        crb_t = np.sqrt(np.mean(np.trace(b[:, 3:, 3:], axis1=1, axis2=2)))
        rms_r = np.sqrt(np.mean(np.sum(e[:, :3] ** 2, 1)))
        crb_r = np.sqrt(np.mean(np.trace(b[:, :3, :3], axis1=1, axis2=2)))
        print(f"{frames:>6} {len(e):>7} {rms_t * 1e3:>9.3f} {crb_t * 1e3:>9.3f} "
              f"{rms_t / crb_t:>8.3f} {np.rad2deg(rms_r):>10.4f} {np.rad2deg(crb_r):>10.4f} "
              f"{rms_r / crb_r:>8.3f} {seconds:>8.3f}")


if __name__ == "__main__":
    main()
