"""Machine-dependent training settings: `trainer.precision: auto` and the time budget."""

from __future__ import annotations

import csv
import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("lightning")
pytest.importorskip("albumentations")

from lightning.pytorch.callbacks import Callback  # noqa: E402

import train.run as train_run  # noqa: E402
from dream.errors import InputError  # noqa: E402
from tests.trainkit import make_drawn_dataset  # noqa: E402
from train import budget  # noqa: E402
from train.checkpoint import checkpoint_config  # noqa: E402
from train.config import load_config  # noqa: E402
from train.run import run_training  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "configs" / "train" / "tiny.yaml"
RATE_ROUNDING = 1e-12   # a warm-up revised mid-rise may recompute its rate this much lower


class RateRecorder(Callback):
    """The learning rate of every optimiser step after the first, read where `BudgetStop`
    revises the plan (after the step's scheduler update)."""

    def __init__(self) -> None:
        self.rates: list[float] = []

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        self.rates.append(trainer.optimizers[0].param_groups[0]["lr"])


def _rises_then_falls(rates: list[float]) -> bool:
    """Whether `rates` never fall before their peak (but for rounding) nor rise after it."""
    peak = int(np.argmax(rates))
    rise, fall = np.diff(rates[:peak + 1]), np.diff(rates[peak:])
    return bool(np.all(rise >= -RATE_ROUNDING * rates[peak]) and np.all(fall <= 0))


@pytest.fixture(scope="module")
def drawn(tmp_path_factory) -> Path:
    return make_drawn_dataset(tmp_path_factory.mktemp("drawn") / "data", 32)


@pytest.mark.parametrize(("device", "native", "expected"), [
    ("cpu", True, "bf16-mixed"), ("cpu", False, "32-true"), ("cuda", True, "bf16-mixed"),
    ("cuda", False, "32-true"), ("other", True, "32-true")])
def test_auto_precision_takes_bfloat16_only_where_it_is_native(device, native, expected):
    assert budget.choose_precision(device, native) == expected


def test_steps_per_epoch_shares_the_frames_between_devices():
    assert budget.steps_per_epoch(28, 8) == 4
    assert budget.steps_per_epoch(1000, 16, world_size=2) == 32      # 500 frames a device
    with pytest.raises(ValueError, match="batch_size >= 1"):
        budget.steps_per_epoch(10, 0)


def test_the_budget_buys_the_steps_that_fit_with_their_validations():
    # 1 s a step, a 10 s validation every 20 steps and after the last: 60 steps take 90 s,
    # 61 would take 101 (a 4th validation)
    assert budget.steps_for_budget(100, 1.0, 10.0, 20, 10**6) == 60
    assert budget.steps_for_budget(100, 1.0, 0.0, 20, 10**6) == 100
    assert budget.steps_for_budget(5, 10.0, 10.0, 20, 10**6) == 1     # at least one
    assert budget.steps_for_budget(100, 1.0, 10.0, 20, 42) == 42      # the cap
    with pytest.raises(ValueError, match="budget_s > 0"):
        budget.steps_for_budget(0, 1.0, 10.0, 20, 100)


@pytest.mark.parametrize("seed", range(5))
def test_the_step_budget_is_the_largest_that_fits(seed):
    rng = np.random.default_rng(seed)
    budget_s, s_step, s_val = rng.uniform(10, 500), rng.uniform(0.1, 2), rng.uniform(0, 20)
    every, cap = int(rng.integers(1, 50)), int(rng.integers(1, 2000))

    def seconds(n):
        return n * s_step + math.ceil(n / every) * s_val

    fits = [n for n in range(1, cap + 1) if seconds(n) <= budget_s]
    assert budget.steps_for_budget(budget_s, s_step, s_val, every, cap) == max(fits, default=1)


