"""Training settings that depend on the machine: `trainer.precision: auto` and
`trainer.time_budget_minutes`.

- **precision auto**: bfloat16 autocast (`bf16-mixed`) only where the hardware computes in
  bfloat16 natively (a CPU with AVX512-BF16 or AMX, a GPU that reports bfloat16 support),
  float32 (`32-true`) elsewhere. Measured with the `panda_cpu` network (forward, backward and
  AdamW, batch 16, 2 threads): on an AMD EPYC with AVX512-BF16 bf16-mixed ran at 57 images/s
  against 36 in float32; on an AVX2-only AMD EPYC (Zen 3) at 1.0 against 11, where PyTorch
  emulates bfloat16.
- **time budget**: a probe run (a throwaway copy of the network, the real data loaders and
  precision, one device) times a few training steps and validation batches on this machine; the
  run then gets the optimiser steps that fit in what the probe left of the budget, validations
  included (`trainer.max_steps`, exact: the last epoch may be partial), so that the
  learning-rate schedule spans the time available. `BudgetStop` ends the run validated and
  checkpointed at the last planned step, or earlier at the deadline when the probe was
  optimistic. During the run the plan is revised from the measured rate (`BudgetStop`,
  `revised_steps`), and the learning-rate schedule re-plans the steps left from the rate it has
  reached, never rising after its peak (`train.schedule`). The resolved values are written to
  the run's config.yaml and checkpoints, with the revised plan and the steps trained (the
  config.yaml when the run ends); a resumed run keeps its checkpoint's values (and the time it
  had spent) instead of probing again.

`choose_precision`, `steps_per_epoch` and `steps_for_budget` are pure; the rest asks torch and
times Lightning.
"""

from __future__ import annotations

import logging
import math
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback
from torch.utils.data import DataLoader

from dream.errors import InputError
from train.config import AUTO_PRECISION, TrainConfig
from train.module import BeliefModule

logger = logging.getLogger(__name__)

BF16 = "bf16-mixed"
FP32 = "32-true"
_LIGHTNING_INFO_LOGGER = "lightning.pytorch.utilities.rank_zero"  # the trainer banners
PROBE_WARMUP_STEPS = 3  # untimed first steps: worker start-up, allocator and oneDNN warm-up
REPLAN_FRACTION = 0.1   # the step plan is revised after every tenth of the time budget
MIN_REPLAN_CHANGE = 0.05  # ... when it changes by more than 5 %


def choose_precision(device: str, native_bf16: bool) -> str:
    """The precision `auto` stands for: bf16-mixed on a "cpu" or "cuda" device that computes
    bfloat16 natively, 32-true otherwise (other devices included)."""
    if device not in ("cpu", "cuda", "other"):
        raise ValueError(f"device must be cpu, cuda or other, got {device!r}")
    return BF16 if device in ("cpu", "cuda") and native_bf16 else FP32


def steps_per_epoch(images: int, batch_size: int, world_size: int = 1) -> int:
    """Optimiser steps of one epoch over `images` frames shared by `world_size` devices."""
    if images < 0 or batch_size < 1 or world_size < 1:
        raise ValueError(f"need images >= 0, batch_size >= 1 and world_size >= 1, got "
                         f"{images}, {batch_size}, {world_size}")
    return math.ceil(math.ceil(images / world_size) / batch_size)


def steps_for_budget(budget_s: float, s_per_step: float, s_per_validation: float,
                     steps_per_validation: int, max_steps: int) -> int:
    """The most optimiser steps, at least one and at most `max_steps`, whose training time plus
    validations (one every `steps_per_validation` steps and one after the last step) fit in
    `budget_s` seconds."""
    if not (budget_s > 0 and s_per_step > 0 and s_per_validation >= 0
            and steps_per_validation >= 1 and max_steps >= 1):
        raise ValueError(f"need budget_s > 0, s_per_step > 0, s_per_validation >= 0, "
                         f"steps_per_validation >= 1 and max_steps >= 1, got {budget_s}, "
                         f"{s_per_step}, {s_per_validation}, {steps_per_validation}, {max_steps}")

    def seconds(steps: int) -> float:
        return steps * s_per_step + math.ceil(steps / steps_per_validation) * s_per_validation

    low, high = 1, max_steps      # the time grows with the steps: bisect for the last that fits
    if seconds(high) <= budget_s:
        return high
    while high - low > 1:
        mid = (low + high) // 2
        low, high = (mid, high) if seconds(mid) <= budget_s else (low, mid)
    return low


