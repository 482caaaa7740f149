"""The learning-rate schedule and its revisions when a time budget re-plans the steps: after its
peak the rate never rises again, whatever the revisions."""

from __future__ import annotations

import io
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from train.schedule import PEAK, LrSchedule, lr_factor

TINY = Path(__file__).resolve().parents[2] / "configs" / "train" / "tiny.yaml"
ONECYCLE = ("onecycle", 0.05, 0.01)       # panda_cpu's schedule, warm-up and final fraction
LR = 0.002                                # panda_cpu's peak learning rate
# A 45-minute run whose plan was revised nine times, 2884 -> ... -> 2433 (at step, new total);
# evaluating the schedule's formula for each new total gave 2.27e-05 at step 2200 (plan 2250)
# and 5.05e-05 at step 2250 (plan 2433): the rate rose again after its peak.
OBSERVED_FIRST_PLAN = 2884
OBSERVED_REVISIONS = ((240, 2800), (480, 2700), (720, 2600), (960, 2500), (1200, 2450),
                      (1440, 2400), (1680, 2330), (1920, 2250), (2210, 2433))
RISING_TOLERANCE = 1e-12   # the warm-up's rise, recomputed at a revision, may round down this


def _factors(first_plan: int, revisions, steps: int, schedule=ONECYCLE) -> np.ndarray:
    """The factors of steps 0 .. steps - 1, each revision made when the run reaches its step
    (as `train.budget.BudgetStop` does): earlier steps are read before it."""
    lr_schedule = LrSchedule(first_plan, *schedule)
    pending = dict(revisions)
    factors = []
    for step in range(steps):
        if step in pending:
            lr_schedule.revise(step, pending.pop(step))
        factors.append(lr_schedule(step))
    return np.array(factors)


def _assert_rises_then_falls(factors: np.ndarray) -> None:
    peak = int(np.argmax(factors))
    assert factors.max() <= PEAK
    assert np.all(np.diff(factors[:peak + 1]) >= -RISING_TOLERANCE), "warm-up fell"
    after = np.diff(factors[peak:])
    assert np.all(after <= 0), f"rose after the peak at step {peak + int(np.argmax(after)) + 1}"


def test_the_formula_for_each_new_total_made_the_observed_rate_rise():
    assert LR * lr_factor(2200, 2250, *ONECYCLE) == pytest.approx(2.27e-05, rel=1e-2)
    assert LR * lr_factor(2250, 2433, *ONECYCLE) == pytest.approx(5.05e-05, rel=1e-2)


def test_the_observed_revisions_never_raise_the_rate_after_its_peak():
    factors = _factors(OBSERVED_FIRST_PLAN, OBSERVED_REVISIONS, 2500)
    _assert_rises_then_falls(factors)
    assert factors[2250] <= factors[2200]
    assert int(np.argmax(factors)) == int(0.05 * OBSERVED_FIRST_PLAN) - 1   # never revised
    assert factors[2433] == pytest.approx(0.01)            # the end of the last plan
    assert np.all(factors[2433:] == factors[2433])


@pytest.mark.parametrize("schedule", [ONECYCLE, ("onecycle", 0.3, 0.0), ("cosine", 0.05, 0.1),
                                      ("constant", 0.05, 0.01)])
@pytest.mark.parametrize("seed", range(8))
def test_no_revision_raises_the_rate_after_its_peak(schedule, seed):
    """Random plans revised at random steps (in the warm-up, after the peak, after the plan
    ended), each to a random total, shorter or longer."""
    rng = np.random.default_rng(seed)
    first = int(rng.integers(2, 3000))
    steps = np.sort(rng.choice(int(1.2 * first), size=int(rng.integers(1, 12)), replace=False))
    revisions = [(int(s), int(rng.integers(s + 1, 2 * first + 2))) for s in steps]
    factors = _factors(first, revisions, 2 * first + 10, schedule)
    _assert_rises_then_falls(factors)
    final = PEAK if schedule[0] == "constant" else schedule[2]
    assert factors[-1] == pytest.approx(final)             # the last plan has ended
    assert factors[int(np.argmax(factors)):].min() >= final - 1e-12 and factors[0] > 0


def test_a_revision_to_the_same_total_changes_nothing():
    for total in (1, 7, 100, 2884):
        plain = [lr_factor(s, total, *ONECYCLE) for s in range(total + 5)]
        revised = _factors(total, [(s, total) for s in range(0, total, 3)], total + 5)
        np.testing.assert_allclose(revised, plain, rtol=0, atol=1e-12)


def test_a_revision_in_the_warm_up_stretches_or_shortens_it_up_to_the_peak():
    # 1000 steps: 50 of warm-up, the rate at step 19 is 20/50
    longer = _factors(1000, [(20, 4000)], 400)          # warm-up now ends at step 199
    assert longer[20] == pytest.approx(21 / 50)          # where it was, then a slower rise
    assert longer[100] < lr_factor(100, 1000, *ONECYCLE) and longer[199] == PEAK
    shorter = _factors(1000, [(20, 100)], 120)          # the new warm-up (5 steps) is over
    assert shorter[20] == pytest.approx(21 / 50) and shorter[21] == PEAK
    _assert_rises_then_falls(longer)
    _assert_rises_then_falls(shorter)


def test_a_plan_extended_after_it_ended_stays_at_the_final_rate():
    factors = _factors(100, [(100, 300)], 300)
    assert np.all(factors[100:] == pytest.approx(0.01))


def test_the_module_revises_its_schedule_and_a_resumed_run_continues_it():
    """Through `BeliefModule`: the rate the optimiser gets step by step while `replan` revises
    the plan (as `BudgetStop` calls it, after the step's scheduler update), and the scheduler
    state a checkpoint saves (loaded weights-only) carrying the revised schedule."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("lightning")
    from train.config import load_config
    from train.module import BeliefModule

    config = load_config(TINY, ["model.num_keypoints=4", f"optim.lr={LR}",
                                "optim.warmup_fraction=0.05", "optim.final_lr_fraction=0.01"])

    def schedule_of(total: int):
        module = BeliefModule(config)
        module.trainer = SimpleNamespace(estimated_stepping_batches=total, global_step=0)
        optimizers = module.configure_optimizers()
        return module, optimizers["optimizer"], optimizers["lr_scheduler"]["scheduler"]

    module, optimizer, scheduler = schedule_of(OBSERVED_FIRST_PLAN)
    revisions = dict(OBSERVED_REVISIONS)
    rates = [optimizer.param_groups[0]["lr"]]
    for step in range(1, 2300):
        optimizer.step()
        scheduler.step()
        rates.append(optimizer.param_groups[0]["lr"])     # the rate of step `step`
        module.trainer.global_step = step
        if step in revisions:
            module.replan(revisions[step])
    _assert_rises_then_falls(np.array(rates) / LR)
    assert module.config.trainer.max_steps == 2433

    saved = io.BytesIO()
    torch.save(scheduler.state_dict(), saved)
    saved.seek(0)
    _, resumed_optimizer, resumed = schedule_of(2433)      # a resumed run's plan
    resumed.load_state_dict(torch.load(saved, weights_only=True))
    for _ in range(50):
        for opt, sched in ((optimizer, scheduler), (resumed_optimizer, resumed)):
            opt.step()
            sched.step()
        assert resumed_optimizer.param_groups[0]["lr"] == optimizer.param_groups[0]["lr"]
