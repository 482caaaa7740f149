"""The training run's callbacks: `metrics.csv` rows per epoch, progress lines when the
progress bar is off, and whether the run saved a checkpoint while training."""

from __future__ import annotations

import csv
import io
import logging
import math
import time
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.trainer.states import TrainerStatus

from dream.io import write_bytes_atomic

logger = logging.getLogger(__name__)


def scalar(value: Any) -> float:
    """A logged metric as a float (a tensor's value)."""
    return float(value.detach().cpu()) if isinstance(value, torch.Tensor) else float(value)


class EpochCsv(Callback):
    """Appends one row per epoch to `metrics.csv`: epoch, step, wall time, learning rate and every
    logged epoch metric. A resumed run keeps the rows of the epochs before its start."""

    def __init__(self, path: Path):
        self.path = path
        self.rows: list[dict[str, Any]] = []
        self.elapsed_before = 0.0
        self._start = time.perf_counter()

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._start = time.perf_counter()
        start_epoch = trainer.current_epoch
        if self.path.exists():
            with open(self.path, newline="", encoding="utf-8") as fh:
                self.rows = [r for r in csv.DictReader(fh) if int(r["epoch"]) < start_epoch]
            if self.rows:
                self.elapsed_before = float(self.rows[-1]["wall_s"])

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or not trainer.is_global_zero:
            return
        row: dict[str, Any] = {"epoch": trainer.current_epoch, "step": trainer.global_step,
                               "wall_s": round(self.elapsed_before + time.perf_counter()
                                               - self._start, 2),
                               "lr": trainer.optimizers[0].param_groups[0]["lr"]}
        for key, value in sorted(trainer.callback_metrics.items()):
            if not key.endswith("_step"):
                row[key.removesuffix("_epoch")] = scalar(value)
        self.rows.append(row)
        columns: list[str] = []
        for r in self.rows:
            columns += [c for c in r if c not in columns]
        out = io.StringIO()
        writer = csv.DictWriter(out, fieldnames=columns, restval="")
        writer.writeheader()
        writer.writerows(self.rows)
        write_bytes_atomic(self.path, out.getvalue().encode("utf-8"), durable=False)


class LogLines(Callback):
    """Progress as logging lines (when the progress bar is off): every `every` steps and at each
    epoch end, with the throughput in images per second."""

    def __init__(self, every: int):
        self.every = every
        self._t0 = time.perf_counter()
        self._images = 0

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._t0, self._images = time.perf_counter(), 0

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any,
                           batch: Any, batch_idx: int) -> None:
        self._images += int(batch["image"].shape[0])
        if trainer.global_step % self.every == 0 and trainer.is_global_zero:
            rate = self._images / max(time.perf_counter() - self._t0, 1e-9)
            loss = trainer.callback_metrics.get("train/loss_step")
            logger.info("epoch %d step %d loss %.5f lr %.2e %.1f images/s", trainer.current_epoch,
                        trainer.global_step, math.nan if loss is None else scalar(loss),
                        trainer.optimizers[0].param_groups[0]["lr"], rate)

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trainer.is_global_zero:
            return
        metrics = {k.removesuffix("_epoch"): scalar(v)
                   for k, v in trainer.callback_metrics.items() if not k.endswith("_step")}
        text = "  ".join(f"{k} {v:.4g}" for k, v in sorted(metrics.items()))
        rate = self._images / max(time.perf_counter() - self._t0, 1e-9)
        logger.info("epoch %d done (%.1f images/s): %s", trainer.current_epoch, rate, text)


class Checkpointed(Callback):
    """Whether the run wrote a checkpoint in the course of training (not the one Lightning
    writes when an exception stops it)."""

    def __init__(self) -> None:
        self.saved = False

    def on_save_checkpoint(self, trainer: L.Trainer, pl_module: L.LightningModule,
                           checkpoint: dict[str, Any]) -> None:
        if trainer.state.status != TrainerStatus.INTERRUPTED:
            self.saved = True
