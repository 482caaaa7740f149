"""One training run: data -> resolved config -> Lightning Trainer -> checkpoints and metrics.

A run folder holds `config.yaml` (the resolved config, written again when the run ends with the
step plan as a time budget last revised it and the steps trained, `trainer.steps_trained`),
`last.ckpt` (refreshed every epoch, every `trainer.checkpoint_every_n_steps` steps and on an
exception or Ctrl-C), `best.ckpt` (the best `trainer.monitor`) and `metrics.csv` (one row per
epoch). Running again into a folder that has a `last.ckpt` resumes from it (epoch, optimiser and
schedule), e.g. after a kill or with a larger `trainer.max_epochs`; the model, input and
keypoints must be those of the checkpoint.
"""

from __future__ import annotations

import logging
import math
import os
import re
import shutil
import signal
import threading
import warnings
from collections.abc import Iterator
from collections.abc import Sequence as SequenceOf
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback, ModelCheckpoint
from torch.utils.data import DataLoader

from dream.errors import InputError
from dream.io import outermost_missing, write_bytes_atomic
from train.budget import (
    BudgetStop,
    Speed,
    measure_speed,
    resolve_precision,
    resolve_time_budget,
    steps_per_epoch,
)
from train.callbacks import Checkpointed, EpochCsv, LogLines, scalar
from train.checkpoint import checkpoint_config, read_checkpoint
from train.config import AUTO_PRECISION, TrainConfig, dump_config
from train.data import (
    check_image_files,
    make_datasets,
    make_loader,
    read_folders,
    resolve_from_data,
)
from train.module import BeliefModule, with_steps_trained
from train.onnx_init import (
    check_metadata,
    init_from_onnx,
    is_onnx_model,
    read_onnx_weights,
    sample_images,
)

logger = logging.getLogger(__name__)

LAST = "last"
BEST = "best"
CHECKPOINT_SUFFIX = ".ckpt"
CONFIG_FILE = "config.yaml"
METRICS_FILE = "metrics.csv"
_FALLBACK_MONITOR = "train/loss_epoch"  # when there is no validation data
LIGHTNING_INTERRUPT_EXIT = 1            # Lightning's exit code after it caught a Ctrl-C


@dataclass(frozen=True)
class TrainResult:
    """Where a run wrote its outputs, its config as config.yaml records it at the end, and its
    last epoch's metrics."""

    run_dir: Path
    last_checkpoint: Path
    best_checkpoint: Path
    config: TrainConfig
    metrics: dict[str, float]
    epochs: int


def _check_resumable(config: TrainConfig, checkpoint: Path,
                     action: str = "resume") -> TrainConfig:
    """The checkpoint's network must be the one this config builds; returns the checkpoint's
    config."""
    saved = checkpoint_config(checkpoint)
    for section in ("model", "input"):
        if getattr(saved, section) != getattr(config, section):
            raise InputError(f"cannot {action}: the checkpoint's {section} settings differ from "
                             f"the config's", checkpoint, "use the same recipe, or a new --out "
                             "folder for a new run")
    if saved.data.keypoints != config.data.keypoints:
        raise InputError(f"cannot {action}: the checkpoint was trained on other keypoints",
                         checkpoint, "use a new --out folder for a new run")
    return saved


def _check_init_source(config: TrainConfig) -> None:
    """`trainer.init_from` (a checkpoint or an exported model) must fit this run."""
    source = Path(config.trainer.init_from)
    if is_onnx_model(source):
        check_metadata(read_onnx_weights(source)[1], config, source)
    else:
        _check_resumable(config, source, action="start from")


def _init_weights(module: BeliefModule, config: TrainConfig, train_set) -> None:
    """Start `module` from the network weights of `config.trainer.init_from`: a checkpoint's,
    or an exported model's with its batch norms split on training images (`train.onnx_init`)."""
    source = Path(config.trainer.init_from)
    if is_onnx_model(source):
        images = sample_images(train_set, config.data.batch_size, config.trainer.seed)
        init_from_onnx(module.model, source, config, images)
    else:
        _check_resumable(config, source, action="start from")
        module.load_state_dict(read_checkpoint(source)["state_dict"])
    logger.info("network weights from %s (fresh optimiser and schedule)", source)