def test_time_budget_becomes_an_exact_step_budget():
    config = load_config(TINY, ["trainer.time_budget_minutes=1",
                                "trainer.max_epochs=1000", "model.num_keypoints=4"])
    speed = budget.Speed(train_images_per_s=100.0, val_images_per_s=200.0, probe_s=4.0)
    # 1000 images of batch 8: 125 steps an epoch, 0.08 s a step; 100 validation images 0.5 s;
    # 56 s left after the probe: 662 steps (52.96 s + 6 validations), 5.3 epochs
    resolved = budget.resolve_time_budget(config, speed, 1000, 100)
    assert resolved.trainer.max_steps == 662
    capped = config.replace(trainer=replace(config.trainer, max_steps=300))
    assert budget.resolve_time_budget(capped, speed, 1000, 100).trainer.max_steps == 300
    epochs = config.replace(trainer=replace(config.trainer, max_epochs=2))
    assert budget.resolve_time_budget(epochs, speed, 1000, 100).trainer.max_steps == 250
    late = replace(speed, probe_s=61.0)                      # the probe spent the budget
    assert budget.resolve_time_budget(config, late, 1000, 100).trainer.max_steps == 1


@pytest.mark.parametrize("override", ["trainer.time_budget_minutes=0",
                                      "trainer.budget_probe_steps=0"])
def test_bad_budget_settings_are_refused(override):
    with pytest.raises(InputError, match=override.split("=")[0].replace(".", r"\.")):
        load_config(TINY, [override])


def test_the_budget_clock_leaves_out_excluded_work_and_survives_a_checkpoint():
    now = [100.0]
    stop = budget.BudgetStop(10, 60.0, spent_s=5.0, clock=lambda: now[0])
    now[0] = 130.0
    assert stop.spent_s() == 35.0                            # the probe's 5 s and 30 s since
    stop.exclude(10.0)                                       # e.g. a benchmark's evaluation
    assert stop.spent_s() == 25.0
    resumed = budget.BudgetStop(10, 999.0, clock=lambda: now[0])
    resumed.load_state_dict(stop.state_dict())
    now[0] = 140.0
    assert (resumed.spent_s(), resumed.deadline_s) == (35.0, 60.0)



def _fake_trainer(step: int) -> SimpleNamespace:
    strategy = SimpleNamespace(reduce_boolean_decision=lambda decision, all: decision)
    return SimpleNamespace(global_step=step, should_stop=False, strategy=strategy,
                           optimizers=[SimpleNamespace(param_groups=[{"lr": 1e-3}])])


def test_a_new_run_whose_probe_spent_the_budget_still_trains_one_step():
    stop = budget.BudgetStop(1, 60.0, spent_s=75.0, clock=lambda: 0.0)
    fresh = _fake_trainer(0)
    stop.on_train_start(fresh, None)
    assert not fresh.should_stop                         # its one planned step is taken
    fresh.global_step = 1
    stop.on_train_batch_end(fresh, None, None, None, 0)
    assert fresh.should_stop
    resumed = _fake_trainer(40)                          # a resumed run that had spent it all
    budget.BudgetStop(100, 60.0, spent_s=75.0, clock=lambda: 0.0).on_train_start(resumed, None)
    assert resumed.should_stop


def _planned_speed(steps_that_fit: int, budget_s: float):
    """A probe's answer under which `steps_that_fit` steps of batch 8 fill `budget_s`."""
    def speed(*args, **kwargs):
        return budget.Speed(8 * (steps_that_fit + 0.5) / budget_s, 1e9, probe_s=0.0)
    return speed


