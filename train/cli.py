"""`dream train`: registered through the `dream.commands` entry point; imports torch only when run.

    dream train --config configs/train/tiny.yaml --set data.train=[DIR1,DIR2] \\
        --set trainer.max_epochs=3 --out RUN_DIR

Writes RUN_DIR/config.yaml, last.ckpt, best.ckpt and metrics.csv; running again into the same
RUN_DIR resumes from its last.ckpt (see `train.run`).
"""

from __future__ import annotations

import argparse
import logging


def cmd_train(args: argparse.Namespace) -> int:
    from train.config import load_config

    config = load_config(args.config, args.set or ())
    logging.getLogger("train").setLevel(logging.INFO)
    from train.run import run_training  # torch and lightning from here on

    result = run_training(config, args.out, resume=args.resume)
    metrics = "  ".join(f"{k} {v:.4g}" for k, v in sorted(result.metrics.items()))
    print(f"trained {result.epochs} epochs: {metrics}")
    print(f"wrote {result.last_checkpoint}, {result.best_checkpoint}, "
          f"{result.run_dir / 'config.yaml'} and {result.run_dir / 'metrics.csv'}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `train` command to `dream`'s sub-commands."""
    help_ = "train the keypoint belief-map network on DREAM-layout folders"
    p = subparsers.add_parser("train", help=help_, description=help_)
    p.add_argument("--config", required=True,
                   help="YAML recipe, e.g. configs/train/panda_cpu.yaml")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a config key (repeatable), e.g. trainer.max_epochs=3 or "
                        "data.train=[DIR1,DIR2]; trainer.max_steps is rounded up to whole "
                        "epochs (exact under trainer.time_budget_minutes); the keys and their "
                        "meaning: train/config.py")
    p.add_argument("--out", required=True,
                   help="run folder (checkpoints, config.yaml, metrics.csv); resumed from its "
                        "last.ckpt when present")
    p.add_argument("--resume", help="resume from this checkpoint instead of RUN_DIR/last.ckpt")
    p.set_defaults(func=cmd_train)
