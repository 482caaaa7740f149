"""Does the readings check (`dream.readings_check`) name a mistake in the joint readings, and
does it stay quiet on right ones?

Renders fixed-camera `real_world.yaml` scenes of each `--robots` arm (clutter, a second robot, a
held object; seeds from `--first-seed`), takes their keypoints from the bundled model (the
Panda) or from the labels plus `--label-noise-px` of noise (`--labels`, any arm), and for each
scene calibrates all frames (keypoints only) from the readings as rendered and from copies with
one mistake each: every joint negated, every two neighbouring joints swapped, each image given
the previous frame's readings (late) and each given the next frame's (early). Prints per mistake
whether the check flags it and names the right fix, the camera error of the keypoint fit it
misled, and whether the verdict without the check had called that fit `good`; then the false
flags on right readings and the share of mistakes caught.

    python benchmarks/readings_check.py [--robots panda] [--scenes 12] [--frames 30]
        [--first-seed 7000] [--labels --label-noise-px 2] [--work DIR]
        [--min-unexplained 0.03 --min-gain 0.03 --min-resolved 0.5]
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
import time
from pathlib import Path

import numpy as np

import dream
from dream.calibration import Observations
from dream.errors import DreamError
from dream.metrics import pose_errors
from dream.pipeline import calibrate, joints_in_robot_order, truth_poses
from dream.quality import GOOD, result_quality
from dream.readings_check import LAGS, ReadingsCheckSettings, check_readings, readings_finding

HERE = Path(__file__).resolve().parent
WRONG_M = 0.05          # a keypoint fit farther than this from the truth is wrong


def _coarse_start():
    spec = importlib.util.spec_from_file_location("coarse_start", HERE / "coarse_start.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def mistakes(joints: np.ndarray, names: tuple[str, ...]) -> list[tuple[str, str, np.ndarray]]:
    """(mistake, the check's name of its fix, the readings with it) for one recording."""
    out = []
    for j, name in enumerate(names):
        wrong = joints.copy()
        wrong[:, j] *= -1
        out.append((f"{name} negated", f"joint '{name}' negated", wrong))
    for j in range(len(names) - 1):
        wrong = joints.copy()
        wrong[:, [j, j + 1]] = joints[:, [j + 1, j]]
        out.append((f"{names[j]}, {names[j + 1]} swapped",
                    f"joints '{names[j]}' and '{names[j + 1]}' swapped", wrong))
    out.append(("previous readings", LAGS[-1][0], np.roll(joints, 1, axis=0)))
    out.append(("next readings", LAGS[1][0], np.roll(joints, -1, axis=0)))
    return out


def observations(seq, robot, model, noise_px: float, rng) -> Observations:
    if model is not None:
        return dream.detect(seq, robot, model)
    obs = dream.labels(seq, robot)
    return Observations(obs.P_base, obs.uv + rng.normal(0.0, noise_px, obs.uv.shape),
                        obs.confidence, obs.frame_names, obs.keypoint_names)


def scene_rows(data: Path, model, noise_px: float, seed: int,
               settings: ReadingsCheckSettings) -> list[dict]:
    """One row per readings (as rendered, then each mistake) of one rendered scene."""
    seq = dream.read_sequence(data)
    robot = dream.load_robot(seq)
    obs = observations(seq, robot, model, noise_px, np.random.default_rng(seed))
    joints = joints_in_robot_order(seq, robot)
    T_true = truth_poses(seq)[0]
    rows = []
    cases = [("as rendered", None, joints)] + mistakes(joints, tuple(robot.joint_names))
    for mistake, fix, readings in cases:
        given = Observations(robot.forward_kinematics(readings), obs.uv, obs.confidence,
                             obs.frame_names, obs.keypoint_names)
        try:
            result = calibrate(seq, given, "all")
        except DreamError as exc:
            rows.append({"mistake": mistake, "solved": False, "why": exc.problem})
            continue
        check = check_readings(result, given, robot, readings, seq.camera, settings)
        finding = readings_finding(check, settings)
        error_m, _ = pose_errors(result.T_cam_base, T_true)
        best = None if check.best is None else check.best.what
        rows.append({"mistake": mistake, "solved": True, "flagged": finding is not None,
                     "named": finding is not None and best == fix, "best": best,
                     "gain": check.gain, "resolved": check.resolved,
                     "error_mm": float(error_m) * 1e3,
                     "good_before": result_quality(result, given).verdict == GOOD})
    return rows


def _line(row: dict) -> str:
    if not row["solved"]:
        return f"{row['mistake']}: no calibration ({row['why']})"
    flag = ("FLAGGED, names the fix" if row["named"] else
            f"FLAGGED as {row['best']}" if row["flagged"] else "quiet")
    return (f"{row['mistake']}: {flag} (gain {row['gain']:+.2f}, resolved "
            f"{row['resolved']:.2f}), fit {row['error_mm']:.0f} mm"
            f"{', was good' if row['good_before'] else ''}")


def summary(rows: list[dict]) -> None:
    right = [r for r in rows if r["mistake"] == "as rendered" and r["solved"]]
    print(f"not solved (the keypoint fit failed): {sum(not r['solved'] for r in rows)} of "
          f"{len(rows)}")
    wrong = [r for r in rows if r["mistake"] != "as rendered" and r["solved"]]
    misled = [r for r in wrong if r["error_mm"] > WRONG_M * 1e3]
    print(f"readings as rendered: flagged {sum(r['flagged'] for r in right)} of {len(right)}")
    print(f"mistakes: flagged {sum(r['flagged'] for r in wrong)} of {len(wrong)}, the fix named "
          f"in {sum(r['named'] for r in wrong)}")
    print(f"mistakes whose keypoint fit lies over {WRONG_M * 1e3:.0f} mm off: {len(misled)}; "
          f"flagged {sum(r['flagged'] for r in misled)}; called good without the check "
          f"{sum(r['good_before'] for r in misled)}, with it "
          f"{sum(r['good_before'] and not r['flagged'] for r in misled)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", default="panda")
    parser.add_argument("--scenes", type=int, default=12)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--first-seed", type=int, default=7000)
    parser.add_argument("--labels", action="store_true",
                        help="keypoints from the labels plus noise, not the bundled model")
    parser.add_argument("--label-noise-px", type=float, default=2.0)
    parser.add_argument("--work", type=Path, help="keep the renders here (default: temporary)")
    for name in ("min_unexplained", "min_gain", "min_resolved"):
        parser.add_argument(f"--{name.replace('_', '-')}", type=float,
                            default=getattr(ReadingsCheckSettings, name))
    args = parser.parse_args()
    render = _coarse_start().render_scene
    model = None if args.labels else dream.load_keypoint_model(dream.BUNDLED_MODEL)
    settings = ReadingsCheckSettings(min_unexplained=args.min_unexplained,
                                     min_gain=args.min_gain, min_resolved=args.min_resolved)
    print(f"readings check: explained within {settings.explained_width:.4g} of the width, "
          f"questioned beyond "
          f"{settings.min_unexplained:g} unexplained, min gain {settings.min_gain:g}, min "
          f"resolved {settings.min_resolved:g}; keypoints from "
          f"{f'labels + {args.label_noise_px:g} px' if args.labels else 'the bundled model'}")
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        rows: list[dict] = []
        for robot in args.robots.split(","):
            for k in range(args.scenes):
                start = time.perf_counter()
                name = "scene" if robot == "panda" else f"{robot}_scene"
                data = render(robot, work / f"{name}{k}", args.first_seed + k, args.frames,
                              reuse=True)
                got = scene_rows(data, model, args.label_noise_px, args.first_seed + k,
                                 settings)
                rows += got
                print(f"{robot} scene {k} ({time.perf_counter() - start:.0f} s): "
                      + "; ".join(_line(r) for r in got), flush=True)
    summary(rows)


if __name__ == "__main__":
    main()
