"""Checkpoints that carry their config (nanoGPT style): the network is rebuilt from the file alone.

A checkpoint is Lightning's (`state_dict` with `model.`-prefixed weights, optimiser and loop
state for resuming) plus `CHECKPOINT_KEY`: a plain dict (strings, numbers, lists; loadable with
`torch.load(weights_only=True)`) holding the resolved config, the keypoint names, the robot and
the preprocessing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from dream.errors import InputError
from train.config import TrainConfig, config_from_dict
from train.model import BeliefNet, build_model

CHECKPOINT_KEY = "dream"
FORMAT_VERSION = 1
_MODEL_PREFIX = "model."


def checkpoint_payload(config: TrainConfig) -> dict[str, Any]:
    """What a checkpoint stores besides the weights."""
    return {"format_version": FORMAT_VERSION, "config": config.to_dict(),
            "keypoint_names": list(config.data.keypoints or ()), "robot": config.data.robot,
            "preprocess": config.input.to_dict(), "output_stride": config.model.output_stride}


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The raw checkpoint dict (on the CPU), checked to be one of ours."""
    path = Path(path)
    if not path.is_file():
        raise InputError("checkpoint not found", path, "give the .ckpt written by dream train")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, OSError, ValueError, EOFError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"cannot read the checkpoint ({first})", path,
                         "give a complete .ckpt written by dream train") from None
    if not isinstance(ckpt, dict) or CHECKPOINT_KEY not in ckpt or "state_dict" not in ckpt:
        raise InputError("not a dream train checkpoint (no config inside)", path,
                         "give a .ckpt written by dream train")
    version = ckpt[CHECKPOINT_KEY].get("format_version")
    if version != FORMAT_VERSION:
        raise InputError(f"checkpoint format {version} is not supported (expected "
                         f"{FORMAT_VERSION})", path, "retrain or use a matching version")
    return ckpt


def checkpoint_config(path: str | Path) -> TrainConfig:
    """The resolved config stored in a checkpoint."""
    return config_from_dict(read_checkpoint(path)[CHECKPOINT_KEY]["config"])


def load_checkpoint(path: str | Path) -> tuple[BeliefNet, TrainConfig]:
    """Rebuild the network of a checkpoint, in eval mode on the CPU, and its resolved config.

    The config's `data.keypoints` are the belief maps' keypoint names, `data.robot` the robot and
    `input` the preprocessing (`config.input.transform_for`, `dream.peaks`)."""
    ckpt = read_checkpoint(path)
    config = config_from_dict(ckpt[CHECKPOINT_KEY]["config"])
    model = build_model(config.model)
    state = {k[len(_MODEL_PREFIX):]: v for k, v in ckpt["state_dict"].items()
             if k.startswith(_MODEL_PREFIX)}
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise InputError(f"the weights do not fit the stored config ({str(exc).splitlines()[0]})",
                         path) from None
    model.eval()
    return model, config
