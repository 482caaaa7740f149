"""Training configuration: frozen dataclasses, loaded from YAML with dotted command-line overrides.

A recipe (`configs/train/<name>.yaml`) gives any subset of the sections below; everything else
keeps its default. `--set model.base_width=16 --set data.train=[DIR1,DIR2]` overrides one key
(the value is parsed as YAML). An unknown key, a value of the wrong type or an invalid value is an
`InputError` naming the key. The resolved config (with the keypoints, robot and number of
keypoints taken from the data) is written beside the checkpoints and stored inside them.

Sections: `model` (`ModelConfig`), `input` (`dream.preprocess.Preprocess`), `data`, `augment`,
`optim`, `loss`, `trainer`, `eval` (with `eval.peaks`: `dream.peaks.PeakSettings`).

Multi-GPU and multi-node training is Lightning's DDP, switched by config only:
`trainer.accelerator=gpu trainer.devices=4 trainer.strategy=ddp trainer.num_nodes=2`
(launch one process per node with the usual MASTER_ADDR / NODE_RANK environment, or under
SLURM / torchrun, which Lightning detects). `data.batch_size` is per device.
"""

from __future__ import annotations

import dataclasses
import os
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from dream.peaks import PeakSettings
from dream.preprocess import Preprocess
from dream.recipe import load_recipe, plain, recipe_from_dict
from dream.zoom import ZoomSettings
from train.model_config import (  # noqa: F401  (re-exported)
    BELIEF_ACTIVATIONS,
    ENCODERS,
    FREEZE_MODES,
    OUTPUT_STRIDES,
    RESNET,
    SKIP_MODES,
    UPSAMPLE_MODES,
    ModelConfig,
)
from train.model_config import require as _require

BELIEF_LOSSES = ("mse", "focal")
SCHEDULES = ("onecycle", "cosine", "constant")
MONITOR_MODES = ("min", "max")
AUTO_PRECISION = "auto"  # bf16-mixed where the hardware has native bfloat16, else 32-true
PRECISIONS = ("32-true", "bf16-mixed", "16-mixed", AUTO_PRECISION)  # 16-mixed: GPUs only
DEFAULT_INPUT = Preprocess(input_width=256, input_height=192)
MAX_SEED = 2 ** 32 - 1  # numpy's seeds are 32-bit unsigned


def _unit(value: float, key: str) -> None:
    _require(0.0 <= value <= 1.0, key, f"must be a probability in [0, 1], got {value}")


def _ordered_pair(pair: tuple[float, float], key: str, low: float | None = None) -> None:
    _require(pair[0] <= pair[1], key, f"must be (low, high) with low <= high, got {pair}")
    if low is not None:
        _require(pair[0] >= low, key, f"must be >= {low}, got {pair}")


@dataclass(frozen=True)
class DataConfig:
    """Datasets (DREAM-layout folders) and targets.

    Attributes:
        train: training folders. val: validation folders; when empty, `val_fraction` of the
            training frames is held out instead, spread evenly (frame i when
            floor((i + 1) * val_fraction) > floor(i * val_fraction): every n-th frame for
            1/n), in [0, 1); 0: no validation.
        keypoints: keypoint names, in belief-map order; null: the first training set's.
        robot: robot name; null: the first training set's (recorded in checkpoints).
        belief_sigma: Gaussian sigma of the belief targets, map pixels.
        use_masks: train the mask head on frames that have a robot mask.
        batch_size: images per step (per device).
        num_workers: data-loading processes (0: in the training process).
    """

    train: tuple[str, ...] = ()
    val: tuple[str, ...] = ()
    val_fraction: float = 0.1
    keypoints: tuple[str, ...] | None = None
    robot: str | None = None
    belief_sigma: float = 2.0
    use_masks: bool = True
    batch_size: int = 16
    num_workers: int = 1

    def __post_init__(self) -> None:
        _require(0.0 <= self.val_fraction < 1.0, "data.val_fraction", "must be in [0, 1)")
        _require(self.belief_sigma > 0, "data.belief_sigma", "must be > 0 (map pixels)")
        _require(self.batch_size >= 1, "data.batch_size", "must be >= 1")
        _require(self.num_workers >= 0, "data.num_workers", "must be >= 0")
        if self.keypoints is not None:
            _require(len(self.keypoints) >= 1 and len(set(self.keypoints)) == len(self.keypoints),
                     "data.keypoints", "must be distinct names (or null)")


