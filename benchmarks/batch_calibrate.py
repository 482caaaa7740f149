"""`dream batch calibrate` on many small recordings: identical results to single `dream
calibrate` runs on both engines, the broken recordings named, a kill -9 resumed, and the
throughput of 2 workers against 1.

    MUJOCO_GL=egl python benchmarks/batch_calibrate.py --work /tmp/batch_bench

The recordings are fixed-camera `real_world.yaml` renders of panda, ur5 and xarm7 (10 frames,
320x240, robot masks kept, no close-ups), their keypoint labels moved by `--label-noise-px` so
that the calibration (`--use-labels`, the silhouette polish against the masks) has work to do.
Three are broken on purpose: an image deleted (from a recording rewritten as images +
joints.csv), the joints written in degrees, a frame JSON cut in half.
It prints the figures of docs/benchmarks.md; the Ray runs need the `cluster` extra.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
REAL_WORLD = REPO / "configs" / "synth" / "real_world.yaml"
ROBOTS = ("panda", "ur5", "xarm7")
OPTIONS = ("--use-labels",)
# recording index of each fault; the missing image in a panda recording turned into images +
# joints.csv (whose reader needs no --robot: panda is its default)
BROKEN = {"missing_image": 6, "degrees": 17, "truncated_json": 29}
FIRST_SEED = 7000
IDENTICAL_TOL = 1e-9
POLL_S = 0.5
ORPHAN_WAIT_S = 10.0


def make_recordings(root: Path, count: int, frames: int, noise_px: float,
                    broken: dict[str, int] | None = None) -> list[Path]:
    """`count` recordings under `root` (made once; reused when complete); `broken`: which
    recording gets which fault (default `BROKEN`)."""
    from synth.config import config_from_dict
    from synth.generate import SynthJob, generate

    config = yaml.safe_load(REAL_WORLD.read_text())
    config["sequence"] = {"mode": "fixed_camera"}
    config["camera"]["closeup_prob"] = 0.0    # every unbroken recording shows enough keypoints
    paths = []
    for i in range(count):
        path = root / f"rec{i:03d}"
        paths.append(path)
        if (path / "_made").exists():
            continue
        generate(SynthJob(robot=ROBOTS[i % len(ROBOTS)], out_dir=path, num_frames=frames,
                          config=config_from_dict(config), seed=FIRST_SEED + i),
                 overwrite=True)
        _move_labels(path, np.random.default_rng(FIRST_SEED + i), noise_px)
        _break(path, i, BROKEN if broken is None else broken)
        (path / "_made").write_text("")
    return paths


def _move_labels(path: Path, rng: np.random.Generator, noise_px: float) -> None:
    for frame in sorted(path.glob("[0-9]*.json")):
        doc = json.loads(frame.read_text())
        for kp in doc["objects"][0]["keypoints"]:
            if "projected_location" not in kp:    # a keypoint the renderer could not project
                continue
            kp["projected_location"] = list(np.asarray(kp["projected_location"])
                                            + rng.normal(0.0, noise_px, 2))
        frame.write_text(json.dumps(doc))


def _break(path: Path, index: int, broken: dict[str, int]) -> None:
    frames = sorted(path.glob("[0-9]*.json"))
    middle = frames[len(frames) // 2]
    if index == broken["missing_image"]:
        _as_images_and_csv(path)
        (path / "images" / f"{middle.name[:6]}.png").unlink()
    elif index == broken["degrees"]:
        for frame in frames:
            doc = json.loads(frame.read_text())
            for joint in doc["sim_state"]["joints"]:
                joint["position"] = float(np.rad2deg(joint["position"]))
            frame.write_text(json.dumps(doc))
    elif index == broken["truncated_json"]:
        text = middle.read_text()
        middle.write_text(text[:len(text) // 2])


def _as_images_and_csv(path: Path) -> None:
    """The recording rewritten as images + joints.csv + K.txt (docs/data_format.md), a layout
    whose joint log names each image: the DREAM layout allows frames without one."""
    camera = json.loads((path / "_camera_settings.json").read_text())["camera_settings"][0]
    k = camera["intrinsic_settings"]
    rows, names = [], None
    (path / "images").mkdir()
    for frame in sorted(path.glob("[0-9]*.json")):
        joints = json.loads(frame.read_text())["sim_state"]["joints"]
        names = [j["name"] for j in joints]
        image = f"{frame.name[:6]}.png"
        (path / f"{frame.name[:6]}.rgb.png").rename(path / "images" / image)
        rows.append(",".join([f"images/{image}", *(repr(j["position"]) for j in joints)]))
    for stale in path.glob("*.json"):
        stale.unlink()
    for stale in path.glob("*.seg.png"):
        stale.unlink()
    (path / "joints.csv").write_text("\n".join([",".join(["image", *names]), *rows]) + "\n")
    (path / "K.txt").write_text(f"{k['fx']} 0 {k['cx']}\n0 {k['fy']} {k['cy']}\n0 0 1\n")


def dream(*args: str) -> list[str]:
    return [str(Path(sys.executable).parent / "dream"), *args]


def single_runs(recordings: list[Path], out: Path) -> dict[str, dict]:
    """One `dream calibrate` per recording: {name: T_cam_base or the error line}."""
    results = {}
    for path in recordings:
        result = out / path.name / "RESULT.json"
        if not result.exists():
            result.parent.mkdir(parents=True, exist_ok=True)
            run = subprocess.run(dream("calibrate", "--data", str(path), "--out", str(result),
                                       *OPTIONS), capture_output=True, text=True)
            if run.returncode:
                (out / path.name / "error.txt").write_text(run.stderr.strip())
        if result.exists():
            results[path.name] = {"T": json.loads(result.read_text())["T_cam_base"]}
        else:
            results[path.name] = {"error": (out / path.name / "error.txt").read_text()}
    return results


def batch_command(data: str, out: Path, engine: str, workers: int) -> list[str]:
    return dream("batch", "calibrate", "--data", data, "--out", str(out), "--engine", engine,
                 "--workers", str(workers), *OPTIONS)


def run_batch(data: str, out: Path, engine: str, workers: int) -> tuple[float, str]:
    start = time.perf_counter()
    run = subprocess.run(batch_command(data, out, engine, workers), capture_output=True,
                         text=True)
    if run.returncode not in (0, 1):
        raise SystemExit(f"batch failed: {run.stderr}")
    return time.perf_counter() - start, run.stderr


def finished(out: Path) -> int:
    try:
        return json.loads((out / "summary.json").read_text())["recordings"]
    except (OSError, ValueError, KeyError):
        return 0


def kill_and_resume(data: str, out: Path, engine: str, total: int) -> dict:
    """kill -9 of the batch once half the recordings are done, then a re-run."""
    shutil.rmtree(out, ignore_errors=True)
    proc = subprocess.Popen(batch_command(data, out, engine, 2), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    while finished(out) < total // 2 and proc.poll() is None:
        time.sleep(POLL_S)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    at_kill = len([p for p in out.glob("rec*") if p.is_dir()])
    time.sleep(ORPHAN_WAIT_S)   # a local worker finishes the recording it ran
    _, stderr = run_batch(data, out, engine, 2)
    line = next(t for t in stderr.splitlines() if t.startswith("batch:"))
    return {"finished_at_kill": at_kill, "rerun": line}


def compare(out: Path, single: dict[str, dict]) -> dict:
    """The batch's rows against the single runs: largest difference of T_cam_base, and the
    failed rows with their errors."""
    rows = json.loads((out / "summary.json").read_text())["rows"]
    worst, failed, mismatched = 0.0, {}, []
    for row in rows:
        name = Path(row["recording"]).name
        if row["status"] == "ok":
            if "T" not in single[name]:
                mismatched.append(name)
                continue
            worst = max(worst, float(np.max(np.abs(np.asarray(row["T_cam_base"])
                                                    - np.asarray(single[name]["T"])))))
        else:
            failed[name] = row["error"]
            if "error" not in single[name]:
                mismatched.append(name)
    return {"ok": len(rows) - len(failed), "failed": failed, "max_abs_diff": worst,
            "mismatched": mismatched}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, required=True, help="scratch folder")
    parser.add_argument("--recordings", type=int, default=40, help="(default: %(default)s)")
    parser.add_argument("--frames", type=int, default=10, help="(default: %(default)s)")
    parser.add_argument("--label-noise-px", type=float, default=2.0,
                        help="(default: %(default)s)")
    parser.add_argument("--engines", default="ray,local", help="(default: %(default)s)")
    parser.add_argument("--skip-throughput", action="store_true")
    parser.add_argument("--only-throughput", action="store_true")
    args = parser.parse_args()
    recordings = make_recordings(args.work / "recordings", args.recordings, args.frames,
                                 args.label_noise_px)
    data = str(args.work / "recordings" / "rec*")
    engines = args.engines.split(",")
    if not args.only_throughput:
        start = time.perf_counter()
        single = single_runs(recordings, args.work / "single")
        print(f"single dream calibrate runs: {sum('T' in s for s in single.values())} "
              f"results, {sum('error' in s for s in single.values())} errors "
              f"({time.perf_counter() - start:.0f} s; made once, then reused)")
    for engine in [] if args.only_throughput else engines:
        out = args.work / f"batch_{engine}"
        resumed = kill_and_resume(data, out, engine, len(recordings))
        check = compare(out, single)
        print(f"{engine}: killed with {resumed['finished_at_kill']} of {len(recordings)} "
              f"finished; re-run: {resumed['rerun']}")
        print(f"{engine}: {check['ok']} results, largest |T_cam_base - single run| "
              f"{check['max_abs_diff']:.2e} (identical within {IDENTICAL_TOL:g}: "
              f"{check['max_abs_diff'] <= IDENTICAL_TOL}); mismatched {check['mismatched']}")
        for name, error in check["failed"].items():
            print(f"  {name}: {error}")
    if args.skip_throughput:
        return
    for engine in engines:
        seconds = {}
        for workers in (1, 2):
            out = args.work / f"throughput_{engine}_{workers}"
            shutil.rmtree(out, ignore_errors=True)
            seconds[workers], _ = run_batch(data, out, engine, workers)
        print(f"{engine}: 1 worker {seconds[1]:.1f} s, 2 workers {seconds[2]:.1f} s, "
              f"throughput x{seconds[1] / seconds[2]:.2f}")


if __name__ == "__main__":
    main()
