"""Learning curve of a training recipe: held-out keypoint error against wall time.

Trains a recipe (default `configs/train/panda_cpu.yaml`) on TRAIN_DIR and, every
`--eval-every-s` seconds of training, runs the network on (a subset of) HELDOUT_DIR through the
real peak finder, printing one table row: training wall time (evaluation excluded), epoch, step,
images seen, training loss, median / mean keypoint error (px at the network input resolution,
found keypoints only), PCK@`eval.pck_threshold_px` and the detection rate over the held-out
keypoints inside the input frame. Both folders are any DREAM-layout datasets with images and
labels (e.g. written by `dream synth`). A recipe's time budget (`trainer.time_budget_minutes`)
leaves these evaluations out, like the training time of the table.

    python benchmarks/train_curve.py TRAIN_DIR HELDOUT_DIR [--out RUN_DIR] [--minutes 45]
        [--eval-every-s 300] [--eval-frames 200] [--config YAML] [--set KEY=VALUE ...]

Besides the table, RUN_DIR/curve.json holds the rows and the final figures (images_per_s
included; `benchmarks/gpu_finetune.sh` reads its probe's speed there).
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from lightning.pytorch.callbacks import Callback

from dream.errors import DreamError
from dream.io import write_json_atomic
from train.budget import BudgetStop
from train.config import load_config
from train.data import KeypointDataset, read_folders
from train.metrics import keypoint_errors, summarize
from train.run import run_training

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = REPO / "configs" / "train" / "panda_cpu.yaml"
CURVE_FILE = "curve.json"    # in the run folder: the rows and the final figures, for scripts
HEADER = (f"{'train_s':>8} {'epoch':>5} {'step':>6} {'images':>7} {'loss':>9} "
          f"{'median_px':>9} {'mean_px':>8} {'pck':>6} {'found':>6}")


class HeldOutCurve(Callback):
    """Evaluates on held-out frames every `every_s` seconds of training (and at both ends);
    stops the run after `budget_s` seconds of training."""

    def __init__(self, heldout: Path, every_s: float, max_frames: int, budget_s: float | None,
                 batch_size: int):
        self.heldout, self.every_s, self.max_frames = heldout, every_s, max_frames
        self.budget_s, self.batch_size = budget_s, batch_size
        self.rows: list[dict[str, float]] = []
        self._train_s = 0.0
        self._last_eval = -np.inf
        self._tick = time.perf_counter()
        self._images = 0
        self._dataset: KeypointDataset | None = None

    def on_train_start(self, trainer, pl_module) -> None:
        config = pl_module.config
        seqs = read_folders([str(self.heldout)])
        dataset = KeypointDataset(seqs, config.data.keypoints, config.input,
                                  config.model.output_stride, config.data.belief_sigma,
                                  augment=None, use_masks=False)
        keep = np.zeros(len(dataset), bool)
        keep[np.unique(np.linspace(0, len(dataset) - 1, min(self.max_frames, len(dataset))
                                   ).round().astype(int))] = True
        self._dataset = KeypointDataset(seqs, config.data.keypoints, config.input,
                                        config.model.output_stride, config.data.belief_sigma,
                                        augment=None, use_masks=False, frame_filter=keep)
        print(f"held-out: {len(self._dataset)} of {len(dataset)} frames of {self.heldout}")
        print(HEADER, flush=True)
        self._evaluate(trainer, pl_module)
        self._tick = time.perf_counter()

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        self._tick = time.perf_counter()  # validation and checkpoints are not training time

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        now = time.perf_counter()
        self._train_s += now - self._tick
        self._images += int(batch["image"].shape[0])
        if self._train_s - self._last_eval >= self.every_s:
            self._evaluate(trainer, pl_module)
        if self.budget_s is not None and self._train_s >= self.budget_s:
            trainer.should_stop = True
        self._tick = time.perf_counter()

    def on_train_end(self, trainer, pl_module) -> None:
        if not self.rows or self.rows[-1]["step"] != trainer.global_step:
            self._evaluate(trainer, pl_module)

    def _evaluate(self, trainer, pl_module) -> None:
        start = time.perf_counter()
        self._evaluate_now(trainer, pl_module)
        for callback in trainer.callbacks:  # the recipe's time budget is for training
            if isinstance(callback, BudgetStop):
                callback.exclude(time.perf_counter() - start)

    def _evaluate_now(self, trainer, pl_module) -> None:
        config = pl_module.config
        model = pl_module.model
        was_training = model.training
        model.eval()
        results = []
        with torch.no_grad():
            for start in range(0, len(self._dataset), self.batch_size):
                items = [self._dataset[i] for i in range(start, min(start + self.batch_size,
                                                                    len(self._dataset)))]
                x = torch.stack([it["image"] for it in items]).to(pl_module.device)
                uv = np.stack([it["uv_input"].numpy() for it in items])
                belief = model(x).belief.float().cpu().numpy()
                results.append(keypoint_errors(belief, uv, config.model.output_stride,
                                               config.input.input_width,
                                               config.input.input_height, config.eval.peaks))
        model.train(was_training)
        summary = summarize(results, config.eval.pck_threshold_px)
        loss = trainer.callback_metrics.get("train/loss_step")
        row = {"train_s": self._train_s, "epoch": trainer.current_epoch,
               "step": trainer.global_step, "images": self._images,
               "loss": float("nan") if loss is None else float(loss), **summary}
        self.rows.append(row)
        self._last_eval = self._train_s
        print(f"{row['train_s']:8.0f} {row['epoch']:5d} {row['step']:6d} {row['images']:7d} "
              f"{row['loss']:9.5f} {row['l2_median_px']:9.2f} {row['l2_mean_px']:8.2f} "
              f"{row['pck']:6.3f} {row['found_rate']:6.3f}", flush=True)


def _json_row(row: dict) -> dict:
    """A curve row for JSON: non-finite values (a loss not logged yet, a metric without any
    found keypoint) as null."""
    return {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in row.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("train_dir", type=Path, help="training set (DREAM layout)")
    parser.add_argument("heldout_dir", type=Path, help="held-out set (DREAM layout)")
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, help="run folder (default: a new temporary folder)")
    parser.add_argument("--minutes", type=float, help="stop training after this many minutes")
    parser.add_argument("--eval-every-s", type=float, default=300.0)
    parser.add_argument("--eval-frames", type=int, default=200)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("train").setLevel(logging.INFO)
    try:
        config = load_config(args.config, [f"data.train=[{args.train_dir}]", *args.set])
        out = args.out or Path(tempfile.mkdtemp(prefix="train-curve-"))
        curve = HeldOutCurve(args.heldout_dir, args.eval_every_s, args.eval_frames,
                             None if args.minutes is None else 60 * args.minutes,
                             config.data.batch_size)
        print(f"recipe {args.config} -> {out}; {config.trainer.threads} threads")
        result = run_training(config, out, callbacks=[curve])
        last = curve.rows[-1]
        rate = last["images"] / max(last["train_s"], 1e-9)
        write_json_atomic(out / CURVE_FILE, {
            "final": {**_json_row(last), "images_per_s": rate},
            "rows": [_json_row(row) for row in curve.rows],
            "best_checkpoint": str(result.best_checkpoint)})
    except DreamError as exc:
        print(f"train_curve: error: {exc}", file=sys.stderr)
        return 2
    print(f"final: median {last['l2_median_px']:.2f} px, PCK@{config.eval.pck_threshold_px:g}px "
          f"{last['pck']:.3f} after {last['train_s']:.0f} s ({last['images']} images, "
          f"{rate:.1f} images/s); best checkpoint "
          f"{result.best_checkpoint}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
