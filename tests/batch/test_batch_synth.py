"""`dream batch synth`: the frames of a one-process `dream synth` of the same seed, byte for
byte, on both engines, and a kill -9 resumed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dream.cli import main
from dream.io import is_temporary
from synth.config import load_config
from synth.generate import SynthJob, generate

SMALL = ["intrinsics.width=96", "intrinsics.height=72"]
SEED = 5
KILL_AFTER_FRAMES = 8
KILL_DEADLINE_S = 120
POLL_S = 0.05


def reference(out: Path, frames: int) -> Path:
    """A one-process `dream synth` of the same recipe and seed."""
    generate(SynthJob("panda", out, frames, load_config(None, SMALL), seed=SEED),
             on_progress=lambda n: None)
    return out


def same_files(a: Path, b: Path) -> None:
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def synth_args(out: Path, frames: int, engine: str) -> list[str]:
    return ["batch", "synth", "--robot", "panda", "--num", str(frames), "--out", str(out),
            "--seed", str(SEED), "--engine", engine, "--workers", "2",
            *[a for s in SMALL for a in ("--set", s)]]


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["local", "ray"])
def test_frames_are_those_of_one_process(tmp_path, engine, capsys):
    if engine == "ray":
        pytest.importorskip("ray")
    whole = reference(tmp_path / "whole", 20)
    out = tmp_path / engine
    assert main(synth_args(out, 20, engine)) == 0
    assert "20 frames rendered, 0 already there" in capsys.readouterr().out
    same_files(out, whole)


@pytest.mark.slow
def test_a_killed_batch_synth_resumes_to_the_same_frames(tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "killed"
    command = [str(Path(sys.executable).parent / "dream"), *synth_args(out, 40, "ray")]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + KILL_DEADLINE_S
    while (len(list(out.glob("[0-9]*.json"))) < KILL_AFTER_FRAMES and proc.poll() is None
           and time.monotonic() < deadline):
        time.sleep(POLL_S)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    time.sleep(1.0)
    before = len(list(out.glob("[0-9]*.json")))
    assert KILL_AFTER_FRAMES <= before < 40, before
    rerun = subprocess.run(command, capture_output=True, text=True, check=True)
    rendered = int(rerun.stdout.split(" frames rendered")[0].rsplit(" ", 1)[-1])
    assert rendered <= 40 - KILL_AFTER_FRAMES
    assert not [p for p in out.iterdir() if is_temporary(p)]
    same_files(out, reference(tmp_path / "whole", 40))