def test_a_budgeted_auto_run_resolves_records_and_resumes_without_probing(drawn, tmp_path,
                                                                          monkeypatch):
    overrides = [f"data.train=[{drawn}]", "trainer.precision=auto",
                 "trainer.time_budget_minutes=1", "trainer.max_epochs=200"]
    # 5 steps fit: 4 steps an epoch (28 training frames of 32), so the second epoch is partial
    monkeypatch.setattr("train.run.measure_speed", _planned_speed(5, 60.0))
    monkeypatch.setattr("train.run._step_cap", lambda *args: None)   # the plan as probed
    run = run_training(load_config(TINY, overrides), tmp_path)
    trainer = run.config.trainer
    expected = budget.choose_precision("cpu", budget.native_bf16("cpu"))
    assert (trainer.precision, trainer.max_steps) == (expected, 5)
    ckpt = torch.load(run.last_checkpoint, map_location="cpu", weights_only=False)
    assert ckpt["global_step"] == 5
    [state] = [v for k, v in ckpt["callbacks"].items() if "BudgetStop" in k]
    assert 0 < state["spent_s"] < state["deadline_s"] <= 60
    rows = _rows(tmp_path / "metrics.csv")
    assert [(r["epoch"], r["step"]) for r in rows] == [("0", "4"), ("1", "5")]
    assert rows[-1]["val/loss"] != ""                        # the partial epoch was validated
    assert run.best_checkpoint.name == "best.ckpt" and run.best_checkpoint.is_file()
    for saved in (checkpoint_config(run.last_checkpoint),
                  load_config(tmp_path / "config.yaml")):
        assert (saved.trainer.precision, saved.trainer.max_steps) == (expected, 5)

    def no_probe(*args, **kwargs):
        raise AssertionError("a resumed run must keep its step budget")

    monkeypatch.setattr("train.run.measure_speed", no_probe)
    again = run_training(load_config(TINY, overrides), tmp_path)
    assert again.config.trainer.max_steps == 5
    assert again.config.trainer.precision == expected


@pytest.mark.slow
def test_a_run_slower_than_its_probe_stops_validated_at_the_deadline(drawn, tmp_path,
                                                                     monkeypatch, caplog):
    overrides = [f"data.train=[{drawn}]", "trainer.time_budget_minutes=1",
                 "trainer.max_epochs=200"]
    monkeypatch.setattr("train.run.measure_speed", _planned_speed(400, 60.0))
    monkeypatch.setattr("train.run._step_cap", lambda *args: None)   # the deadline, no new plan
    ticks = iter(range(0, 10**6, 10))     # a clock that advances 10 s at every reading
    stops: list[budget.BudgetStop] = []

    def fake_clock_stop(config, speed, val_images, step_cap=None):
        stops.append(budget.BudgetStop(config.trainer.max_steps, 60.0, 0.0,
                                       clock=lambda: float(next(ticks))))
        return stops[-1]

    monkeypatch.setattr("train.run._budget_stop", fake_clock_stop)
    with caplog.at_level("WARNING", logger="train.budget"):
        run = run_training(load_config(TINY, overrides), tmp_path)
    stopped = stops[0].stopped_at_deadline
    assert run.config.trainer.max_steps == 400 and stopped is not None and stopped < 400
    assert torch.load(run.last_checkpoint, map_location="cpu",
                      weights_only=False)["global_step"] == stopped
    assert _rows(tmp_path / "metrics.csv")[-1]["val/loss"] != ""
    assert "step plan was optimistic" in caplog.text
    recorded = load_config(tmp_path / "config.yaml").trainer
    assert (recorded.max_steps, recorded.steps_trained) == (400, stopped)
    # run again into the folder: the checkpoint's clock says the budget is spent, no more steps
    again = run_training(load_config(TINY, overrides), tmp_path)
    assert stops[-1].spent_s() >= 60.0 and again.config.trainer.max_steps == 400
    assert again.config.trainer.steps_trained == stopped
    assert torch.load(again.last_checkpoint, map_location="cpu",
                      weights_only=False)["global_step"] == stopped


def _budget_overrides(drawn) -> list[str]:
    """A one-minute budgeted run of the tiny recipe on `drawn`, one thread."""
    return [f"data.train=[{drawn}]", "trainer.time_budget_minutes=1",
            "trainer.max_epochs=200", "trainer.num_threads=1"]


def _fake_clock_stops(monkeypatch, clock) -> list[budget.BudgetStop]:
    """Make every `BudgetStop` of the next run read `clock()` instead of the wall clock; the
    list fills with the stops made."""
    stops: list[budget.BudgetStop] = []
    real_stop = train_run._budget_stop

    def fake_clock_stop(config, speed, val_images, step_cap=None):
        stop = real_stop(config, speed, val_images, step_cap)
        stop.clock = clock
        stop._start = stop.clock()
        stops.append(stop)
        return stop

    monkeypatch.setattr("train.run._budget_stop", fake_clock_stop)
    return stops


