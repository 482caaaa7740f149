"""How good must single-frame keypoints be for a single-frame ADD AUC target?

Solves every frame of a set with ground truth from its true in-frame keypoints plus Gaussian
pixel noise of each `--sigmas` value (per coordinate, image pixels; no outliers, no missed
detections; `--repeats` draws per frame), with the same single-frame solver and ADD AUC as
`dream calibrate --frames each` and `dream eval`, and prints the ADD AUC and median ADD per noise
level: the ceiling that keypoints of that accuracy allow on this set's cameras and poses,
whatever the network. The median keypoint error (L2) of each level is sigma sqrt(2 ln 2), to
compare with `dream eval`'s keypoint_l2_px median.

    python benchmarks/keypoint_noise_limit.py --data DATA_DIR [--sigmas 0.25 0.5 1 2]
        [--repeats 5] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from dream.errors import DreamError
from dream.io import read_sequence
from dream.metrics import (
    ADD_AUC_STEP_M,
    ADD_AUC_THRESHOLD_M,
    MIN_INFRAME_KEYPOINTS,
    add_per_frame,
    auc,
)
from dream.pipeline import robot_for, true_keypoints
from dream.pnp import RAYLEIGH_MEDIAN, PoseFit, solve_pnp_batch


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="a set with ground-truth extrinsics")
    parser.add_argument("--sigmas", type=float, nargs="+", default=[0.25, 0.5, 1.0, 2.0],
                        help="pixel noise per coordinate (image pixels)")
    parser.add_argument("--repeats", type=int, default=5, help="noise draws per frame")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if any(not s >= 0 for s in args.sigmas) or args.repeats < 1:
        parser.error("--sigmas must be >= 0 and --repeats >= 1")
    try:
        seq = read_sequence(args.data)
        truth = true_keypoints(seq, robot_for(seq, None))
    except DreamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    P_base, T_true, in_frame = truth.P_base, truth.T_cam_base, truth.in_frame
    counted = np.flatnonzero(truth.counted)                       # as `dream eval`
    cameras = [seq.frame_camera(i) for i in range(len(seq))]
    rng = np.random.default_rng(args.seed)
    print(f"{args.data}: {len(counted)} of {len(seq)} frames with >= {MIN_INFRAME_KEYPOINTS} "
          f"in-frame keypoints (mean {in_frame[counted].sum(axis=1).mean():.1f} of "
          f"{in_frame.shape[1]}); camera {seq.camera.width}x{seq.camera.height}, "
          f"fx {seq.camera.fx:.1f} px")
    frames = np.tile(counted, args.repeats)
    for sigma in args.sigmas:
        uv = truth.uv[frames] + rng.normal(0.0, sigma, truth.uv[frames].shape)
        uv[~in_frame[frames]] = np.nan
        fits = solve_pnp_batch(P_base[frames], uv, [cameras[i] for i in frames.tolist()])
        T_est = np.array([fit.T_cam_base if isinstance(fit, PoseFit) else np.full((4, 4), np.nan)
                          for fit in fits])                          # NaN: failed, ADD inf
        add = add_per_frame(P_base[frames], T_est, T_true[frames])
        print(f"noise {sigma:5.2f} px per coordinate (median L2 {RAYLEIGH_MEDIAN * sigma:5.2f} "
              f"px): ADD AUC {100 * auc(add, ADD_AUC_THRESHOLD_M, ADD_AUC_STEP_M):5.1f}, median "
              f"ADD {1000 * np.median(add):6.1f} mm ({len(add)} solves)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