def device_kind(accelerator: str) -> str:
    """"cuda", "cpu" or "other" for a Lightning accelerator name ("auto" as Lightning picks:
    CUDA when available)."""
    if accelerator in ("gpu", "cuda") or (accelerator == "auto" and torch.cuda.is_available()):
        return "cuda"
    if accelerator == "cpu" or (accelerator == "auto" and not torch.backends.mps.is_available()):
        return "cpu"
    return "other"


def native_bf16(device: str) -> bool:
    """Whether `device` ("cpu" or "cuda") computes bfloat16 natively."""
    if device == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    if device == "cpu":  # torch.cpu's feature tests; absent in other torch versions: no
        return any(getattr(torch.cpu, name, lambda: False)()
                   for name in ("_is_avx512_bf16_supported", "_is_amx_tile_supported"))
    return False


def resolve_precision(config: TrainConfig) -> TrainConfig:
    """`config` with `trainer.precision: auto` replaced by what this machine runs best."""
    if config.trainer.precision != AUTO_PRECISION:
        return config
    device = device_kind(config.trainer.accelerator)
    native = native_bf16(device)
    precision = choose_precision(device, native)
    logger.info("precision auto: %s (%s device, %s bfloat16)", precision, device,
                "native" if native else "no native")
    return config.replace(trainer=replace(config.trainer, precision=precision))


@dataclass(frozen=True)
class Speed:
    """Measured on this machine: training and validation images per second, and the seconds
    the measurement took."""

    train_images_per_s: float
    val_images_per_s: float | None  # None: no validation data
    probe_s: float = 0.0

    def validation_s(self, images: int) -> float:
        """Seconds of one validation over `images` frames (0 without validation data)."""
        return images / self.val_images_per_s if self.val_images_per_s and images else 0.0


class _BatchClock(Callback):
    """Times the training (or validation) batches after the first `skip`."""

    def __init__(self, skip: int, stage: str):
        self.skip, self.stage = skip, stage
        self.images, self.start, self.end, self._batches = 0, None, None, 0

    def _on_start(self) -> None:
        if self._batches == self.skip:
            self.start = time.perf_counter()

    def _on_end(self, batch) -> None:
        if self._batches >= self.skip:
            self.images += int(batch["image"].shape[0])
            self.end = time.perf_counter()
        self._batches += 1

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        if self.stage == "train":
            self._on_start()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        if self.stage == "train":
            self._on_end(batch)

    def on_validation_batch_start(self, trainer, pl_module, batch, batch_idx,
                                  dataloader_idx=0) -> None:
        if self.stage == "val":
            self._on_start()

    def on_validation_batch_end(self, trainer, pl_module, outputs, batch, batch_idx,
                                dataloader_idx=0) -> None:
        if self.stage == "val":
            self._on_end(batch)

    def images_per_s(self) -> float:
        if self.start is None or self.end is None or self.end <= self.start or not self.images:
            raise InputError("the speed probe timed no batch", None,
                             "raise trainer.budget_probe_steps or give more training data")
        return self.images / (self.end - self.start)


def _probe_trainer(config: TrainConfig, clock: _BatchClock, root: str, **limits) -> L.Trainer:
    tc = config.trainer
    return L.Trainer(default_root_dir=root, accelerator=tc.accelerator, devices=1,
                     precision=tc.precision, logger=False, enable_checkpointing=False,
                     enable_progress_bar=False, enable_model_summary=False,
                     num_sanity_val_steps=0, callbacks=[clock], **limits)


def measure_speed(config: TrainConfig, train_loader: DataLoader,
                  val_loader: DataLoader | None) -> Speed:
    """Training and validation speed of `config`'s network on this machine (one device),
    through the real loaders: `trainer.budget_probe_steps` timed steps after
    `PROBE_WARMUP_STEPS`, and as many validation batches after one untimed batch (the only
    batch timed when there is one)."""
    steps = config.trainer.budget_probe_steps
    start = time.perf_counter()
    banners = logging.getLogger(_LIGHTNING_INFO_LOGGER)
    level = banners.level
    banners.setLevel(logging.WARNING)   # the probe's trainers: no "GPU available" lines
    try:
        train_rate, val_rate = _probe(config, train_loader, val_loader, steps)
    finally:
        banners.setLevel(level)
    probe_s = time.perf_counter() - start
    logger.info("speed probe: %.0f s", probe_s)
    return Speed(train_rate, val_rate, probe_s)


