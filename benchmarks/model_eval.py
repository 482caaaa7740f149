"""Figures of a keypoint model end to end: synthetic held-out set, rendered fixed-camera scenes,
and the two real Panda sets. Everything goes through `dream calibrate` / `dream eval` (the
onnxruntime path a user runs); nothing here is tuned on the real images.

    python benchmarks/model_eval.py --model dream/models/panda_cpu.onnx
        [--heldout DATA/panda_heldout] [--scenes 5] [--realdata ../shared/realdata]
        [--out WORK_DIR] [--skip-polish] [--held-object] [--scene-masks data|network]
        [--first-seed 100] [--only PART]

Prints:
1. synthetic held-out DR set (`--heldout`, random cameras): single-frame ADD AUC (0-0.1 m,
   DREAM's definition), keypoint PCK AUC, median ADD; then the same after `--polish` (each
   frame's pose aligned with the set's own masks, `*.seg.png`), unless `--skip-polish`;
2. `--scenes` rendered fixed-camera scenes (`synth.demo` recipe, seeds 100..): all-frames
   extrinsic error (camera position, rotation) per scene and their median, then the same
   after `--polish` with each scene's own masks (`*.seg.png`; with `--scene-masks network`
   the scene folders' masks are deleted and `--polish --mask-head` uses the network's), unless
   `--skip-polish`; with `--held-object` the arm holds an object in every scene
   (`distractors.held_prob` 1); `--first-seed` moves the seeds;
3. panda_teleop: single-frame ADD AUC against its reference extrinsic (keypoints only and with
   the edge alignment of each frame), and the all-frames
   extrinsic error with the edge alignment (the default), and with `--polish --mask-head`
   and `--polish --motion-masks` (no masks in the data: the network's mask head, or motion
   masks, both opt-in);
4. franka_offline: silhouette IoU with the hand-made masks before and after `--polish`, and the
   spread of the extrinsic over the 45 leave-two-frames-out subsets.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import itertools
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dream.cli import main as dream
from dream.io import read_sequence
from dream.io.dream_layout import write_dream
from dream.metrics import pose_errors

REPO = Path(__file__).resolve().parents[1]


def run(args: list[str]) -> str:
    """`dream ARGS`; its stdout (raises on failure)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = dream([str(a) for a in args])
    if code != 0:
        raise SystemExit(f"dream {' '.join(map(str, args))} failed ({code}):\n{buf.getvalue()}")
    return buf.getvalue()


def calibrate(data: Path, model: Path, out: Path, *extra: str) -> dict:
    run(["calibrate", "--data", data, "--model", model, "--out", out, *extra])
    return json.loads(out.read_text())


def evaluate(data: Path, result: Path, out: Path) -> dict:
    run(["eval", "--data", data, "--result", result, "--out", out])
    return json.loads(out.read_text())


def heldout(model: Path, data: Path, work: Path, polish: bool) -> None:
    result = work / "heldout_each.json"
    calibrate(data, model, result, "--frames", "each", "--refine", "none")
    m = evaluate(data, result, work / "heldout_each.metrics.json")
    print(f"1. synthetic held-out set {data} ({m['frames']} frames, random cameras), single "
          f"frame: ADD AUC {100 * m['add_auc']:.1f} (target >= 92), median ADD "
          f"{1000 * m['add_m']['median']:.1f} mm, PCK AUC {100 * m['pck_auc']:.1f}, keypoint "
          f"L2 median {m['keypoint_l2_px']['median']:.2f} px, frames in the AUC "
          f"{m['frames_in_add_auc']}", flush=True)
    if not polish:
        return
    polished = work / "heldout_each_polish.json"
    start = time.perf_counter()
    p = calibrate(data, model, polished, "--frames", "each", "--polish")["polish"]
    seconds = time.perf_counter() - start
    m = evaluate(data, polished, work / "heldout_each_polish.metrics.json")
    print(f"   with --polish (the set's masks): ADD AUC {100 * m['add_auc']:.1f}, median ADD "
          f"{1000 * m['add_m']['median']:.1f} mm; polish kept in {p['frames_kept']} of "
          f"{p['frames_polished']} frames, mean IoU {p['iou_before']:.3f} -> {p['iou_kept']:.3f}; "
          f"{seconds:.0f} s for calibrate --polish", flush=True)


