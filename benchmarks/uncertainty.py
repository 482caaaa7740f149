"""Is the stated uncertainty honest? The all-frames extrinsic's error against its 1-sigma.

For rendered fixed-camera scenes (`synth.demo` recipe, seeds `--first-seed`.., ground truth) and for
`--data` folders (e.g. ../shared/realdata/panda_teleop with its reference extrinsic; without
one, e.g. franka_offline, only the sigmas are printed), detects the
keypoints with `--model` (onnxruntime, as `dream calibrate`), solves the all-frames extrinsic
and compares its camera-position error with two covariances: the fit's (independent detection
errors) and the reported one (the fit's plus the keypoint jackknife's, `dream.calibrate`). Per
scene: the error, each covariance's 1-sigma (root of the trace of the camera-position
covariance, mm) and the squared Mahalanobis distance of the error (chi-square with 3 degrees of
freedom when the covariance is right: median 2.37, 95 % below 7.81); then the share of scenes
inside the 95 % ellipsoid (target: about 95 %).

    python benchmarks/uncertainty.py [--model dream/models/panda_cpu.onnx] [--scenes 20]
        [--first-seed 100] [--held-object] [--data DIR ...] [--out WORK_DIR]
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dream.detect import detect_keypoints, load_keypoint_model, load_model_robot
from dream.errors import DreamError
from dream.io import read_sequence
from dream.pipeline import calibrate
from dream.result import camera_position_covariance
from dream.transforms import invert_T

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MODEL = REPO / "dream" / "models" / "panda_cpu.onnx"
CHI2_3_MEDIAN = 2.366
CHI2_3_95 = 7.815
FIRST_SCENE_SEED = 100


def scene_row(data: Path, model) -> dict[str, float]:
    """Error and the two covariances' sigma and chi-square of one sequence's all-frames fit."""
    seq = read_sequence(data)
    T_true = seq.T_cam_base_truth(seq.frames[0])       # None: sigmas only
    robot = load_model_robot(seq, model)
    obs = detect_keypoints(seq, robot, model, peak_params=model.peak_params)
    result = calibrate(seq, obs, "all")
    T = result.fit.T_cam_base
    error = None if T_true is None else invert_T(T)[:3, 3] - invert_T(T_true)[:3, 3]
    row = {"error_mm": np.nan if error is None else 1000 * float(np.linalg.norm(error))}
    for name, covariance in (("fit", result.fit.covariance), ("reported", result.covariance)):
        C = camera_position_covariance(T, covariance)
        row[f"{name}_sigma_mm"] = 1000 * float(np.sqrt(np.trace(C)))
        row[f"{name}_chi2"] = np.nan if error is None else float(error @ np.linalg.solve(C, error))
    return row


def print_summary(label: str, rows: list[dict[str, float]]) -> None:
    error = np.median([r["error_mm"] for r in rows])
    print(f"{label}: {len(rows)} sequences, median error {error:.1f} mm")
    for name in ("fit", "reported"):
        chi2 = np.array([r[f"{name}_chi2"] for r in rows])
        sigma = np.median([r[f"{name}_sigma_mm"] for r in rows])
        inside = chi2 <= CHI2_3_95
        print(f"  {name:8s} covariance: median 1-sigma {sigma:6.1f} mm, median chi2 "
              f"{np.median(chi2):8.2f} (right: {CHI2_3_MEDIAN}), inside the 95 % ellipsoid "
              f"{inside.mean():.0%} ({int(inside.sum())}/{len(chi2)})")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(DEFAULT_MODEL))
    parser.add_argument("--scenes", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=FIRST_SCENE_SEED,
                        help="the scenes' seeds are this and the next ones")
    parser.add_argument("--held-object", action="store_true",
                        help="the arm holds an object in every scene")
    parser.add_argument("--data", action="append", default=[],
                        help="a folder with a reference or ground-truth extrinsic (repeatable)")
    parser.add_argument("--out", default=None, help="keep the rendered scenes here")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    start = time.perf_counter()
    try:
        model = load_keypoint_model(args.model, threads=args.threads)
        with tempfile.TemporaryDirectory() as tmp:
            work = Path(args.out or tmp)
            rows = []
            if args.scenes > 0:
                from synth.demo import render_demo_scene

                for k in range(args.scenes):
                    seed = args.first_seed + k
                    data = render_demo_scene(work / f"scene_{seed}", seed=seed,
                                             held_object=args.held_object)
                    row = scene_row(data, model)
                    rows.append(row)
                    print(f"scene seed {seed}: error {row['error_mm']:6.1f} mm; fit 1-sigma "
                          f"{row['fit_sigma_mm']:5.1f} mm, chi2 {row['fit_chi2']:8.2f}; reported "
                          f"1-sigma {row['reported_sigma_mm']:5.1f} mm, chi2 "
                          f"{row['reported_chi2']:6.2f}", flush=True)
                held = ", the arm holding an object" if args.held_object else ""
                print_summary(f"{args.scenes} rendered scenes (30 frames each{held})", rows)
            for folder in args.data:
                row = scene_row(Path(folder), model)
                print(f"{folder}: error {row['error_mm']:.1f} mm; fit 1-sigma "
                      f"{row['fit_sigma_mm']:.1f} mm, chi2 {row['fit_chi2']:.2f}; reported "
                      f"1-sigma {row['reported_sigma_mm']:.1f} mm, chi2 {row['reported_chi2']:.2f}")
    except DreamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
