"""Checkpoints that carry their config (nanoGPT style): the network is rebuilt from the file alone.

A checkpoint is Lightning's (`state_dict` with `model.`-prefixed weights, optimiser and loop
state for resuming) plus `CHECKPOINT_KEY`: a plain dict (strings, numbers, lists; loadable with
`torch.load(weights_only=True)`) holding the resolved config, the keypoint names, the robot and
the preprocessing.
"""

from __future__ import annotations

import pickle
import struct
import warnings
import zipfile
from pathlib import Path
from typing import Any

import torch

from dream.errors import InputError
from train.config import TrainConfig, config_from_dict
from train.model import BeliefNet, build_model

CHECKPOINT_KEY = "dream"
FORMAT_VERSION = 1
_MODEL_PREFIX = "model."
_FIX_CHECKPOINT = "give a complete .ckpt written by dream train"
# What torch.load raises on a file that is not a (complete) checkpoint: a truncated or foreign
# zip, bytes that are no pickle, or a pickle the weights-only loader refuses or chokes on.
_LOAD_ERRORS = (zipfile.BadZipFile, struct.error, RuntimeError, OSError,
                ValueError, EOFError, KeyError, IndexError, AttributeError, TypeError)


def checkpoint_payload(config: TrainConfig) -> dict[str, Any]:
    """What a checkpoint stores besides the weights."""
    return {"format_version": FORMAT_VERSION, "config": config.to_dict(),
            "keypoint_names": list(config.data.keypoints or ()), "robot": config.data.robot,
            "preprocess": config.input.to_dict(), "output_stride": config.model.output_stride}


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The raw checkpoint dict (on the CPU), checked to be one of ours: a missing, truncated,
    corrupt or foreign file is an `InputError` naming it."""
    path = Path(path)
    if not path.is_file():
        raise InputError("checkpoint not found", path, "give the .ckpt written by dream train")
    try:
        with warnings.catch_warnings():  # a corrupt pickle: "Detected pickle protocol ..."
            warnings.simplefilter("ignore")
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise InputError("cannot read the checkpoint (not a PyTorch checkpoint, or a corrupt "
                         "one)", path, _FIX_CHECKPOINT) from None
    except _LOAD_ERRORS as exc:
        text = str(exc).strip()
        first = text.splitlines()[0] if text and not isinstance(exc, KeyError) else ""
        why = first or type(exc).__name__
        raise InputError(f"cannot read the checkpoint ({why})", path, _FIX_CHECKPOINT) from None
    if (not isinstance(ckpt, dict) or not isinstance(ckpt.get(CHECKPOINT_KEY), dict)
            or not isinstance(ckpt.get("state_dict"), dict)):
        raise InputError("not a dream train checkpoint (no config inside)", path,
                         "give a .ckpt written by dream train")
    version = ckpt[CHECKPOINT_KEY].get("format_version")
    if version != FORMAT_VERSION:
        raise InputError(f"checkpoint format {version} is not supported (expected "
                         f"{FORMAT_VERSION})", path, "retrain or use a matching version")
    return ckpt


def _stored_config(ckpt: dict[str, Any], path: Path) -> TrainConfig:
    """The config inside a checkpoint read by `read_checkpoint`; a damaged one names the file."""
    doc = ckpt[CHECKPOINT_KEY].get("config")
    if not isinstance(doc, dict):
        raise InputError("the checkpoint holds no config", path, _FIX_CHECKPOINT)
    try:
        return config_from_dict(doc)
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(f"the checkpoint's config is invalid ({exc.problem.rstrip('.')})", path,
                         _FIX_CHECKPOINT) from None


def checkpoint_config(path: str | Path) -> TrainConfig:
    """The resolved config stored in a checkpoint."""
    return _stored_config(read_checkpoint(path), Path(path))


def load_checkpoint(path: str | Path) -> tuple[BeliefNet, TrainConfig]:
    """Rebuild the network of a checkpoint, in eval mode on the CPU, and its resolved config.

    The config's `data.keypoints` are the belief maps' keypoint names, `data.robot` the robot and
    `input` the preprocessing (`config.input.transform_for`, `dream.peaks`)."""
    ckpt = read_checkpoint(path)
    config = _stored_config(ckpt, Path(path))
    model = build_model(config.model, load_weights=False)   # the checkpoint's weights follow
    state = {k[len(_MODEL_PREFIX):]: v for k, v in ckpt["state_dict"].items()
             if k.startswith(_MODEL_PREFIX)}
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise InputError(f"the weights do not fit the stored config ({str(exc).splitlines()[0]})",
                         path, _FIX_CHECKPOINT) from None
    model.eval()
    return model, config