@pytest.mark.parametrize("probed, tick_s", [
    (400, 1.0),   # a probe about 8x optimistic: the plan shrinks, the deadline does not cut it
    (40, 0.25),   # a probe taken while the machine was busy: the plan grows to fill the budget
    (5, 0.25),    # so pessimistic that the plan ends before the first revision: extended there
])
def test_the_step_plan_follows_the_measured_rate(drawn, tmp_path, monkeypatch, probed, tick_s):
    """A fake clock that advances `tick_s` at every reading (one a step, two a checkpoint):
    the plan is revised from the measured rate, and the run ends at its plan, not at the
    deadline, with the learning rate at the end of its schedule, validated, the checkpoint
    recording the revised plan, which spends most of the budget."""
    monkeypatch.setattr("train.run.measure_speed", _planned_speed(probed, 60.0))
    ticks = (tick_s * i for i in range(10**6))
    stops = _fake_clock_stops(monkeypatch, lambda: float(next(ticks)))
    recorder = RateRecorder()
    run = run_training(load_config(TINY, _budget_overrides(drawn)), tmp_path,
                       callbacks=[recorder])
    stop = stops[0]
    assert stop.revisions and stop.stopped_at_deadline is None
    assert _rises_then_falls(recorder.rates), (stop.revisions, recorder.rates)
    final = stop.revisions[-1][1]
    assert (final < probed) == (tick_s >= 1.0), stop.revisions
    spent = stop.spent_s()      # (this reading and the last checkpoints' advance the clock too)
    assert 0.8 * stop.deadline_s <= spent <= stop.deadline_s + 10 * tick_s
    ckpt = torch.load(run.last_checkpoint, map_location="cpu", weights_only=False)
    assert ckpt["global_step"] == final
    assert checkpoint_config(run.last_checkpoint).trainer.max_steps == final
    recorded = load_config(tmp_path / "config.yaml").trainer
    assert (recorded.max_steps, recorded.steps_trained) == (final, final)
    lr = ckpt["lr_schedulers"][0]["_last_lr"][0]
    assert lr <= 2 * run.config.optim.lr * run.config.optim.final_lr_fraction
    assert _rows(tmp_path / "metrics.csv")[-1]["val/loss"] != ""


def test_config_yaml_records_the_plan_as_revised_and_the_steps_trained(drawn, tmp_path,
                                                                      monkeypatch):
    """A run whose plan grew, then shrank as the machine slowed down (a fake clock: 0.25 s a
    reading, then 20 s), and whose deadline came before its last plan: config.yaml, written
    again when the run ends, records that plan and the steps trained, as its last checkpoint
    does; the learning rate never rose after its peak."""
    monkeypatch.setattr("train.run.measure_speed", _planned_speed(40, 60.0))
    slow_from = 45      # readings at 0.25 s, then 20 s each

    def seconds(reading: int) -> float:
        return 0.25 * min(reading, slow_from) + 20.0 * max(0, reading - slow_from)

    readings = iter(range(10**6))
    stops = _fake_clock_stops(monkeypatch, lambda: seconds(next(readings)))
    recorder = RateRecorder()
    run = run_training(load_config(TINY, _budget_overrides(drawn)), tmp_path,
                       callbacks=[recorder])
    stop = stops[0]
    trained = stop.stopped_at_deadline
    assert trained is not None and trained < stop.max_steps
    assert [new > 40 for _, new in stop.revisions][:1] == [True] and len(stop.revisions) > 1
    recorded = load_config(tmp_path / "config.yaml")
    assert (recorded.trainer.max_steps, recorded.trainer.steps_trained) == (stop.max_steps,
                                                                           trained)
    assert recorded == run.config == checkpoint_config(run.last_checkpoint)
    assert torch.load(run.last_checkpoint, map_location="cpu",
                      weights_only=True)["global_step"] == trained
    assert _rises_then_falls(recorder.rates), (stop.revisions, recorder.rates)


def test_revised_steps():
    assert budget.revised_steps(100, 0.5, 60.0, 10_000) == 220
    assert budget.revised_steps(100, 0.5, 60.0, 150) == 150
    assert budget.revised_steps(100, 0.5, -5.0, 10_000) == 101      # at least one more
    with pytest.raises(ValueError):
        budget.revised_steps(100, 0.0, 60.0, 10_000)


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))