@dataclass(frozen=True)
class AugmentConfig:
    """Image augmentation (albumentations; `train.augment`). `*_p` are probabilities; the
    geometric transform moves the keypoints with the image.

    Attributes:
        enabled: false switches every augmentation off.
        affine_p, scale, translate, rotate_rad: random scale in `scale`, shift up to
            `translate` of the image size, rotation up to +-rotate_rad radians.
        gauss_noise_p, gauss_noise_std: additive noise, std as a fraction of 255.
        iso_noise_p, iso_color_shift, iso_intensity: camera sensor noise.
        brightness_contrast_p, brightness, contrast: +- limits (fractions).
        hue_saturation_p, hue_shift, saturation_shift, value_shift: +- limits (OpenCV units).
        blur_p, blur_limit: box blur, odd kernel sizes.
        motion_blur_p, motion_blur_limit: motion blur, odd kernel sizes (centred).
        jpeg_p, jpeg_quality: JPEG re-compression quality range.
        zoom_p: the share of samples cut around their labelled keypoints instead of the whole
            image (`dream.zoom`); above 0 the exported model carries `zoom_margin` and
            `zoom_max`, and detection looks a second time at each frame's keypoints.
        zoom_margin, zoom_max: the cut's widening (a fraction of the keypoints' extent, every
            side) and its most magnification (times the whole image's), as detection uses them.
        zoom_margin_jitter, zoom_shift: training draws the margin within +- zoom_margin_jitter
            and moves the box's centre up to +- zoom_shift of its size (the first pass's
            keypoints are not the labels).
    """

    enabled: bool = True
    affine_p: float = 0.7
    scale: tuple[float, float] = (0.8, 1.2)
    translate: float = 0.1
    rotate_rad: float = 0.26
    gauss_noise_p: float = 0.3
    gauss_noise_std: tuple[float, float] = (0.01, 0.06)
    iso_noise_p: float = 0.2
    iso_color_shift: tuple[float, float] = (0.01, 0.05)
    iso_intensity: tuple[float, float] = (0.1, 0.5)
    brightness_contrast_p: float = 0.5
    brightness: float = 0.25
    contrast: float = 0.25
    hue_saturation_p: float = 0.3
    hue_shift: float = 10.0
    saturation_shift: float = 20.0
    value_shift: float = 10.0
    blur_p: float = 0.1
    blur_limit: tuple[int, int] = (3, 5)
    motion_blur_p: float = 0.1
    motion_blur_limit: tuple[int, int] = (3, 7)
    jpeg_p: float = 0.3
    jpeg_quality: tuple[int, int] = (40, 95)
    zoom_p: float = 0.0
    zoom_margin: float = 0.25
    zoom_max: float = 4.0
    zoom_margin_jitter: float = 0.1
    zoom_shift: float = 0.1

    def zoom_settings(self) -> ZoomSettings | None:
        """The cut detection makes where this recipe trains on cuts (`zoom_p` > 0), else
        None."""
        if not self.enabled or self.zoom_p <= 0:
            return None
        return ZoomSettings(self.zoom_margin, self.zoom_max)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name.endswith("_p"):
                _unit(getattr(self, f.name), f"augment.{f.name}")
        _ordered_pair(self.scale, "augment.scale", low=0.01)
        _require(0 <= self.translate < 1, "augment.translate", "must be in [0, 1)")
        _ordered_pair(self.gauss_noise_std, "augment.gauss_noise_std", low=0.0)
        _ordered_pair(self.iso_color_shift, "augment.iso_color_shift", low=0.0)
        _ordered_pair(self.iso_intensity, "augment.iso_intensity", low=0.0)
        for name in ("blur_limit", "motion_blur_limit"):
            pair = getattr(self, name)
            _ordered_pair(pair, f"augment.{name}", low=3)
            _require(pair[0] % 2 == 1 and pair[1] % 2 == 1, f"augment.{name}",
                     f"kernel sizes must be odd (centred), got {pair}")
        _ordered_pair(self.jpeg_quality, "augment.jpeg_quality", low=1)
        _require(self.jpeg_quality[1] <= 100, "augment.jpeg_quality", "must be <= 100")
        for name in ("rotate_rad", "brightness", "contrast", "hue_shift", "saturation_shift",
                     "value_shift", "zoom_shift"):
            _require(getattr(self, name) >= 0, f"augment.{name}", "must be >= 0")
        _require(0 <= self.zoom_margin_jitter <= self.zoom_margin, "augment.zoom_margin_jitter",
                 "must be in [0, zoom_margin] (the drawn margin stays >= 0)")
        _require(self.zoom_max > 1, "augment.zoom_max", "must be > 1 (times the whole image's "
                 "magnification)")


