"""Is the stated uncertainty honest? The extrinsic's error against its 1-sigma.

For rendered fixed-camera scenes (`synth.demo` recipe, seeds `--first-seed`.., ground truth) and for
`--data` folders (e.g. ../shared/realdata/panda_teleop with its reference extrinsic; without
one, e.g. franka_offline, only the sigmas are printed), detects the
keypoints with `--model` (onnxruntime, as `dream calibrate`), solves the extrinsic as
`dream calibrate --frames MODE` and compares its camera-position error with two covariances:
the fit's (independent detection errors) and the reported one (the fit's plus the keypoint
jackknife's, `dream.calibration`). Per sequence: the error, each covariance's 1-sigma (root of
the trace of the camera-position covariance, mm) and the squared Mahalanobis distance of the
error (chi-square with 3 degrees of freedom when the covariance is right: median 2.37, 95 %
below 7.81); then the share inside the 95 % ellipsoid (target: about 95 %).

`--frames each` does this for every frame's own extrinsic that has a jackknife (rows are
frames) and also prints the error of the reported frame (the smallest trace of the reported
covariance) against that of the frame the fit's covariance alone would pick.

    python benchmarks/uncertainty.py [--model dream/models/panda_cpu.onnx] [--scenes 20]
        [--first-seed 100] [--held-object] [--frames all|each] [--data DIR ...] [--out WORK_DIR]
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dream.detection import detect_keypoints, load_keypoint_model, load_model_robot
from dream.errors import DreamError
from dream.io import read_sequence
from dream.pipeline import calibrate
from dream.pnp import PoseFit
from dream.readings import with_interpolated_readings
from dream.transforms import camera_position_covariance, invert_T

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MODEL = REPO / "dream" / "models" / "panda_cpu.onnx"
CHI2_3_MEDIAN = 2.366
CHI2_3_95 = 7.815
FIRST_SCENE_SEED = 100


def position_error(T: np.ndarray, T_true: np.ndarray | None) -> np.ndarray | None:
    """(3,) error of the camera position in the base frame, m (None without a truth)."""
    return None if T_true is None else invert_T(T)[:3, 3] - invert_T(T_true)[:3, 3]


def error_mm(T: np.ndarray, T_true: np.ndarray | None) -> float:
    error = position_error(T, T_true)
    return np.nan if error is None else 1000 * float(np.linalg.norm(error))


def pose_row(T: np.ndarray, T_true: np.ndarray | None, fit_covariance: np.ndarray,
             reported_covariance: np.ndarray) -> dict[str, float]:
    """Error and the two covariances' sigma and chi-square of one extrinsic."""
    error = position_error(T, T_true)
    row = {"error_mm": error_mm(T, T_true)}
    for name, covariance in (("fit", fit_covariance), ("reported", reported_covariance)):
        C = camera_position_covariance(T, covariance)
        row[f"{name}_sigma_mm"] = 1000 * float(np.sqrt(np.trace(C)))
        row[f"{name}_chi2"] = np.nan if error is None else float(error @ np.linalg.solve(C, error))
    return row


def sequence_rows(data: Path, model, frames: str) -> tuple[list[dict[str, float]], dict]:
    """The rows of one sequence (all: its extrinsic; each: every frame with a jackknife) and,
    in each mode, the errors of the reported frame and of the fit-only choice (the frame with
    the smallest trace of the fit's covariance among all solved frames, without the
    jackknife). A held joint log is interpolated in time, as `dream calibrate` does."""
    seq, _ = with_interpolated_readings(read_sequence(data))
    T_true = seq.T_cam_base_truth(seq.frames[0])       # None: sigmas only
    robot = load_model_robot(seq, model)
    obs = detect_keypoints(seq, robot, model, peak_params=model.peak_params)
    result = calibrate(seq, obs, frames)
    if frames == "all":
        return [pose_row(result.fit.T_cam_base, T_true, result.fit.covariance,
                         result.covariance)], {}
    with_jackknife = [f for f in result.frames if f.jackknife is not None]
    rows = [pose_row(f.fit.T_cam_base, T_true, f.fit.covariance, f.covariance)
            for f in with_jackknife]
    fit_choice = min((f.fit for f in result.frames if isinstance(f.fit, PoseFit)),
                     key=lambda fit: np.trace(fit.covariance))
    choice = {"reported": error_mm(result.fit.T_cam_base, T_true),
              "fit_only": error_mm(fit_choice.T_cam_base, T_true)}
    return rows, choice


