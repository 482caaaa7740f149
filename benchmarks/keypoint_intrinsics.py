"""Do the keypoint path's intrinsics checks (`dream.focal_check`, `dream.principal_check`)
catch a wrong focal length or principal point, and do they stay quiet on right ones?

Renders fixed-camera `real_world.yaml` scenes of the Panda (clutter, a second robot, a held
object; seeds from `--first-seed`), takes their keypoints from the bundled model (or, with
`--labels-noise PX`, the renderer's labels plus that much Gaussian noise: a detector as
accurate as an adapted one), and for each scene calibrates all frames (keypoints only)
through the rendered intrinsics and through copies whose fx, fy are scaled (`--scales`: a
depth stream's or a datasheet's focal length) or whose cx, cy are moved (`--shifts DU,DV`,
pixels: the image centre given for a calibrated camera's, a crop); prints per camera the
focal scale and the principal shift the keypoints ask for, how often each check flags, and the
camera's error against the truth.

With `--refined`, each scene is calibrated as a user does (`dream calibrate --model` with the
bundled model, the default `--refine auto`: the edge alignment, then the silhouettes'
cross-check, which checks the focal length and the principal point on the robot's outlines at
its optimum, and calibrates again through those they ask for), through the rendered camera and
each of `--scales` and `--shifts`; prints the verdict, whether each check flagged and what was
adopted, the error, and whether the truth lies inside the written 95 % ellipsoid;
with `--masks` the scenes keep their robot masks (written to their own `--work`), and the
default refinement is the silhouette polish against them, then the cross-check on them;
`--refined --refine none` does the same for the keypoint fit alone (`dream calibrate --refine
none`: its verdict and 1-sigma, with what the keypoints' own intrinsics checks leave open).

    python benchmarks/keypoint_intrinsics.py [--scenes 10] [--frames 30] [--first-seed 7000]
        [--scales 1.05 1.1 0.92] [--shifts 6,-4 12,-8 24,-16] [--labels-noise PX] [--work DIR]
    python benchmarks/keypoint_intrinsics.py --refined --scenes 12 --scales 1.05 --shifts 12,-8
    python benchmarks/keypoint_intrinsics.py --refined --refine none --scenes 12
    python benchmarks/keypoint_intrinsics.py --refined --masks --scenes 12 --scales 1.05
        --shifts 12,-8 --work DIR
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import dream
from dream.cli.calibrate import CalibrateRequest, run_calibrate
from dream.coarse.focal import with_focal_scale
from dream.coarse.principal import with_principal_shift
from dream.errors import DreamError
from dream.focal_check import FocalCheckSettings, keypoint_focal, keypoint_focal_finding
from dream.metrics import pose_errors
from dream.pipeline import calibrate, observations_from_labels, truth_poses
from dream.pnp import increment_between
from dream.principal_check import (
    PrincipalCheckSettings,
    keypoint_principal,
    keypoint_principal_finding,
)
from dream.quality import result_quality

HERE = Path(__file__).resolve().parent
AS_RENDERED = "as rendered"
CHI2_6DOF_95 = 12.592     # 95 % quantile of the chi-square distribution with 6 degrees of freedom
WRONG_MM, WRONG_DEG = 50.0, 5.0     # a `good` verdict beyond either is wrong


def _coarse_start():
    spec = importlib.util.spec_from_file_location("coarse_start", HERE / "coarse_start.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def given_cameras(camera, scales: list[float], shifts: list[tuple[float, float]]):
    """(name, the camera given) for the rendered one and each wrong focal length and principal
    point."""
    return ([(AS_RENDERED, camera)]
            + [(f"fx, fy x{s:g}", with_focal_scale(camera, s)) for s in scales]
            + [(f"cx, cy {du:+g}, {dv:+g} px", with_principal_shift(camera, (du, dv)))
               for du, dv in shifts])


def observations(seq, robot, model, labels_noise: float | None, seed: int):
    """The bundled model's detections, or the labels plus `labels_noise` px."""
    if labels_noise is None:
        return dream.detect(seq, robot, model)
    obs = observations_from_labels(seq, robot)
    noise = np.random.default_rng(seed).normal(0.0, labels_noise, obs.uv.shape)
    return replace(obs, uv=obs.uv + noise)