@dataclass(frozen=True)
class OptimConfig:
    """AdamW and its learning-rate schedule (per optimiser step).

    Attributes:
        lr: peak learning rate. weight_decay: AdamW's decoupled weight decay.
        schedule: "onecycle" (linear warm-up, cosine down to lr * final_lr_fraction),
            "cosine" (the same without warm-up) or "constant".
        warmup_fraction: part of the steps spent warming up ("onecycle").
        final_lr_fraction: last learning rate / lr.
    """

    lr: float = 2e-3
    weight_decay: float = 1e-4
    schedule: str = "onecycle"
    warmup_fraction: float = 0.05
    final_lr_fraction: float = 0.01

    def __post_init__(self) -> None:
        _require(self.lr > 0, "optim.lr", "must be > 0")
        _require(self.weight_decay >= 0, "optim.weight_decay", "must be >= 0")
        _require(self.schedule in SCHEDULES, "optim.schedule", f"must be one of {SCHEDULES}")
        _require(0 <= self.warmup_fraction < 1, "optim.warmup_fraction", "must be in [0, 1)")
        _require(0 <= self.final_lr_fraction <= 1, "optim.final_lr_fraction",
                 "must be in [0, 1]")


@dataclass(frozen=True)
class LossConfig:
    """loss = belief_weight * belief loss + mask_weight * BCE(mask logits), the mask term
    only over frames with a mask and when the model has a mask head.

    Attributes:
        belief: "mse": per-pixel mean squared error, weighted by `foreground_weight`; "focal":
            per-pixel binary cross-entropy against the Gaussian targets scaled by
            |target - belief|^focal_gamma (the quality focal loss of Generalized Focal Loss, Li
            et al. 2020), summed over each map and averaged over the maps; it needs
            model.belief_activation "sigmoid".
        focal_gamma: exponent of the focal factor (0: plain soft-target cross-entropy).
        belief_weight: weight of the belief loss.
        mask_weight: weight of the per-pixel binary cross-entropy of the robot mask.
        foreground_weight: "mse" only: belief pixels are weighted by
            1 + foreground_weight * target (0: plain MSE, as DREAM).
        foreground_weight_end: when set, the training weight moves geometrically from
            `foreground_weight` at the first step to this at the end of the step budget (a high
            weight pulls the maps out of all-zero early; a low one later penalises the second
            peaks a high one tolerates). Validation and test use this end weight throughout,
            so val/loss stays comparable across the run.
    """

    belief: str = "mse"
    focal_gamma: float = 2.0
    belief_weight: float = 1.0
    mask_weight: float = 0.01
    foreground_weight: float = 0.0
    foreground_weight_end: float | None = None

    def __post_init__(self) -> None:
        _require(self.belief in BELIEF_LOSSES, "loss.belief",
                 f"must be one of {BELIEF_LOSSES}, got {self.belief!r}")
        _require(self.focal_gamma >= 0, "loss.focal_gamma", "must be >= 0")
        _require(self.belief_weight > 0, "loss.belief_weight", "must be > 0")
        _require(self.mask_weight >= 0, "loss.mask_weight", "must be >= 0")
        _require(self.foreground_weight >= 0, "loss.foreground_weight", "must be >= 0")
        if self.belief != "mse":
            _require(self.foreground_weight == 0 and self.foreground_weight_end is None,
                     "loss.foreground_weight", f"weights the mse loss only; with loss.belief="
                     f"{self.belief} leave foreground_weight 0 and foreground_weight_end unset")
        if self.foreground_weight_end is not None:
            _require(self.foreground_weight > 0 and self.foreground_weight_end > 0,
                     "loss.foreground_weight_end",
                     "needs foreground_weight and foreground_weight_end both > 0 (geometric)")