def print_summary(label: str, rows: list[dict[str, float]], unit: str = "sequences") -> None:
    error = np.median([r["error_mm"] for r in rows])
    truth = bool(np.isfinite(error))
    print(f"{label}: {len(rows)} {unit}, " + (f"median error {error:.1f} mm" if truth else
                                                 "no reference extrinsic (sigmas only)"))
    for name in ("fit", "reported"):
        chi2 = np.array([r[f"{name}_chi2"] for r in rows])
        sigma = np.median([r[f"{name}_sigma_mm"] for r in rows])
        inside = chi2 <= CHI2_3_95
        print(f"  {name:8s} covariance: median 1-sigma {sigma:6.1f} mm" + (
            f", median chi2 {np.median(chi2):8.2f} (right: {CHI2_3_MEDIAN}), inside the 95 % "
            f"ellipsoid {inside.mean():.0%} ({int(inside.sum())}/{len(chi2)})" if truth else ""))


def print_row(label: str, row: dict[str, float]) -> None:
    print(f"{label}: error {row['error_mm']:6.1f} mm; fit 1-sigma {row['fit_sigma_mm']:5.1f} mm, "
          f"chi2 {row['fit_chi2']:8.2f}; reported 1-sigma {row['reported_sigma_mm']:5.1f} mm, "
          f"chi2 {row['reported_chi2']:6.2f}", flush=True)


def print_choices(label: str, choices: list[dict]) -> None:
    for name, text in (("reported", "the reported frame (fit + jackknife)"),
                       ("fit_only", "the frame the fit's covariance alone would pick")):
        e = np.array([c[name] for c in choices])
        print(f"{label}, {text}: median error {np.median(e):.1f} mm, mean {np.mean(e):.1f} mm, "
              f"max {np.max(e):.1f} mm")


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
    parser.add_argument("--frames", choices=("all", "each"), default="all",
                        help="as dream calibrate --frames")
    parser.add_argument("--out", default=None, help="keep the rendered scenes here")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    start = time.perf_counter()
    try:
        model = load_keypoint_model(args.model, threads=args.threads)
        with tempfile.TemporaryDirectory() as tmp:
            work = Path(args.out or tmp)
            rows, choices = [], []
            unit = "sequences" if args.frames == "all" else "frames"
            if args.scenes > 0:
                from synth.demo import render_demo_scene

                for k in range(args.scenes):
                    seed = args.first_seed + k
                    data = render_demo_scene(work / f"scene_{seed}", seed=seed,
                                             held_object=args.held_object)
                    scene_rows, choice = sequence_rows(data, model, args.frames)
                    rows += scene_rows
                    if choice:
                        choices.append(choice)
                        print(f"scene seed {seed}: {len(scene_rows)} frames; the reported "
                              f"frame's error {choice['reported']:.1f} mm (fit-only choice: "
                              f"{choice['fit_only']:.1f} mm)", flush=True)
                    else:
                        print_row(f"scene seed {seed}", scene_rows[0])
                held = ", the arm holding an object" if args.held_object else ""
                label = f"{args.scenes} rendered scenes (30 frames each{held})"
                print_summary(label, rows, unit)
                if choices:
                    print_choices(label, choices)
            for folder in args.data:
                data_rows, choice = sequence_rows(Path(folder), model, args.frames)
                if choice:
                    print_summary(folder, data_rows, unit)
                    if np.isfinite(choice["reported"]):
                        print_choices(folder, [choice])
                else:
                    print_row(folder, data_rows[0])
    except DreamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