def _as_started(config: TrainConfig, saved: TrainConfig) -> TrainConfig:
    """A resumed run keeps the machine-dependent values its start chose (`train.budget`):
    the precision behind `auto` and the step budget of a time budget."""
    tc = config.trainer
    precision = saved.trainer.precision if tc.precision == AUTO_PRECISION else tc.precision
    max_steps = saved.trainer.max_steps if tc.time_budget_minutes is not None else tc.max_steps
    return config.replace(trainer=replace(tc, precision=precision, max_steps=max_steps))


def _fit_time_budget(config: TrainConfig, trainer: L.Trainer, train_loader: DataLoader,
                     val_loader: DataLoader | None) -> tuple[TrainConfig, Speed]:
    """`config` with the step budget that fits `trainer.time_budget_minutes` here, and the
    speed measured."""
    if trainer.world_size > 1:
        raise InputError(f"trainer.time_budget_minutes times one device, but this run uses "
                         f"{trainer.world_size}", None, "set trainer.max_steps instead "
                         "(and trainer.time_budget_minutes=null)")
    speed = measure_speed(config, train_loader, val_loader)
    L.seed_everything(config.trainer.seed, workers=True, verbose=False)  # as without the probe
    val_images = len(val_loader.dataset) if val_loader is not None else 0
    return resolve_time_budget(config, speed, len(train_loader.dataset), val_images), speed


def _budget_stop(config: TrainConfig, speed: Speed | None, val_images: int,
                 step_cap: int | None = None) -> BudgetStop:
    """The stop of a time-budgeted run: its deadline leaves time for one last validation
    (a resumed run, `speed` None, takes its clock and deadline from the checkpoint); with a
    `step_cap` (the most steps the config allows) it revises the plan as the run goes."""
    budget_s = 60 * config.trainer.time_budget_minutes
    if speed is None:
        return BudgetStop(config.trainer.max_steps, budget_s)
    return BudgetStop(config.trainer.max_steps, budget_s - speed.validation_s(val_images),
                      speed.probe_s, step_cap=step_cap)


def _step_cap(config: TrainConfig, train_images: int) -> int:
    """The most optimiser steps the config allows: its max_epochs, and its max_steps when set
    (before a time budget replaces them)."""
    tc = config.trainer
    cap = tc.max_epochs * steps_per_epoch(train_images, config.data.batch_size)
    return min(cap, tc.max_steps) if tc.max_steps is not None else cap


def _trainer(config: TrainConfig, run_dir: Path, has_val: bool,
             callbacks: SequenceOf[Callback]) -> tuple[L.Trainer, ModelCheckpoint]:
    tc = config.trainer
    last = ModelCheckpoint(dirpath=run_dir, filename=LAST, monitor=None, save_top_k=1,
                           every_n_epochs=1, save_on_train_epoch_end=True, save_on_exception=True,
                           enable_version_counter=False)
    best = ModelCheckpoint(dirpath=run_dir, filename=BEST,
                           monitor=tc.monitor if has_val else _FALLBACK_MONITOR,
                           mode=tc.monitor_mode if has_val else "min", save_top_k=1,
                           auto_insert_metric_name=False, enable_version_counter=False)
    savers = [best, last]
    if tc.checkpoint_every_n_steps:  # mid-epoch refreshes of the same last.ckpt
        savers.append(ModelCheckpoint(dirpath=run_dir, filename=LAST, monitor=None, save_top_k=1,
                                      every_n_train_steps=tc.checkpoint_every_n_steps,
                                      enable_version_counter=False))
    all_callbacks: list[Callback] = [EpochCsv(run_dir / METRICS_FILE), *callbacks]
    if not tc.progress_bar:
        all_callbacks.append(LogLines(tc.log_every_n_steps))
    all_callbacks += savers
    trainer = L.Trainer(
        default_root_dir=run_dir, max_epochs=tc.max_epochs, accelerator=tc.accelerator,
        devices=tc.devices, strategy=tc.strategy, num_nodes=tc.num_nodes,
        precision=tc.precision, callbacks=all_callbacks, logger=False,
        enable_progress_bar=tc.progress_bar, enable_model_summary=tc.progress_bar,
        log_every_n_steps=tc.log_every_n_steps, check_val_every_n_epoch=tc.val_every_n_epochs,
        limit_val_batches=None if has_val else 0, num_sanity_val_steps=0,
        gradient_clip_val=tc.gradient_clip_val)
    return trainer, best