@dataclass(frozen=True)
class TrainerConfig:
    """Lightning Trainer settings (`accelerator`, `devices`, `strategy`, `num_nodes` switch
    GPUs and DDP; see the module docstring).

    Attributes:
        max_epochs: epochs (a resumed run continues up to this).
        max_steps: a budget of optimiser steps, rounded up to whole epochs (so that the run
            ends validated and checkpointed): the run stops after whichever of max_epochs and
            ceil(max_steps / steps per epoch) epochs comes first (null: epochs only). A step
            budget fixes the training time whatever the dataset size; the learning-rate
            schedule spans the run. Under a time budget max_steps is exact instead (below).
        num_threads: torch CPU threads; null: every core of the machine.
        seed: seeds torch, numpy, the augmentation and the shuffling (0 .. 2^32 - 1).
        progress_bar: Lightning's progress bar; false: one logging line every
            `log_every_n_steps` steps and per epoch.
        monitor, monitor_mode: the validation metric that picks `best.ckpt`.
        gradient_clip_val: clip gradient norms to this (null: no clipping).
        checkpoint_every_n_steps: also refresh last.ckpt every N optimiser steps (0: only at
            epoch ends), so a long epoch killed midway loses little.
        init_from: a checkpoint whose network weights start this run (fine-tuning, or a
            longer run with a fresh schedule); its model and input settings must equal this
            config's. Unlike resuming, the epoch count, optimiser and schedule start afresh.
            An exported `.onnx` model (the bundled one, say) works too: its batch norms,
            folded into the convolutions by the export, are split again on training images
            (`train.onnx_init`).
        precision: Lightning's precision: "32-true", or "bf16-mixed" (convolutions in
            bfloat16 under autocast, weights, losses and belief maps in float32; on CPUs with
            AVX512-BF16 or AMX about 1.6x the training speed, on other CPUs about 10x slower),
            or "auto": bf16-mixed where the hardware computes bfloat16 natively, else 32-true
            (`train.budget`; the run's config.yaml and checkpoints hold the value chosen).
        time_budget_minutes: fit the run to this much wall time on this machine: a probe of
            `budget_probe_steps` training steps (and as many validation batches) measures the
            speed, and max_steps becomes the optimiser steps that fit, with their validations,
            in what the probe left of the budget (at least one; within max_epochs and a
            max_steps given too). The last epoch may be partial: the run ends validated and
            checkpointed at that step, or at the deadline should the machine run slower than
            the probe (`train.budget.BudgetStop`). The plan follows the rate measured during
            the run, the learning-rate schedule re-planned from the rate it has reached (never
            rising after its peak; `train.schedule`). Null: max_steps and max_epochs alone.
            The run's config.yaml (rewritten when the run ends) and checkpoints hold the
            plan as last revised, with `steps_trained`; a resumed run keeps the plan, and the
            time already spent.
        budget_probe_steps: timed steps of that probe.
        steps_trained: recorded by the run, not read: the optimiser steps trained when its
            checkpoint or config.yaml was written (config.yaml: when the run ended; null while
            it runs). Under a time budget it can fall short of max_steps (the deadline).
        channels_last: keep the network and its input batches in NHWC memory order (faster
            oneDNN convolutions on CPU; checkpoints and ONNX files are unaffected).
    """

    max_epochs: int = 10
    max_steps: int | None = None
    accelerator: str = "auto"
    devices: int | str = "auto"
    strategy: str = "auto"
    num_nodes: int = 1
    precision: str = "32-true"
    num_threads: int | None = None
    seed: int = 0
    log_every_n_steps: int = 10
    val_every_n_epochs: int = 1
    progress_bar: bool = True
    monitor: str = "val/loss"
    monitor_mode: str = "min"
    gradient_clip_val: float | None = 1.0
    checkpoint_every_n_steps: int = 0
    init_from: str | None = None
    channels_last: bool = False
    time_budget_minutes: float | None = None
    budget_probe_steps: int = 20
    steps_trained: int | None = None

    def __post_init__(self) -> None:
        _require(self.precision in PRECISIONS, "trainer.precision",
                 f"must be one of {PRECISIONS}")
        _require(self.max_epochs >= 1, "trainer.max_epochs", "must be >= 1")
        _require(0 <= self.seed <= MAX_SEED, "trainer.seed",
                 f"must be an integer in [0, {MAX_SEED}], got {self.seed}")
        if self.max_steps is not None:
            _require(self.max_steps >= 1, "trainer.max_steps", "must be >= 1 or null")
        _require(self.num_nodes >= 1, "trainer.num_nodes", "must be >= 1")
        if self.num_threads is not None:
            _require(self.num_threads >= 1, "trainer.num_threads", "must be >= 1 or null")
        _require(self.log_every_n_steps >= 1, "trainer.log_every_n_steps", "must be >= 1")
        _require(self.val_every_n_epochs >= 1, "trainer.val_every_n_epochs", "must be >= 1")
        _require(self.monitor_mode in MONITOR_MODES, "trainer.monitor_mode",
                 f"must be one of {MONITOR_MODES}")
        _require(self.checkpoint_every_n_steps >= 0, "trainer.checkpoint_every_n_steps",
                 "must be >= 0")
        if self.gradient_clip_val is not None:
            _require(self.gradient_clip_val > 0, "trainer.gradient_clip_val", "must be > 0")
        if self.time_budget_minutes is not None:
            _require(self.time_budget_minutes > 0, "trainer.time_budget_minutes",
                     "must be > 0 or null")
        _require(self.budget_probe_steps >= 1, "trainer.budget_probe_steps", "must be >= 1")
        if self.steps_trained is not None:
            _require(self.steps_trained >= 0, "trainer.steps_trained", "must be >= 0 or null")

    @property
    def threads(self) -> int:
        return self.num_threads or os.cpu_count() or 1