def scenes(model: Path, count: int, work: Path, held_object: bool, polish: bool,
           mask_head: bool, first_seed: int) -> None:
    from synth.demo import render_demo_scene

    errors = {"keypoints": [], "polish": []}
    masks = "the network's mask head" if mask_head else "the scene's masks"
    kept = 0
    for k in range(count):
        seed = first_seed + k
        data = render_demo_scene(work / f"scene_{seed}", seed=seed, held_object=held_object)
        T_true = read_sequence(data).frames[0].T_cam_base_true
        if polish and mask_head:        # the scene without its masks: the network's instead
            for mask in data.glob("*.seg.png"):
                mask.unlink()
        # one `dream calibrate` per scene: with --polish, RESULT.json's `polish` object keeps
        # the keypoint extrinsic (T_cam_base_keypoints) beside the polished one
        doc = calibrate(data, model, work / f"scene_{seed}.json",
                        *(["--polish"] if polish else ["--refine", "none"]),
                        *(["--mask-head"] if polish and mask_head else []))
        T_keypoints = doc["polish"]["T_cam_base_keypoints"] if polish else doc["T_cam_base"]
        t_err, r_err = pose_errors(np.asarray(T_keypoints), T_true)
        errors["keypoints"].append((float(t_err), float(r_err)))
        line = (f"   scene seed {seed}: {doc['frames_used']} frames, {doc['keypoints_used']} "
                f"keypoints, camera position error {1000 * t_err:.1f} mm, rotation "
                f"{np.rad2deg(r_err):.2f} deg")
        if polish:
            t_err, r_err = pose_errors(np.asarray(doc["T_cam_base"]), T_true)
            errors["polish"].append((float(t_err), float(r_err)))
            kept += bool(doc["polish"]["kept"])
            line += (f"; --polish ({masks}): {1000 * t_err:.1f} mm, "
                     f"{np.rad2deg(r_err):.3f} deg, IoU {doc['polish']['iou_before']:.3f} -> "
                     f"{doc['polish']['iou_after']:.3f}, "
                     f"{'kept' if doc['polish']['kept'] else 'not kept'}")
        print(line, flush=True)
    held = ", the arm holding an object" if held_object else ""
    t, r = np.array(errors["keypoints"]).T
    summary = (f"2. {count} rendered fixed-camera scenes (seeds {first_seed}-"
               f"{first_seed + count - 1}, 30 frames each{held}), all frames: "
               f"median camera position error {1000 * np.median(t):.1f} mm, rotation "
               f"{np.rad2deg(np.median(r)):.2f} deg")
    if polish:
        tp, rp = np.array(errors["polish"]).T
        summary += (f"; with --polish ({masks}): median "
                    f"{1000 * np.median(tp):.2f} mm (max {1000 * tp.max():.2f}), rotation "
                    f"{np.rad2deg(np.median(rp)):.3f} deg; polish kept in {kept} of {count}; "
                    f"camera position better than the keypoint extrinsic's in "
                    f"{int(np.sum(tp < t))}, worse in "
                    f"{int(np.sum(tp > t))}")
    print(summary, flush=True)


def panda_teleop(model: Path, data: Path, work: Path, polish: bool) -> None:
    each = work / "teleop_each.json"
    calibrate(data, model, each, "--frames", "each")      # with the edge alignment (auto)
    m_each = evaluate(data, each, work / "teleop_each.metrics.json")
    plain = work / "teleop_each_keypoints.json"
    calibrate(data, model, plain, "--frames", "each", "--refine", "none")
    m_plain = evaluate(data, plain, work / "teleop_each_keypoints.metrics.json")
    allf = work / "teleop_all.json"
    doc = calibrate(data, model, allf, "--overlays", work / "teleop_overlays")
    m_all = evaluate(data, allf, work / "teleop_all.metrics.json")
    polish_line = ""
    if polish:
        for source in ("--mask-head", "--motion-masks"):
            polished = work / f"teleop_all_polish{source.replace('--', '_')}.json"
            pdoc = calibrate(data, model, polished, "--polish", source)
            m_pol = evaluate(data, polished, polished.with_suffix(".metrics.json"))
            p = pdoc.get("polish", {})
            polish_line += (f"; --polish {source}: IoU {p.get('iou_before', float('nan')):.3f}"
                            f" -> {p.get('iou_after', float('nan')):.3f} ({p.get('reason')}), "
                            f"camera position error "
                            f"{1000 * m_pol['translation_error_m']['median']:.1f} mm, rotation "
                            f"{np.rad2deg(m_pol['rotation_error_rad']['median']):.2f} deg")
    print(f"3. panda_teleop ({m_each['frames']} frames): single-frame ADD AUC, keypoints "
          f"only {100 * m_plain['add_auc']:.1f}, median ADD "
          f"{1000 * m_plain['add_m']['median']:.1f} mm; with the edge alignment "
          f"{100 * m_each['add_auc']:.1f} (target >= 80), median ADD "
          f"{1000 * m_each['add_m']['median']:.1f} mm; keypoint L2 median "
          f"{m_each['keypoint_l2_px']['median']:.2f} px; all frames: camera position error "
          f"{1000 * m_all['translation_error_m']['median']:.1f} mm, rotation "
          f"{np.rad2deg(m_all['rotation_error_rad']['median']):.2f} deg (target <= 10 mm, "
          f"0.5 deg), {doc['keypoints_used']} keypoints in {doc['frames_used']} frames, RMSE "
          f"{doc['rmse_px']:.2f} px; overlays in {work / 'teleop_overlays'}{polish_line}",
          flush=True)


