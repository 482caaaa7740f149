"""benchmarks/frame_subset.py: the frames of a rendered set that show a draw, and the same
frames of a set rendered without it."""

from __future__ import annotations

import json
from pathlib import Path

from dream.cli import main as dream_main
from tests.benchmark_scripts import load_benchmark

BENCH = load_benchmark("frame_subset")
FIXED = ["--set", "intrinsics.fx=300", "--set", "intrinsics.fy=300", "--set",
         "intrinsics.cx=159.5", "--set", "intrinsics.cy=119.5", "--set", "distractors.count=[0,0]"]


def _synth(out: Path, *extra: str) -> None:
    assert dream_main(["synth", "--robot", "panda", "--num", "8", "--seed", "4", "--out",
                       str(out), *FIXED, *extra]) == 0


def test_loose_part_frames_and_the_same_frames_without_them(tmp_path, capsys):
    loose, plain = tmp_path / "loose", tmp_path / "plain"
    _synth(loose, "--set", "distractors.loose_prob=0.5")
    _synth(plain)
    sub, sub_plain = tmp_path / "sub", tmp_path / "sub_plain"
    code = BENCH.main([str(loose), "--with", "loose_parts", "--out", str(sub),
                       "--same-frames-of", str(plain), str(sub_plain)])
    assert code == 0
    kept = BENCH.frame_indices(sub)
    assert 0 < len(kept) < 8 and BENCH.frame_indices(sub_plain) == kept
    assert json.loads((sub / "_synth.json").read_text())["seed"] == 4
    # nothing of the plain set shows loose parts; the rest of the draws are the same
    assert BENCH.frames_with(plain, "loose_parts") == []
    for i in kept:
        a = json.loads((sub / f"{i:06d}.json").read_text())
        b = json.loads((sub_plain / f"{i:06d}.json").read_text())
        uv = [[k["projected_location"] for k in doc["objects"][0]["keypoints"]] for doc in (a, b)]
        assert uv[0] == uv[1]
    assert f"{len(kept)} of 8 frames show loose_parts" in capsys.readouterr().out


def test_not_a_rendered_set_is_one_error_line(tmp_path, capsys):
    code = BENCH.main([str(tmp_path), "--with", "held", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and "_synth.json" in err and err.count("\n") == 1
    assert not (tmp_path / "x").exists()
