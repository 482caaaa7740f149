"""Machine-dependent training settings: `trainer.precision: auto` and the time budget."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("lightning")
pytest.importorskip("albumentations")

from dream.errors import InputError  # noqa: E402
from tests.trainkit import make_drawn_dataset  # noqa: E402
from train import budget  # noqa: E402
from train.checkpoint import checkpoint_config  # noqa: E402
from train.config import load_config  # noqa: E402
from train.run import run_training  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "configs" / "train" / "tiny.yaml"


@pytest.fixture(scope="module")
def drawn(tmp_path_factory) -> Path:
    return make_drawn_dataset(tmp_path_factory.mktemp("drawn") / "data", 32)


@pytest.mark.parametrize(("device", "native", "expected"), [
    ("cpu", True, "bf16-mixed"), ("cpu", False, "32-true"), ("cuda", True, "bf16-mixed"),
    ("cuda", False, "32-true"), ("other", True, "32-true")])
def test_auto_precision_takes_bfloat16_only_where_it_is_native(device, native, expected):
    assert budget.choose_precision(device, native) == expected


def test_the_budget_buys_whole_epochs_within_the_caps():
    assert budget.epochs_for_budget(2700, 300, 30, 1000) == 8        # floor(2700 / 330)
    assert budget.epochs_for_budget(2700, 270, 0, 1000) == 10
    assert budget.epochs_for_budget(60, 300, 30, 1000) == 1          # at least one
    assert budget.epochs_for_budget(2700, 30, 0, 20) == 20           # max_epochs
    with pytest.raises(ValueError, match="budget_s > 0"):
        budget.epochs_for_budget(0, 300, 30, 10)


def test_time_budget_becomes_a_step_budget():
    config = load_config(TINY, ["trainer.time_budget_minutes=1",
                                "trainer.max_epochs=1000", "model.num_keypoints=4"])
    speed = budget.Speed(train_images_per_s=100.0, val_images_per_s=200.0)
    # 1000 images of batch 8: 125 steps and 10 s an epoch, 100 validation images 0.5 s.
    resolved = budget.resolve_time_budget(config, speed, 1000, 100)
    assert resolved.trainer.max_steps == 5 * 125              # floor(60 / 10.5)
    capped = config.replace(trainer=replace(config.trainer, max_steps=300))
    assert budget.resolve_time_budget(capped, speed, 1000, 100).trainer.max_steps == 3 * 125


@pytest.mark.parametrize("override", ["trainer.time_budget_minutes=0",
                                      "trainer.budget_probe_steps=0"])
def test_bad_budget_settings_are_refused(override):
    with pytest.raises(InputError, match=override.split("=")[0].replace(".", r"\.")):
        load_config(TINY, [override])


def test_a_budgeted_auto_run_resolves_records_and_resumes_without_probing(drawn, tmp_path,
                                                                          monkeypatch):
    overrides = [f"data.train=[{drawn}]", "trainer.precision=auto",
                 "trainer.time_budget_minutes=0.05", "trainer.max_epochs=200",
                 "trainer.budget_probe_steps=4"]
    run = run_training(load_config(TINY, overrides), tmp_path)
    trainer = run.config.trainer
    expected = budget.choose_precision("cpu", budget.native_bf16("cpu"))
    assert trainer.precision == expected
    steps_per_epoch = math.ceil(28 / 8)                       # 32 frames, 1/8 validation
    assert trainer.max_steps % steps_per_epoch == 0
    assert 1 <= trainer.max_steps // steps_per_epoch < 200   # the budget, not max_epochs
    assert run.epochs == trainer.max_steps // steps_per_epoch
    for saved in (checkpoint_config(run.last_checkpoint),
                  load_config(tmp_path / "config.yaml")):
        assert (saved.trainer.precision, saved.trainer.max_steps) == (expected,
                                                                     trainer.max_steps)

    def no_probe(*args, **kwargs):
        raise AssertionError("a resumed run must keep its step budget")

    monkeypatch.setattr("train.run.measure_speed", no_probe)
    again = run_training(load_config(TINY, overrides), tmp_path)
    assert again.config.trainer.max_steps == trainer.max_steps
    assert again.config.trainer.precision == expected
