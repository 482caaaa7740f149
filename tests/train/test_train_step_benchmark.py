"""benchmarks/train_step.py: the training-step timer runs a recipe and its variants."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.benchmark_scripts import load_benchmark

torch = pytest.importorskip("torch")

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "configs" / "train" / "tiny.yaml"
BENCH = load_benchmark("train_step")


def test_forward_macs_counts_the_convolutions():
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3, padding=1), torch.nn.ReLU(),
                              torch.nn.Conv2d(4, 2, 1))
    assert BENCH.forward_macs(net, 5, 6) == 5 * 6 * (4 * 3 * 9 + 2 * 4)


def test_the_recipe_and_its_variants_are_timed(capsys):
    code = BENCH.main(["--config", str(TINY), "--variant", "model.skip=add",
                       "--steps", "1", "--warmup", "0"])
    out = capsys.readouterr().out
    assert code == 0
    rows = [line.split() for line in out.splitlines()[2:]]
    assert [r[0] for r in rows] == ["recipe", "model.skip=add"]
    assert all(float(r[-1]) > 0 and float(r[-2]) > 0 for r in rows)


def test_a_bad_override_is_one_error_line(capsys):
    assert BENCH.main(["--config", str(TINY), "--variant", "model.skp=add"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "model.skp" in err