def scene_rows(data: Path, scales, shifts, model, labels_noise: float | None,
               seed: int) -> list[dict]:
    """One row per camera given of one rendered scene."""
    seq = dream.read_sequence(data)
    robot = dream.load_robot(seq)
    obs = observations(seq, robot, model, labels_noise, seed)
    T_true = truth_poses(seq)[0]
    rows = []
    for name, camera in given_cameras(seq.camera, scales, shifts):
        given = seq.with_fixed_camera(camera)
        try:
            result = calibrate(given, obs, "all")
        except DreamError as exc:               # the detector saw too little of the arm
            print(f"{data.name} {name}: no calibration ({exc.problem})")
            continue
        focal = keypoint_focal(result, obs, camera)
        principal = keypoint_principal(result, obs, camera)
        error_m, error_rad = pose_errors(result.T_cam_base, T_true)
        findings = (keypoint_focal_finding(focal, camera),
                    keypoint_principal_finding(principal, camera))
        rows.append({
            "verdict_before": result_quality(result, obs, extra=findings[:1]).verdict,
            "verdict": result_quality(result, obs, extra=findings).verdict,
            "given": name, "error_mm": float(error_m) * 1e3,
            "error_deg": float(np.rad2deg(error_rad)),
            "scale": None if focal is None else focal.scale,
            "focal_flagged": keypoint_focal_finding(focal, camera) is not None,
            "shift": None if principal is None else principal.shift_px,
            "sigma": None if principal is None else principal.sigma_px,
            "turn_deg": None if principal is None else float(np.rad2deg(principal.angle_rad)),
            "principal_flagged": keypoint_principal_finding(principal, camera) is not None})
    return rows


def refined_rows(data: Path, scales, shifts, model, work: Path, refine: str = "auto"
                 ) -> list[dict]:
    """One row per camera given of `dream calibrate --model --refine REFINE`."""
    seq = dream.read_sequence(data)
    T_true = truth_poses(seq)[0]
    rows = []
    for name, camera in given_cameras(seq.camera, scales, shifts):
        start = time.perf_counter()
        request = CalibrateRequest(
            data=str(data), out=str(work / f"{data.name}_{len(rows)}.json"),
            model=str(dream.BUNDLED_MODEL), loaded_model=model, override_intrinsics=True,
            refine=refine,
            intrinsics=f"{camera.fx!r},{camera.fy!r},{camera.cx!r},{camera.cy!r}")
        try:
            with contextlib.redirect_stdout(io.StringIO()), \
                    contextlib.redirect_stderr(io.StringIO()):
                doc = run_calibrate(request)
        except DreamError as exc:               # the detector saw too little of the arm
            print(f"{data.name} {name}: no calibration ({exc.problem})")
            continue
        T = np.asarray(doc["T_cam_base"])
        error_m, error_rad = pose_errors(T, T_true)
        xi = increment_between(T, T_true)
        chi2 = float(xi @ np.linalg.pinv(np.asarray(doc["covariance_xi"])) @ xi)
        outlines = (doc.get("silhouette_check") or {}).get("principal")
        focal = (doc.get("silhouette_check") or {}).get("focal")
        lens = (doc.get("silhouette_check") or {}).get("distortion")
        rows.append({
            "given": name, "verdict": doc["quality"]["verdict"],
            "error_mm": float(error_m) * 1e3, "error_deg": float(np.rad2deg(error_rad)),
            "chi2": chi2, "inside": chi2 <= CHI2_6DOF_95,
            "keypoints_flagged": not (doc.get("keypoint_principal") or {}).get("agrees", True),
            "keypoints_unresolved": [name for name in ("focal", "principal") if (
                doc.get(f"keypoint_{name}") or {}).get("unresolved")],
            "outlines_flagged": bool(outlines and outlines["flagged"]),
            "outlines": outlines, "focal": focal, "distortion": lens,
            "focal_asked": bool(focal and focal["asked"]),
            "adopted": (doc.get("focal") or {}).get("scale"),
            "shift_adopted": (doc.get("principal") or {}).get("shift_px"),
            "seconds": time.perf_counter() - start})
    return rows