def _check_run_dir(run_dir: Path) -> None:
    """`run_dir` is, or can become, a folder this run writes into."""
    existing = next(p for p in (run_dir, *run_dir.parents) if p.exists() or p == p.parent)
    if existing == run_dir and not run_dir.is_dir():
        problem = "is a file, not a folder"
    elif not existing.is_dir():
        problem = f"cannot be created: {existing} is a file"
    elif not os.access(existing, os.W_OK | os.X_OK):
        problem = f"cannot be written: {existing} is not writable"
    elif existing == run_dir and any(run_dir.iterdir()) and not (run_dir / CONFIG_FILE).exists():
        problem = "holds other files and no run (no config.yaml): a data folder?"
    else:
        return
    raise InputError(f"the run folder {problem}", run_dir,
                     "give --out a new folder, or the folder of a run to go on with")


def _make_run_dir(run_dir: Path) -> Path | None:
    """Create the run folder; returns the outermost folder this created (None: it existed)."""
    created = outermost_missing(run_dir)
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the run folder ({exc.strerror or exc})", run_dir,
                         "give --out a folder that can be created") from None
    return created


_WORKER_ERROR = re.compile(r"^(?:dream\.errors\.)?InputError: (.+)$", re.MULTILINE)


def _unwrap_worker_error(exc: InputError) -> InputError:
    """An `InputError` raised in a data-loading worker comes back with the worker's traceback
    as its message; the original one-line error instead (its message is the last line)."""
    if exc.path is not None or "DataLoader worker" not in exc.problem:
        return exc
    found = _WORKER_ERROR.findall(exc.problem)
    if not found:
        return exc
    error = InputError(found[-1])
    error.args = (found[-1],)  # the original text exactly (no second full stop)
    return error


def _plan_steps(trainer: L.Trainer, config: TrainConfig, num_train: int, num_val: int,
                budget_speed: Speed | None, step_cap: int | None = None) -> None:
    """Set the trainer's epochs for `trainer.max_steps`; with a time budget (`budget_speed`,
    the probe's measurement) exactly those steps, a partial last epoch ended by BudgetStop."""
    epoch_steps = steps_per_epoch(num_train, config.data.batch_size, trainer.world_size)
    epochs = min(config.trainer.max_epochs, math.ceil(config.trainer.max_steps / epoch_steps))
    trainer.fit_loop.max_epochs = epochs
    budgeted = config.trainer.time_budget_minutes is not None
    if budgeted:
        trainer.fit_loop.epoch_loop.max_steps = config.trainer.max_steps
        trainer.callbacks.insert(0, _budget_stop(config, budget_speed, num_val, step_cap))
    logger.info("step budget %d: %d epochs of %d steps%s", config.trainer.max_steps,
                epochs, epoch_steps, "" if budgeted else " (whole epochs)")


def _fit_quietly(trainer: L.Trainer, module: BeliefModule, train_loader: Any, val_loader: Any,
                 ckpt_path: Path | None) -> None:
    """`trainer.fit` without the warnings that say what this module already says."""
    with warnings.catch_warnings():
        # the run folder holds config.yaml (and, resuming, more)
        warnings.filterwarnings("ignore", message=r".*exists and is not empty")
        # no validation data: said when the loaders are made
        warnings.filterwarnings("ignore", message=r".*no `val_dataloader`")
        # Lightning 2.6 on torch 2.13, not ours to fix
        warnings.filterwarnings("ignore", message=r".*LeafSpec.*is deprecated")
        with _ctrl_c_interrupts(trainer):
            trainer.fit(module, train_loader, val_loader, ckpt_path=ckpt_path)