def _probe(config: TrainConfig, train_loader: DataLoader, val_loader: DataLoader | None,
           steps: int) -> tuple[float, float | None]:
    with tempfile.TemporaryDirectory(prefix="dream-probe-") as root:
        module = BeliefModule(config)
        clock = _BatchClock(PROBE_WARMUP_STEPS, "train")
        with warnings.catch_warnings():  # validation has its own probe below
            warnings.filterwarnings("ignore", message=r".*no `val_dataloader`")
            _probe_trainer(config, clock, root, max_steps=PROBE_WARMUP_STEPS + steps,
                           max_epochs=-1, limit_val_batches=0).fit(module, train_loader)
        train_rate = clock.images_per_s()
        val_rate = None
        if val_loader is not None:
            clock = _BatchClock(1 if len(val_loader) > 1 else 0, "val")
            _probe_trainer(config, clock, root, limit_val_batches=min(len(val_loader),
                                                                      steps + 1)
                           ).validate(module, val_loader, verbose=False)
            val_rate = clock.images_per_s()
    return train_rate, val_rate


def resolve_time_budget(config: TrainConfig, speed: Speed, train_images_per_epoch: int,
                        val_images_per_validation: int) -> TrainConfig:
    """`config` with `trainer.max_steps` set to the optimiser steps of `speed` that fit, with
    their validations, in `trainer.time_budget_minutes` less the probe's time (at least one step,
    at most the config's own max_steps and max_epochs).

    Args:
        train_images_per_epoch: training images per epoch (one device).
        val_images_per_validation: the validation images (0: none).
    """
    tc = config.trainer
    batch = config.data.batch_size
    epoch_steps = steps_per_epoch(train_images_per_epoch, batch)
    cap = tc.max_epochs * epoch_steps
    if tc.max_steps is not None:
        cap = min(cap, tc.max_steps)
    s_per_validation = speed.validation_s(val_images_per_validation)
    left_s = 60 * tc.time_budget_minutes - speed.probe_s
    steps = 1 if left_s <= 0 else steps_for_budget(
        left_s, batch / speed.train_images_per_s, s_per_validation,
        epoch_steps * tc.val_every_n_epochs, max(cap, 1))
    logger.info("time budget %.1f min (%.1f left after the probe): %.1f training images/s, %s "
                "validation images/s -> %d steps, %.2f epochs of %d steps", tc.time_budget_minutes,
                left_s / 60, speed.train_images_per_s,
                "no" if speed.val_images_per_s is None else f"{speed.val_images_per_s:.1f}",
                steps, steps / epoch_steps, epoch_steps)
    return config.replace(trainer=replace(tc, max_steps=steps))


def revised_steps(step: int, s_per_step: float, left_s: float, step_cap: int) -> int:
    """The step plan revised at optimiser step `step`: those done and the ones that fit in the
    `left_s` seconds left at the measured `s_per_step` (validations included, as they were in
    the measurement), at least one more and at most `step_cap` (pure).

    >>> revised_steps(100, 0.5, 60.0, 10_000)
    220
    >>> revised_steps(100, 0.5, 60.0, 150)
    150
    """
    if not s_per_step > 0:
        raise ValueError(f"s_per_step must be > 0, got {s_per_step}")
    return int(min(step_cap, step + max(1, math.floor(max(left_s, 0.0) / s_per_step))))