def _wrong_good(row: dict) -> bool:
    return row["verdict"] == "good" and (row["error_mm"] > WRONG_MM
                                         or row["error_deg"] > WRONG_DEG)


def _refined_text(r: dict) -> str:
    o = r["outlines"]
    asked = ("outlines: no check" if o is None else
             "outlines ask {:+.1f}, {:+.1f} px ({:.2f} deg{})".format(
                 *o["shift_px"], np.rad2deg(o["angle_rad"]),
                 ", FLAGGED" if o["flagged"] else ""))
    f = r["focal"]
    focal = ("" if f is None else
             f"; outlines ask x{f['scale']:.3f}{' (ASKED)' if f['asked'] else ''}")
    d = r["distortion"]
    focal += ("" if d is None else f", a radial shift of {100 * d['corner_shift']:+.1f} % at "
              f"the corner{' (ASKED)' if d['asked'] else ''}")
    again = ([f"x{r['adopted']:.3f}"] if r["adopted"] is not None else []) + (
        ["{:+.1f}, {:+.1f} px".format(*r["shift_adopted"])] if r["shift_adopted"] else [])
    if again:
        asked = f"calibrated again at {' and '.join(again)}; there {asked}"
    return (f"{r['given']}: {r['verdict']}, {r['error_mm']:.1f} mm, {r['error_deg']:.2f} deg, "
            f"chi2 {r['chi2']:.1f}; {asked}{focal}; keypoints "
            f"{'FLAGGED' if r['keypoints_flagged'] else 'agree'}"
            + "".join(f", {name} unresolved" for name in r["keypoints_unresolved"])
            + f"; {r['seconds']:.0f} s")


def refined_summary(rows: list[dict], name: str) -> str:
    mine = [r for r in rows if r["given"] == name]
    verdicts = ", ".join(f"{level} {sum(r['verdict'] == level for r in mine)}"
                         for level in ("good", "check", "unreliable"))
    return (f"{name}: {verdicts} of {len(mine)}; outlines flagged the principal point "
            f"{sum(r['outlines_flagged'] for r in mine)}, asked for a focal length "
            f"{sum(r['focal_asked'] for r in mine)}; adopted a focal length "
            f"{sum(r['adopted'] is not None for r in mine)}, a principal point "
            f"{sum(r['shift_adopted'] is not None for r in mine)}; keypoints flagged "
            f"{sum(r['keypoints_flagged'] for r in mine)}, left unresolved "
            f"{sum(bool(r['keypoints_unresolved']) for r in mine)}; wrong `good` (beyond "
            f"{WRONG_MM:g} mm or {WRONG_DEG:g} deg) {sum(_wrong_good(r) for r in mine)}"
            f"; inside {sum(r['inside'] for r in mine)}"
            f"; error median {np.median([r['error_mm'] for r in mine]):.1f} mm, "
            f"{np.median([r['error_deg'] for r in mine]):.2f} deg (max "
            f"{np.max([r['error_deg'] for r in mine]):.2f} deg); "
            f"{np.min([r['seconds'] for r in mine]):.0f}-{np.max([r['seconds'] for r in mine]):.0f}"
            " s")


def _row_text(r: dict) -> str:
    flags = "".join(f" {w} FLAGGED" for w in ("focal", "principal") if r[f"{w}_flagged"])
    shift = ("no principal fit" if r["shift"] is None else
             f"shift {r['shift'][0]:+.1f}, {r['shift'][1]:+.1f} (+-{r['sigma'][0]:.1f}, "
             f"{r['sigma'][1]:.1f}) px, {r['turn_deg']:.2f} deg")
    scale = "no focal fit" if r["scale"] is None else f"scale {r['scale']:.3f}"
    return (f"{r['given']}: {scale}, {shift}{flags}; {r['error_mm']:.1f} mm, "
            f"{r['error_deg']:.2f} deg, {r['verdict_before']} -> {r['verdict']}")


