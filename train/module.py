"""The LightningModule: one shared step for train / val / test, AdamW, warm-up + cosine schedule.

loss = belief_weight * belief loss (weighted MSE or quality focal, `LossConfig.belief`)
       + mask_weight * BCE(mask logits, robot fraction),
the mask term over the samples that have a mask. Validation and test also run the real peak
finder (`dream.peaks`) on the predicted maps and report the keypoint L2 error (median and mean,
input pixels), PCK at `eval.pck_threshold_px` and the detection rate. Under DDP these are averaged
over the ranks (each rank's median, an approximation).

The checkpoint carries the resolved config (keypoint names, robot, preprocessing included) under
`CHECKPOINT_KEY`, so `train.checkpoint.load_checkpoint` rebuilds the network from the file alone.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import lightning as L
import torch
from torch.nn import functional as F

from train.checkpoint import CHECKPOINT_KEY, checkpoint_payload
from train.config import TrainConfig
from train.metrics import KeypointErrors, keypoint_errors, summarize
from train.model import build_model
from train.schedule import LrSchedule, lr_factor  # noqa: F401  (lr_factor re-exported)

TRAIN, VAL, TEST = "train", "val", "test"
_FOCAL_EPS = 1e-4  # belief clamp before the logarithms of the focal loss


def with_steps_trained(config: TrainConfig, steps: int | None) -> TrainConfig:
    """`config` recording `steps` optimiser steps trained (`trainer.steps_trained`; None: not
    recorded, the run has not ended)."""
    return config.replace(trainer=dataclasses.replace(config.trainer, steps_trained=steps))


def foreground_weight_at(step: int, total_steps: int, start: float, end: float | None) -> float:
    """The belief foreground weight at optimiser step `step` of `total_steps`: `start` when
    `end` is None, else geometric from `start` (step 0) to `end` (the last step)."""
    if end is None:
        return start
    progress = min(1.0, max(0.0, step / max(1, total_steps - 1)))
    return start * (end / start) ** progress


def belief_mse(pred: torch.Tensor, target: torch.Tensor, foreground_weight: float) -> torch.Tensor:
    """Mean squared error of belief maps, each pixel weighted by 1 + foreground_weight * target.

    With plain MSE (weight 0) and Gaussians covering ~0.2 % of the map, all-zero maps are a
    strong local minimum; weighting the pixels near keypoints pulls the network out of it.
    """
    if foreground_weight == 0:
        return F.mse_loss(pred, target)
    return torch.mean((1.0 + foreground_weight * target) * (pred - target) ** 2)


def belief_focal(pred: torch.Tensor, target: torch.Tensor, gamma: float) -> torch.Tensor:
    """Quality focal loss of belief maps in (0, 1) against Gaussian targets in [0, 1]:
    BCE(pred, target) * |target - pred|^gamma, summed over each (H, W) map, averaged over the
    N x K maps.

    Unlike the weighted MSE, a confident peak where the target is ~0 costs -log(1 - pred), so a
    second peak on a neighbouring keypoint is penalised as hard as a missed one.
    """
    # float32, written out: CUDA autocast refuses F.binary_cross_entropy on sigmoid outputs
    pred = pred.float().clamp(_FOCAL_EPS, 1 - _FOCAL_EPS)
    target = target.float()
    bce = -(target * torch.log(pred) + (1 - target) * torch.log1p(-pred))
    per_pixel = bce * (target - pred).abs().pow(gamma) if gamma > 0 else bce
    return per_pixel.sum(dim=(-2, -1)).mean()


class BeliefModule(L.LightningModule):
    """Training wrapper of `train.model.BeliefNet` for a resolved `TrainConfig` (keypoints and
    num_keypoints set)."""

    def __init__(self, config: TrainConfig):
        super().__init__()
        self.config = config
        self.model = build_model(config.model)
        self._results: dict[str, list[KeypointErrors]] = {VAL: [], TEST: []}
        self._lr_schedule: LrSchedule | None = None   # made with the optimiser

    def forward(self, image: torch.Tensor):
        return self.model(image)

    def setup(self, stage: str) -> None:
        if self.config.trainer.channels_last:
            self.model.to(memory_format=torch.channels_last)

    def _step(self, batch: dict[str, torch.Tensor], stage: str) -> torch.Tensor:
        """The one step of every stage: loss, and keypoint errors outside training."""
        image = batch["image"]
        if self.config.trainer.channels_last:
            image = image.contiguous(memory_format=torch.channels_last)
        out = self.model(image)
        weights = self.config.loss
        if weights.belief == "focal":
            belief_loss = belief_focal(out.belief, batch["belief"], weights.focal_gamma)
        else:
            belief_loss = belief_mse(out.belief, batch["belief"], self._foreground_weight(stage))
        loss = weights.belief_weight * belief_loss
        n = batch["image"].shape[0]
        has_mask = batch["has_mask"]
        if out.mask is not None and weights.mask_weight > 0 and bool(has_mask.any()):
            mask_loss = F.binary_cross_entropy_with_logits(out.mask[has_mask],
                                                           batch["mask"][has_mask])
            loss = loss + weights.mask_weight * mask_loss
            self.log(f"{stage}/mask_bce", mask_loss, on_step=False, on_epoch=True, batch_size=n,
                     sync_dist=stage != TRAIN)
        on_step = stage == TRAIN
        self.log(f"{stage}/belief_{weights.belief}", belief_loss, on_step=False, on_epoch=True,
                 batch_size=n, sync_dist=stage != TRAIN)
        self.log(f"{stage}/loss", loss, on_step=on_step, on_epoch=True, prog_bar=True,
                 batch_size=n, sync_dist=stage != TRAIN)
        if stage != TRAIN:
            pre = self.config.input
            self._results[stage].append(keypoint_errors(
                out.belief.detach().float().cpu().numpy(), batch["uv_input"].cpu().numpy(),
                self.config.model.output_stride, pre.input_width, pre.input_height,
                self.config.eval.peaks))
        return loss

    def _foreground_weight(self, stage: str) -> float:
        loss = self.config.loss
        if loss.foreground_weight_end is None:
            return loss.foreground_weight
        if stage != TRAIN:
            return loss.foreground_weight_end
        weight = foreground_weight_at(self.global_step,
                                      int(self.trainer.estimated_stepping_batches),
                                      loss.foreground_weight, loss.foreground_weight_end)
        self.log("train/foreground_weight", weight, on_step=True, on_epoch=False)
        return weight

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        return self._step(batch, TRAIN)

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        return self._step(batch, VAL)

    def test_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        return self._step(batch, TEST)

    def _log_keypoint_metrics(self, stage: str) -> None:
        summary = summarize(self._results[stage], self.config.eval.pck_threshold_px)
        self._results[stage] = []
        pck = f"{stage}/pck@{self.config.eval.pck_threshold_px:g}px"
        self.log_dict({f"{stage}/l2_median_px": summary["l2_median_px"],
                       f"{stage}/l2_mean_px": summary["l2_mean_px"], pck: summary["pck"],
                       f"{stage}/found_rate": summary["found_rate"]}, sync_dist=True,
                      prog_bar=False)

    def on_validation_epoch_end(self) -> None:
        self._log_keypoint_metrics(VAL)

    def on_test_epoch_end(self) -> None:
        self._log_keypoint_metrics(TEST)

    def configure_optimizers(self) -> dict[str, Any]:
        optim = self.config.optim
        decay, no_decay = [], []
        for param in self.model.parameters():  # no weight decay on biases and norms
            (decay if param.ndim >= 2 else no_decay).append(param)
        optimizer = torch.optim.AdamW([{"params": decay, "weight_decay": optim.weight_decay},
                                       {"params": no_decay, "weight_decay": 0.0}], lr=optim.lr)
        self._lr_schedule = LrSchedule(max(1, int(self.trainer.estimated_stepping_batches)),
                                       optim.schedule, optim.warmup_fraction,
                                       optim.final_lr_fraction)
        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, self._lr_schedule)
        return {"optimizer": optimizer,
                "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}

    def replan(self, total_steps: int) -> None:
        """The run's step plan revised at the current step (`train.budget.BudgetStop`): the
        learning-rate schedule re-plans the steps from here to `total_steps` from the rate it
        has reached (`train.schedule`: after the peak it never rises), and checkpoints record
        the new plan."""
        total_steps = max(1, int(total_steps))
        if self._lr_schedule is not None:
            self._lr_schedule.revise(self.global_step, total_steps)
        self.config = self.config.replace(trainer=dataclasses.replace(
            self.config.trainer, max_steps=total_steps))

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """The checkpoint records the config with the current step plan (`trainer.max_steps`,
        as a time budget last revised it) and the steps trained so far."""
        checkpoint[CHECKPOINT_KEY] = checkpoint_payload(
            with_steps_trained(self.config, int(self.global_step)))
