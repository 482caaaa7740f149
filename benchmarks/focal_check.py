"""Does the keypoint path's focal check (`dream.focal_check`) catch a wrong focal length, and
does it stay quiet on a right one?

Renders fixed-camera `real_world.yaml` scenes of the Panda (clutter, a second robot, a held
object; seeds from `--first-seed`), detects their keypoints with the bundled model, and for
each scene calibrates all frames (keypoints only) through the rendered intrinsics and through
copies whose fx, fy are scaled (`--scales`: a depth stream's or a datasheet's focal length);
prints per scale the focal scale the keypoints ask for, its 1-sigma, how often the check flags
it, and the camera position's error against the truth.

    python benchmarks/focal_check.py [--scenes 10] [--frames 30] [--first-seed 7000]
        [--scales 1 1.05 1.1 0.92] [--work DIR]
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
import time
from pathlib import Path

import numpy as np

import dream
from dream.coarse.focal import with_focal_scale
from dream.errors import DreamError
from dream.focal_check import FocalCheckSettings, keypoint_focal, keypoint_focal_finding
from dream.metrics import pose_errors
from dream.pipeline import calibrate, truth_poses

HERE = Path(__file__).resolve().parent


def _coarse_start():
    spec = importlib.util.spec_from_file_location("coarse_start", HERE / "coarse_start.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def scene_rows(data: Path, scales: list[float], model) -> list[dict]:
    """One row per focal scale of one rendered scene."""
    seq = dream.read_sequence(data)
    robot = dream.load_robot(seq)
    obs = dream.detect(seq, robot, model)
    T_true = truth_poses(seq)[0]
    rows = []
    for scale in scales:
        given = seq.with_fixed_camera(with_focal_scale(seq.camera, scale))
        try:
            result = calibrate(given, obs, "all")
        except DreamError as exc:               # the detector saw too little of the arm
            print(f"{data.name} x{scale:g}: no calibration ({exc.problem})")
            continue
        focal = keypoint_focal(result, obs, given.camera)
        flagged = keypoint_focal_finding(focal, given.camera) is not None
        error_m, _ = pose_errors(result.T_cam_base, T_true)
        rows.append({"scale": scale, "asked": None if focal is None else focal.scale,
                     "sigma": None if focal is None else focal.sigma, "flagged": flagged,
                     "error_mm": float(error_m) * 1e3})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--first-seed", type=int, default=7000)
    parser.add_argument("--scales", type=float, nargs="+", default=[1.0, 1.05, 1.1, 0.92])
    parser.add_argument("--work", type=Path, help="keep the renders here (default: temporary)")
    args = parser.parse_args()
    render = _coarse_start().render_scene
    model = dream.load_keypoint_model(dream.BUNDLED_MODEL)
    settings = FocalCheckSettings()
    print(f"focal check: tolerance {settings.tolerance:g}, z {settings.z:g}")
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        rows: list[dict] = []
        for k in range(args.scenes):
            start = time.perf_counter()
            data = render("panda", work / f"scene{k}", args.first_seed + k, args.frames,
                          reuse=True)
            got = scene_rows(data, args.scales, model)
            rows += got
            print(f"scene {k} ({time.perf_counter() - start:.0f} s): " + "; ".join(
                f"x{r['scale']:g}: asks {r['asked'] or float('nan'):.3f} +-"
                f"{r['sigma'] or float('nan'):.3f}{' FLAGGED' if r['flagged'] else ''}, "
                f"{r['error_mm']:.0f} mm" for r in got), flush=True)
    for scale in args.scales:
        mine = [r for r in rows if r["scale"] == scale]
        asked = np.array([r["asked"] for r in mine if r["asked"] is not None])
        print(f"given x{scale:g}: flagged {sum(r['flagged'] for r in mine)} of {len(mine)}; "
              f"asks median {np.median(asked) if len(asked) else float('nan'):.3f} "
              f"(expected {1 / scale:.3f}); camera error median "
              f"{np.median([r['error_mm'] for r in mine]):.0f} mm")


if __name__ == "__main__":
    main()
