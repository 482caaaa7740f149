"""The model card `dream export` writes beside the ONNX file (`MODEL.md`): what the network is,
what it was trained on and for how long, how it was exported; the metadata inside the file says
the same to the program (`export.runner.ModelMetadata`).

    card_path(Path("model.onnx")) -> Path("model.md")
    model_card(report, checkpoint) -> str
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from train.model_config import RESNET

CARD_SUFFIX = ".md"


def card_path(model: Path) -> Path:
    """The card beside an ONNX file.

    >>> card_path(Path("models/xarm7.onnx")).as_posix()
    'models/xarm7.md'
    """
    return model.with_suffix(CARD_SUFFIX)


def _folders(folders: tuple[str, ...]) -> str:
    return ", ".join(f"`{f}`" for f in folders) if folders else "none"


def _training_lines(config: Any) -> list[str]:
    trainer, data = config.trainer, config.data
    steps = trainer.steps_trained
    planned = trainer.max_steps
    trained = ("not recorded (a checkpoint written before the run ended)" if steps is None
               else f"{steps} optimiser steps" + (f" of {planned} planned" if planned else ""))
    validation = (_folders(data.val) if data.val
                  else f"{data.val_fraction:.0%} of the training frames held out")
    start = (f"the weights of `{trainer.init_from}`" if trainer.init_from
             else _initialisation(config.model))
    return [f"- Trained: {trained}, {data.batch_size} images per step, learning rate "
            f"{config.optim.lr:g} ({config.optim.schedule}), from {start}.",
            f"- Training data: {_folders(data.train)}.",
            f"- Validation: {validation}."]


def _initialisation(model: Any) -> str:
    """Where the network's weights started without `trainer.init_from`: the resnet encoder is
    always trained from scratch (`pretrained` applies to an EfficientNet-Lite only)."""
    if model.encoder != RESNET and model.pretrained:
        return f"the ImageNet weights of {model.encoder} (the decoder from scratch)"
    return "scratch (random initialisation)"


def _zoom_lines(zoom: Any) -> list[str]:
    if zoom is None:
        return []
    return [f"- Detection: a second pass on each frame's cut around its keypoints (margin "
            f"{zoom.margin:g} of their extent, at most {zoom.max_zoom:g} times the whole "
            "image's magnification; `dream.zoom`): twice the network time."]


def model_card(report: Any, checkpoint: str | Path) -> str:
    """The card's text for an `export.onnx_export.ExportReport` of `checkpoint`."""
    meta, config = report.metadata, report.config
    pre = meta.preprocess
    diffs = ", ".join(f"{name} {diff:.2g}" for name, diff in report.max_abs_diff.items())
    peaks = ", ".join(f"{k} {v:g}" for k, v in dataclasses.asdict(meta.peak_params).items()
                      if isinstance(v, (int, float)))
    model = ", ".join(f"{k} {v}" for k, v in dataclasses.asdict(config.model).items()
                      if isinstance(v, (str, int, float, bool))
                      and not (k == "pretrained" and config.model.encoder == RESNET))
    return "\n".join([
        f"# {report.path.name}: keypoint network for `{meta.robot}`", "",
        f"- Robot: `{meta.robot}` (URDF sha256 {meta.urdf_sha256 or 'unknown'}); "
        f"{len(meta.keypoint_names)} keypoints: {', '.join(meta.keypoint_names)}.",
        f"- Input {pre.input_width}x{pre.input_height} ({pre.mode}), belief maps at stride "
        f"{meta.output_stride}, belief sigma {meta.belief_sigma:g} map px.",
        f"- Model: {model}.",
        *_training_lines(config),
        f"- Exported from `{Path(checkpoint)}` (config sha256 {meta.config_sha256}) by "
        f"dream-calib {meta.dream_version}; onnxruntime against torch, max |difference|: "
        f"{diffs}.",
        f"- Peak finder: {peaks}.", *_zoom_lines(meta.zoom), "",
        "Measure it on held-out data before use: `dream eval`, or "
        "`python benchmarks/model_eval.py` (docs/benchmarks.md).", ""])