class BudgetStop(Callback):
    """Ends a time-budgeted run validated and checkpointed: at its last planned step (Lightning
    ends a partial epoch at `max_steps` without validating) or, when the plan was optimistic,
    at the deadline. Its clock (the seconds spent, the probe's included) is saved in the
    checkpoints, so a resumed run keeps the deadline.

    With a `step_cap`, the plan is revised after every `REPLAN_FRACTION` of the budget, and at
    its last step, from the rate measured in this run (`revised_steps`): shrunk whenever it no
    longer fits, grown when by more than `MIN_REPLAN_CHANGE`. A probe taken while the machine
    was busy, or a machine that slows down, no longer leaves most of the budget unused or the
    schedule cut short. The trainer's step and epoch limits and the module's schedule
    (`replan(steps)`: the steps left re-planned from the learning rate reached, which never
    rises after its peak, `train.schedule`) follow.

    Args:
        max_steps: the planned optimiser steps.
        deadline_s: seconds after which the run stops at the next step.
        spent_s: seconds already spent (the probe).
        clock: seconds, monotonic (tests pass their own).
        step_cap: the most steps the config allows (None: the plan is not revised).
    """

    def __init__(self, max_steps: int, deadline_s: float, spent_s: float = 0.0,
                 clock: Callable[[], float] = time.monotonic, step_cap: int | None = None):
        self.max_steps, self.deadline_s, self.clock = max_steps, deadline_s, clock
        self._spent_before, self._start, self._excluded_s = spent_s, clock(), 0.0
        self.stopped_at_deadline: int | None = None  # the step, when the deadline ended the run
        self.step_cap = step_cap
        self.revisions: list[tuple[int, int]] = []   # (at step, new plan)
        self._run_start = (0, spent_s)               # (step, seconds spent) when training began
        self._next_replan_s = spent_s + REPLAN_FRACTION * deadline_s

    def spent_s(self) -> float:
        return self._spent_before + self.clock() - self._start - self._excluded_s

    def exclude(self, seconds: float) -> None:
        """Leave `seconds` of work that is not the run's (a benchmark's own evaluations) out of
        the budget."""
        self._excluded_s += seconds

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._start, self._excluded_s = self.clock(), 0.0
        spent = self.spent_s()
        self._run_start = (trainer.global_step, spent)
        self._next_replan_s = spent + REPLAN_FRACTION * self.deadline_s
        # a resumed run that had spent its budget stops; a new run whose probe took it all
        # still trains its one planned step
        if spent >= self.deadline_s and trainer.global_step > 0:
            trainer.should_stop = True

    def _replan(self, trainer: L.Trainer, pl_module: L.LightningModule, step: int,
                spent: float) -> None:
        """Revise the plan from the rate measured since training began (class doc)."""
        self._next_replan_s = spent + REPLAN_FRACTION * self.deadline_s
        done, elapsed = step - self._run_start[0], spent - self._run_start[1]
        if done < 1 or elapsed <= 0:
            return
        new = revised_steps(step, elapsed / done, self.deadline_s - spent, self.step_cap)
        if self.max_steps <= new <= (1 + MIN_REPLAN_CHANGE) * self.max_steps:
            return    # a plan that no longer fits always shrinks; one that fits grows by > 5 %
        logger.info("step plan revised at step %d: %d -> %d steps (%.3f s per step measured)",
                    step, self.max_steps, new, elapsed / done)
        self.max_steps = new
        self.revisions.append((step, new))
        trainer.fit_loop.epoch_loop.max_steps = new
        trainer.fit_loop.max_epochs = max(trainer.current_epoch + 1, math.ceil(
            new / max(1, trainer.num_training_batches)))
        replan = getattr(pl_module, "replan", None)
        if replan is not None:
            replan(new)

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any,
                           batch: Any, batch_idx: int) -> None:
        step = trainer.global_step
        spent = self.spent_s()
        late = trainer.strategy.reduce_boolean_decision(spent >= self.deadline_s, all=False)
        if self.step_cap is not None and not late and (spent >= self._next_replan_s
                                                       or step >= self.max_steps):
            self._replan(trainer, pl_module, step, spent)   # also before ending at the plan
        if step >= self.max_steps or late:
            trainer.should_stop = True   # Lightning validates and checkpoints, then stops
        if late and step < self.max_steps and self.stopped_at_deadline is None:
            self.stopped_at_deadline = step
            logger.warning("time budget spent (%.1f min) at step %d of the %d planned: the "
                           "step plan was optimistic; stopping with the learning rate at "
                           "%.2e", self.spent_s() / 60, step, self.max_steps,
                           trainer.optimizers[0].param_groups[0]["lr"])

    def state_dict(self) -> dict[str, float]:
        return {"spent_s": self.spent_s(), "deadline_s": self.deadline_s}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._spent_before = float(state_dict["spent_s"])
        self.deadline_s = float(state_dict["deadline_s"])
        self._start, self._excluded_s = self.clock(), 0.0
