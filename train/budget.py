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
  run then gets the whole epochs that fit in the budget, as a step budget (`trainer.max_steps`),
  so that the learning-rate schedule spans the time available and the run ends validated and
  checkpointed. The resolved values are written to the run's config.yaml and checkpoints; a
  resumed run keeps its checkpoint's values instead of probing again.

`choose_precision` and `epochs_for_budget` are pure; the rest asks torch and times Lightning.
"""

from __future__ import annotations

import logging
import math
import tempfile
import time
import warnings
from dataclasses import dataclass, replace

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
PROBE_WARMUP_STEPS = 3  # untimed first steps: worker start-up, allocator and oneDNN warm-up


def choose_precision(device: str, native_bf16: bool) -> str:
    """The precision `auto` stands for: bf16-mixed on a "cpu" or "cuda" device that computes
    bfloat16 natively, 32-true otherwise (other devices included)."""
    if device not in ("cpu", "cuda", "other"):
        raise ValueError(f"device must be cpu, cuda or other, got {device!r}")
    return BF16 if device in ("cpu", "cuda") and native_bf16 else FP32


def epochs_for_budget(budget_s: float, train_s_per_epoch: float, val_s_per_epoch: float,
                      max_epochs: int) -> int:
    """The whole epochs (training plus validation) that fit in `budget_s` seconds: at least
    one, at most `max_epochs`."""
    if not (budget_s > 0 and train_s_per_epoch > 0 and val_s_per_epoch >= 0
            and max_epochs >= 1):
        raise ValueError(f"need budget_s > 0, train_s_per_epoch > 0, val_s_per_epoch >= 0 and "
                         f"max_epochs >= 1, got {budget_s}, {train_s_per_epoch}, "
                         f"{val_s_per_epoch}, {max_epochs}")
    return int(min(max_epochs, max(1, math.floor(budget_s / (train_s_per_epoch
                                                              + val_s_per_epoch)))))


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
    """Measured on this machine: training and validation images per second."""

    train_images_per_s: float
    val_images_per_s: float | None  # None: no validation data


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
    logger.info("speed probe: %.0f s", time.perf_counter() - start)
    return Speed(train_rate, val_rate)


def resolve_time_budget(config: TrainConfig, speed: Speed, train_images_per_epoch: int,
                        val_images_per_epoch: float) -> TrainConfig:
    """`config` with `trainer.max_steps` set to the whole epochs of `speed` that fit in
    `trainer.time_budget_minutes` (and within the config's own max_steps and max_epochs).

    Args:
        train_images_per_epoch: training images per epoch (one device).
        val_images_per_epoch: validation images per training epoch (one device; a run that
            validates every n epochs spends 1/n of its validation set per epoch).
    """
    tc = config.trainer
    batch = config.data.batch_size
    steps_per_epoch = math.ceil(train_images_per_epoch / batch)
    train_s = train_images_per_epoch / speed.train_images_per_s
    val_s = (val_images_per_epoch / speed.val_images_per_s
             if speed.val_images_per_s and val_images_per_epoch else 0.0)
    cap = tc.max_epochs
    if tc.max_steps is not None:
        cap = min(cap, math.ceil(tc.max_steps / steps_per_epoch))
    epochs = epochs_for_budget(60 * tc.time_budget_minutes, train_s, val_s, cap)
    logger.info("time budget %.1f min: %.1f training images/s, %s validation images/s -> %d "
                "epochs of %d steps (about %.1f min)", tc.time_budget_minutes,
                speed.train_images_per_s,
                "no" if speed.val_images_per_s is None else f"{speed.val_images_per_s:.1f}",
                epochs, steps_per_epoch, epochs * (train_s + val_s) / 60)
    return config.replace(trainer=replace(tc, max_steps=epochs * steps_per_epoch))