def summary(rows: list[dict], name: str) -> str:
    """One line per camera given: flags, the asked values' medians, the errors' medians."""
    mine = [r for r in rows if r["given"] == name]
    if not mine:
        return f"{name}: no calibration"
    scales = [r["scale"] for r in mine if r["scale"] is not None]
    turns = [r["turn_deg"] for r in mine if r["turn_deg"] is not None]
    shifts = np.array([r["shift"] for r in mine if r["shift"] is not None]).reshape(-1, 2)
    verdicts = "; ".join(
        f"{when} " + ", ".join(f"{level} {sum(r[key] == level for r in mine)}"
                               for level in ("good", "check", "unreliable"))
        for when, key in (("without the principal check", "verdict_before"),
                          ("with it", "verdict")))
    return (f"{name}: focal flagged {sum(r['focal_flagged'] for r in mine)}, principal "
            f"flagged {sum(r['principal_flagged'] for r in mine)} of {len(mine)}; asks "
            f"scale {np.median(scales):.3f}, shift {np.median(shifts[:, 0]):+.1f}, "
            f"{np.median(shifts[:, 1]):+.1f} px (median), turn {np.median(turns):.2f} "
            f"(max {np.max(turns):.2f}) deg; camera error median "
            f"{np.median([r['error_mm'] for r in mine]):.1f} mm, "
            f"{np.median([r['error_deg'] for r in mine]):.2f} deg; {verdicts}")


def _pair(text: str) -> tuple[float, float]:
    du, dv = (float(v) for v in text.split(","))
    return du, dv


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--first-seed", type=int, default=7000)
    parser.add_argument("--scales", type=float, nargs="*", default=[1.05, 1.1, 0.92])
    parser.add_argument("--shifts", type=_pair, nargs="*",
                        default=[(6.0, -4.0), (12.0, -8.0), (24.0, -16.0)])
    parser.add_argument("--labels-noise", type=float,
                        help="the labels plus this much noise (px) instead of the model")
    parser.add_argument("--refined", action="store_true",
                        help="calibrate as `dream calibrate --model` does (module doc)")
    parser.add_argument("--masks", action="store_true",
                        help="keep the scenes' robot masks (with --refined: the default "
                             "refinement is then the silhouette polish against them)")
    parser.add_argument("--refine", choices=("auto", "none"), default="auto",
                        help="with --refined: `dream calibrate --refine` (none: the keypoint "
                             "fit alone, its verdict and 1-sigma)")
    parser.add_argument("--work", type=Path, help="keep the renders here (default: temporary)")
    args = parser.parse_args()
    render = _coarse_start().render_scene
    model = (dream.load_keypoint_model(dream.BUNDLED_MODEL) if args.labels_noise is None
             else None)
    focal, principal = FocalCheckSettings(), PrincipalCheckSettings()
    print(f"focal check: tolerance {focal.tolerance:g}, z {focal.z:g}; principal check: "
          f"turn above {np.rad2deg(principal.min_angle_rad):g} deg, z {principal.z:g}")
    if args.refined:
        def rows_of(data: Path, k: int, work: Path) -> list[dict]:
            (work / "results").mkdir(exist_ok=True)
            return refined_rows(data, args.scales, args.shifts, model, work / "results",
                                args.refine)

        run_scenes(args, render, rows_of, _refined_text, refined_summary)
    else:
        def rows_of(data: Path, k: int, work: Path) -> list[dict]:
            return scene_rows(data, args.scales, args.shifts, model, args.labels_noise,
                              args.first_seed + k)

        run_scenes(args, render, rows_of, _row_text, summary)


def run_scenes(args, render, rows_of, text_of, summary_of) -> None:
    """Render (or reuse) each scene, print its rows as they come, then one summary line per
    camera given."""
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        rows: list[dict] = []
        for k in range(args.scenes):
            start = time.perf_counter()
            data = render("panda", work / f"scene{k}", args.first_seed + k, args.frames,
                          reuse=True, keep_masks=args.masks)
            got = rows_of(data, k, work)
            rows += got
            print(f"scene {k} ({time.perf_counter() - start:.0f} s):", flush=True)
            for r in got:
                print("    " + text_of(r), flush=True)
    for name in dict.fromkeys(r["given"] for r in rows):
        print(summary_of(rows, name))


if __name__ == "__main__":
    main()