@dataclass(frozen=True)
class EvalConfig:
    """Validation metrics: keypoints through the real peak finder, errors in input pixels.

    Attributes:
        peaks: the peak finder's parameters (`dream.peaks.PeakSettings`).
        pck_threshold_px: PCK counts a keypoint correct within this many input pixels.
    """

    peaks: PeakSettings = field(default_factory=PeakSettings)
    pck_threshold_px: float = 5.0

    def __post_init__(self) -> None:
        _require(self.pck_threshold_px > 0, "eval.pck_threshold_px", "must be > 0")


@dataclass(frozen=True)
class TrainConfig:
    """Everything a training run needs; stored in its checkpoints (nanoGPT style)."""

    model: ModelConfig = field(default_factory=ModelConfig)
    input: Preprocess = DEFAULT_INPUT
    data: DataConfig = field(default_factory=DataConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    trainer: TrainerConfig = field(default_factory=TrainerConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def __post_init__(self) -> None:
        n = self.model.network_stride
        _require(self.input.input_width % n == 0 and self.input.input_height % n == 0,
                 "input", f"input size {self.input.input_width}x{self.input.input_height} must "
                 f"be a multiple of the network stride {n} (model.network_stride)")
        if self.data.keypoints is not None and self.model.num_keypoints is not None:
            _require(len(self.data.keypoints) == self.model.num_keypoints, "model.num_keypoints",
                     f"is {self.model.num_keypoints} but data.keypoints names "
                     f"{len(self.data.keypoints)}")
        if self.loss.belief == "focal":
            _require(self.model.belief_activation == "sigmoid", "loss.belief",
                     "focal needs maps in (0, 1): set model.belief_activation=sigmoid")

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (lists, numbers, strings, None): YAML/JSON/checkpoint-safe."""
        return plain(dataclasses.asdict(self))

    def replace(self, **sections: Any) -> TrainConfig:
        return dataclasses.replace(self, **sections)


def config_from_dict(doc: dict[str, Any], base: TrainConfig | None = None) -> TrainConfig:
    """A `TrainConfig` from a (partial) nested dict over `base` (default: the defaults)."""
    return recipe_from_dict(TrainConfig, doc, base)


def load_config(path: str | Path | None, overrides: typing.Sequence[str] = ()) -> TrainConfig:
    """The recipe at `path` (YAML; None: the defaults) with `KEY=VALUE` overrides applied."""
    return load_recipe(TrainConfig, path, overrides,
                       "a YAML recipe, e.g. configs/train/tiny.yaml")


def dump_config(config: TrainConfig) -> str:
    """YAML text of the resolved config (loads back with `load_config`)."""
    return yaml.safe_dump(config.to_dict(), sort_keys=False, default_flow_style=None)
