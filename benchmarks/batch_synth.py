"""`dream batch synth` with Ray on 2 workers against a one-process `dream synth` of the same
seed: byte-identical frames, a kill -9 halfway resumed, and the rates.

    MUJOCO_GL=egl python benchmarks/batch_synth.py --work /tmp/batch_synth --num 2000

Needs the `cluster` extra (Ray). Prints the figures of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

SEED = 11
POLL_S = 0.2


def dream(*args: str) -> list[str]:
    return [str(Path(sys.executable).parent / "dream"), *args]


def synth(out: Path, num: int, workers: int) -> list[str]:
    return dream("synth", "--robot", "panda", "--num", str(num), "--out", str(out),
                 "--seed", str(SEED), "--workers", str(workers))


def batch_synth(out: Path, num: int, engine: str, workers: int) -> list[str]:
    return dream("batch", "synth", "--robot", "panda", "--num", str(num), "--out", str(out),
                 "--seed", str(SEED), "--engine", engine, "--workers", str(workers))


def timed(command: list[str]) -> tuple[float, str]:
    start = time.perf_counter()
    run = subprocess.run(command, capture_output=True, text=True)
    if run.returncode:
        raise SystemExit(f"{' '.join(command)} failed: {run.stderr}")
    return time.perf_counter() - start, run.stdout


def frames(out: Path) -> int:
    return len(list(out.glob("[0-9]*.json")))


def differing(a: Path, b: Path) -> list[str]:
    names = sorted(p.name for p in a.iterdir())
    if names != sorted(p.name for p in b.iterdir()):
        return ["(the file lists differ)"]
    return [n for n in names if (a / n).read_bytes() != (b / n).read_bytes()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, required=True, help="scratch folder")
    parser.add_argument("--num", type=int, default=2000, help="frames (default: %(default)s)")
    args = parser.parse_args()
    one, batch = args.work / "synth_one_process", args.work / "batch_ray"
    for folder in (one, batch):
        shutil.rmtree(folder, ignore_errors=True)
    seconds_one, _ = timed(synth(one, args.num, 1))
    print(f"dream synth, 1 process: {args.num} frames in {seconds_one:.1f} s "
          f"({args.num / seconds_one:.1f} frames/s)")
    proc = subprocess.Popen(batch_synth(batch, args.num, "ray", 2), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    start = time.perf_counter()
    while frames(batch) < args.num // 2 and proc.poll() is None:
        time.sleep(POLL_S)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    first = time.perf_counter() - start
    time.sleep(1.0)
    at_kill = frames(batch)
    seconds_rest, stdout = timed(batch_synth(batch, args.num, "ray", 2))
    print(f"dream batch synth --engine ray --workers 2: killed (kill -9) after {first:.1f} s "
          f"with {at_kill} frames; the re-run said: {stdout.strip().splitlines()[0]} "
          f"({seconds_rest:.1f} s)")
    bad = differing(batch, one)
    print(f"files differing from the one-process run: {len(bad)} {bad[:5]}")
    shutil.rmtree(batch)
    seconds_two, _ = timed(batch_synth(batch, args.num, "ray", 2))
    print(f"dream batch synth --engine ray --workers 2, uninterrupted: {seconds_two:.1f} s "
          f"({args.num / seconds_two:.1f} frames/s, x{seconds_one / seconds_two:.2f} one "
          f"process); files differing: {len(differing(batch, one))}")


if __name__ == "__main__":
    main()