def franka_offline(model: Path, data: Path, work: Path, polish: bool) -> None:
    full = work / "franka_all.json"
    doc = calibrate(data, model, full, *(["--polish"] if polish else ["--refine", "none"]),
                    "--overlays", work / "franka_overlays")
    if polish and "polish" in doc:
        p = doc["polish"]
        every = np.mean(p["iou_after_per_frame"])
        left = ", ".join(f"{f['frame']} ({f['reason']})" for f in p["frames_left_out"])
        print(f"4. franka_offline: silhouette IoU {p['iou_before']:.3f} -> {p['iou_after']:.3f}"
              f" ({p['reason']}); over all {len(p['frames'])} frames {every:.3f}; frames left "
              f"out: {left or 'none'}; keypoint fit {doc['keypoints_used']} keypoints, RMSE "
              f"{doc['rmse_px']:.2f} px", flush=True)
    seq = read_sequence(data)
    T_ref = np.asarray(doc["T_cam_base"])
    positions, angles, failures = [], [], 0
    for drop in itertools.combinations(range(len(seq)), 2):
        sub = dataclasses.replace(seq, frames=tuple(f for i, f in enumerate(seq.frames)
                                                    if i not in drop))
        folder = work / "l2o" / f"{drop[0]}_{drop[1]}"
        write_dream(sub, folder, overwrite=True)
        try:
            d = calibrate(folder, model, folder / "r.json",
                          *(["--polish"] if polish else ["--refine", "none"]))
        except SystemExit:
            failures += 1
            continue
        t, r = pose_errors(np.asarray(d["T_cam_base"]), T_ref)
        positions.append(float(t))
        angles.append(float(r))
        shutil.rmtree(folder)
    positions, angles = np.array(positions), np.array(angles)
    print(f"   leave-two-frames-out{' with --polish' if polish else ''} ({len(positions)} of 45 "
          "subsets solved): camera position "
          f"differs from the all-frames solution by median {1000 * np.median(positions):.1f} mm"
          f" (max {1000 * positions.max():.1f}), rotation median "
          f"{np.rad2deg(np.median(angles)):.2f} deg (max {np.rad2deg(angles.max()):.2f})",
          flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=REPO / "dream" / "models" / "panda_cpu.onnx")
    parser.add_argument("--heldout", type=Path)
    parser.add_argument("--scenes", type=int, default=5)
    parser.add_argument("--realdata", type=Path, default=REPO.parent / "shared" / "realdata")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--skip-polish", action="store_true")
    parser.add_argument("--held-object", action="store_true",
                        help="the rendered scenes show the arm holding an object (a plate or a "
                             "primitive at the hand, as a board held during calibration)")
    parser.add_argument("--scene-masks", choices=("data", "network"), default="data",
                        help="the masks of the scenes' polish: their own (*.seg.png) or the "
                             "network's mask head (--mask-head)")
    parser.add_argument("--first-seed", type=int, default=100, help="seed of the first scene")
    parser.add_argument("--only", choices=("heldout", "scenes", "teleop", "franka"))
    args = parser.parse_args()
    if args.scene_masks == "network" and args.skip_polish:
        parser.error("--scene-masks network chooses the masks of the scenes' polish; drop "
                     "--skip-polish")
    work = args.out or Path(tempfile.mkdtemp(prefix="dream-model-eval-"))
    work.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    if args.heldout and args.only in (None, "heldout"):
        heldout(args.model, args.heldout, work, not args.skip_polish)
    if args.scenes and args.only in (None, "scenes"):
        scenes(args.model, args.scenes, work, args.held_object, not args.skip_polish,
               args.scene_masks == "network", args.first_seed)
    if (args.realdata / "panda_teleop").exists() and args.only in (None, "teleop"):
        panda_teleop(args.model, args.realdata / "panda_teleop", work, not args.skip_polish)
    if (args.realdata / "franka_offline").exists() and args.only in (None, "franka"):
        franka_offline(args.model, args.realdata / "franka_offline", work, not args.skip_polish)
    print(f"({time.perf_counter() - started:.0f} s; outputs in {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