@contextmanager
def _ctrl_c_interrupts(trainer: L.Trainer) -> Iterator[None]:
    """Ctrl-C stays a `KeyboardInterrupt` (the command says "interrupted", exit 130):
    Lightning catches it, shuts the run down, exits 1 (`SystemExit`) and ignores Ctrl-C from
    then on; the earlier handler is put back."""
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGINT) if main_thread else None
    try:
        yield
    except SystemExit as exc:
        if trainer.interrupted and exc.code == LIGHTNING_INTERRUPT_EXIT:
            raise KeyboardInterrupt from None
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def run_training(config: TrainConfig, run_dir: str | Path, resume: str | Path | None = None,
                 callbacks: SequenceOf[Callback] = ()) -> TrainResult:
    """Train `config` into `run_dir` (created if needed).

    Every input is checked before the run folder is created: the data folders, their frames
    and image files (`check_image_files`), the checkpoint resumed from or started from and the
    folder itself. An input error found once training runs (an image corrupt inside its data)
    removes the folder again when this run created it and had not yet written a checkpoint.

    Args:
        config: the recipe (data folders in `data.train` / `data.val`).
        run_dir: the run folder; its `last.ckpt`, when present, is resumed from.
        resume: resume from this checkpoint instead (any path).
        callbacks: extra Lightning callbacks (e.g. a held-out evaluation).
    """
    run_dir = Path(run_dir)
    _check_run_dir(run_dir)
    torch.set_num_threads(config.trainer.threads)
    L.seed_everything(config.trainer.seed, workers=True, verbose=False)
    train_sequences = read_folders(config.data.train)
    val_sequences = read_folders(config.data.val) if config.data.val else []
    config = resolve_from_data(config, train_sequences)
    last_path = run_dir / f"{LAST}{CHECKPOINT_SUFFIX}"
    ckpt_path = Path(resume) if resume is not None else (last_path if last_path.exists() else None)
    if ckpt_path is not None:
        saved = _check_resumable(config, ckpt_path)
        logger.info("resuming from %s", ckpt_path)
        config = _as_started(config, saved)
    elif config.trainer.init_from is not None:
        _check_init_source(config)
    config = with_steps_trained(resolve_precision(config), None)   # recorded when it ends
    train_set, val_set = make_datasets(config, train_sequences, val_sequences)
    check_image_files(train_set, val_set)
    train_loader = make_loader(train_set, config, shuffle=True)
    val_loader = make_loader(val_set, config, shuffle=False) if len(val_set) else None
    if val_loader is None:
        logger.info("no validation data (set data.val, or data.val_fraction for more frames): "
                    "no validation metrics, best.ckpt follows %s", _FALLBACK_MONITOR)
    checkpointed = Checkpointed()
    trainer, best = _trainer(config, run_dir, val_loader is not None,
                             [checkpointed, *callbacks])
    budgeted = config.trainer.time_budget_minutes is not None
    speed, step_cap = None, None
    if budgeted and ckpt_path is None:
        step_cap = _step_cap(config, len(train_set))
        config, speed = _fit_time_budget(config, trainer, train_loader, val_loader)
    module = BeliefModule(config)
    if config.trainer.init_from is not None and ckpt_path is None:
        _init_weights(module, config, train_set)
    created = _make_run_dir(run_dir)
    try:
        write_bytes_atomic(run_dir / CONFIG_FILE, dump_config(config).encode("utf-8"),
                           durable=False)
        if config.trainer.max_steps is not None:
            _plan_steps(trainer, config, len(train_set), len(val_set), speed, step_cap)
        _fit_quietly(trainer, module, train_loader, val_loader, ckpt_path)
    except InputError as exc:
        if created is not None and not checkpointed.saved and trainer.is_global_zero:
            shutil.rmtree(created, ignore_errors=True)  # nothing of this run worth keeping
        error = _unwrap_worker_error(exc)
        if error is exc:
            raise
        raise error from None
    config = with_steps_trained(module.config, trainer.global_step)   # the plan as revised
    write_bytes_atomic(run_dir / CONFIG_FILE, dump_config(config).encode("utf-8"), durable=False)
    metrics = {k.removesuffix("_epoch"): scalar(v) for k, v in trainer.callback_metrics.items()
               if not k.endswith("_step")}
    best_path = Path(best.best_model_path) if best.best_model_path else last_path
    return TrainResult(run_dir, last_path, best_path, config, metrics, trainer.current_epoch)
