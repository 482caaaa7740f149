"""Checkpoint -> self-describing ONNX model, checked against torch in onnxruntime.

    from export.onnx_export import export_onnx
    export_onnx("runs/tiny/best.ckpt", "model.onnx")

`KeypointExportWrapper` is the exported module (segment-anything style: the training network is
wrapped, not changed): input `image` (N, 3, H, W) normalised RGB with a dynamic batch axis,
outputs `belief` (N, K, H/s, W/s) and, when the network has a mask head, `mask` (N, 1, H/s, W/s)
logits. The export uses torch's default exporter (`torch.onnx.export(..., dynamo=True)`), as
`tests/test_train.py` checks. The model's description is written into the file as
metadata_props (`export.runner.ModelMetadata`). Before the file appears, onnxruntime runs it on
a random batch of another size than the traced one and every output must match torch within
`PARITY_ATOL` (absolute); otherwise nothing is written and an `InputError` says so.

Opsets: the exporter builds the graph in torchlib's opset (18) and converts it with onnxscript's
version converter to the opset asked for (default 20 with torch 2.13); that converter supports
18-25 with onnxscript 0.7 (`supported_opsets`). For any other opset it falls back to onnx's C
converter, which on failure logs a traceback and leaves the model at 18 without raising. So
another `opset` is refused before the export, and the written model's opset is checked
against the one asked for.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import secrets
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from dream import __version__
from dream.detection import BELIEF_OUTPUT, MASK_OUTPUT
from dream.errors import InputError
from dream.io import check_output_file
from dream.io.fields import one_line, os_reason
from dream.peaks import PeakSettings, peak_params_from_overrides
from dream.robot.identity import robot_urdf_sha256
from export.runner import INPUT_NAME, ModelMetadata, OnnxKeypointModel
from train.checkpoint import load_checkpoint
from train.config import TrainConfig
from train.model import BeliefNet

log = logging.getLogger(__name__)

ONNX_SUFFIX = ".onnx"
PARITY_ATOL = 1e-4        # largest absolute difference onnxruntime vs torch, belief scale
TRACE_BATCH = 2           # batch of the traced example (not 0 or 1: those would be specialised)
PARITY_BATCH = 3          # batch of the parity check (another size: the axis must be dynamic)
PARITY_SEED = 0
BATCH_AXIS = "batch"
_EXPORTER_LOGGERS = ("torch.onnx._internal.exporter._registration",)
_TOKEN_BYTES = 4
# node annotations of the exporter (source file paths, FX node names, rewrite rules): debugging
# aids that would put the building machine's paths into a shipped file
EXPORTER_NODE_PROPS = ("pkg.torch.onnx.", "pkg.onnxscript.")
# (lowest, highest) opset of onnxscript's version converter, used when its private constants
# cannot be read (the values of onnxscript 0.7 with torch 2.13)
OPSET_RANGE_FALLBACK = (18, 25)
ONNX_DOMAINS = ("", "ai.onnx")   # the default operator set's names in opset_import


class KeypointExportWrapper(nn.Module):
    """The exported graph: a `BeliefNet` returning named tensors instead of a NamedTuple.

    `forward(image)` -> (belief,) or (belief, mask), in the order of `output_names`.
    """

    def __init__(self, net: BeliefNet):
        super().__init__()
        self.net = net
        self.output_names = (BELIEF_OUTPUT, MASK_OUTPUT) if net.mask_head is not None \
            else (BELIEF_OUTPUT,)

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = self.net(image)
        return (out.belief, out.mask) if out.mask is not None else (out.belief,)


@dataclass(frozen=True)
class ExportReport:
    """What `export_model` wrote.

    Attributes:
        path: the .onnx file.
        metadata: the description stored in it.
        output_names: the graph's outputs, in order.
        max_abs_diff: per output, the largest |onnxruntime - torch| on the parity batch.
        config: the checkpoint's resolved training config (for the model card).
    """

    path: Path
    metadata: ModelMetadata
    output_names: tuple[str, ...]
    max_abs_diff: dict[str, float]
    config: TrainConfig


def config_sha256(config: TrainConfig) -> str:
    """sha256 (hex digest) of the config's canonical JSON: `config.to_dict()` written by
    `json.dumps` with sorted keys, separators `","` and `":"` (no spaces) and ASCII escapes,
    encoded as UTF-8."""
    text = json.dumps(config.to_dict(), sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def metadata_for(config: TrainConfig, checkpoint: str | Path | None = None) -> ModelMetadata:
    """The ONNX metadata of a checkpoint's resolved config, with the SHA-256 of its robot's URDF
    where that URDF (a built-in robot's, or the path the config names) can be read here."""
    if not config.data.keypoints or not config.data.robot:
        raise InputError("the checkpoint's config names no keypoints or robot", checkpoint,
                         "export a checkpoint written by dream train")
    return ModelMetadata(robot=config.data.robot, keypoint_names=tuple(config.data.keypoints),
                         preprocess=config.input, output_stride=config.model.output_stride,
                         dream_version=__version__, config_sha256=config_sha256(config),
                         belief_sigma=config.data.belief_sigma, peak_params=config.eval.peaks,
                         urdf_sha256=robot_urdf_sha256(config.data.robot),
                         zoom=config.augment.zoom_settings())


@contextmanager
def _quiet_exporter() -> Iterator[None]:
    """Silence the exporter's notes about optional packages (torchvision ops) and torch's
    internal deprecation warnings; errors still raise."""
    loggers = [logging.getLogger(name) for name in _EXPORTER_LOGGERS]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=FutureWarning, module=r"(torch|copyreg)")
            warnings.filterwarnings("ignore", category=DeprecationWarning, module=r"torch")
            yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def supported_opsets() -> tuple[int, int]:
    """(lowest, highest) ONNX opset torch's exporter writes: the range of onnxscript's version
    converter (torch converts its torchlib graph with it), capped at the newest opset the
    installed onnx package knows."""
    low, high = OPSET_RANGE_FALLBACK
    try:
        from onnxscript.version_converter import _version_converter as converter
    except ImportError:
        pass
    else:
        low = int(getattr(converter, "SUPPORTED_MIN_ONNX_OPSET", low))
        high = int(getattr(converter, "SUPPORTED_MAX_ONNX_OPSET", high))
    return low, min(high, onnx.defs.onnx_opset_version())


def check_opset(opset: int | None) -> int | None:
    """`opset` when torch's exporter can write it (None: its default), else an `InputError`."""
    if opset is None:
        return None
    low, high = supported_opsets()
    if isinstance(opset, bool) or not isinstance(opset, int | np.integer) or \
            not low <= opset <= high:
        raise InputError(f"ONNX opset {opset!r} is not supported: torch's exporter writes "
                         f"opsets {low} to {high}",
                         fix=f"give --opset between {low} and {high}, or leave it out")
    return int(opset)


def model_opset(proto: onnx.ModelProto) -> int | None:
    """The version of the default ONNX operator set a model imports (None: none)."""
    versions = [o.version for o in proto.opset_import if o.domain in ONNX_DOMAINS]
    return versions[0] if versions else None


def to_onnx_proto(wrapper: KeypointExportWrapper, width: int, height: int,
                  opset: int | None = None) -> onnx.ModelProto:
    """The wrapper as an ONNX model with a dynamic batch axis (torch's default exporter),
    without the exporter's per-node debugging annotations."""
    example = torch.zeros(TRACE_BATCH, 3, height, width)
    batch = torch.export.Dim(BATCH_AXIS, min=1)
    with _quiet_exporter():
        program = torch.onnx.export(wrapper, (example,), None, input_names=[INPUT_NAME],
                                    output_names=list(wrapper.output_names), dynamo=True,
                                    dynamic_shapes={"image": {0: batch}}, opset_version=opset,
                                    verbose=False)
    proto = program.model_proto
    for node in [*proto.graph.node, *(n for f in proto.functions for n in f.node)]:
        keep = [p for p in node.metadata_props if not p.key.startswith(EXPORTER_NODE_PROPS)]
        del node.metadata_props[:]
        node.metadata_props.extend(keep)
    return proto


def parity(wrapper: KeypointExportWrapper, model: OnnxKeypointModel,
           batch: int = PARITY_BATCH, seed: int = PARITY_SEED) -> dict[str, float]:
    """Per output, the largest |onnxruntime - torch| on a random (batch, 3, H, W) input."""
    pre = model.preprocess
    x = torch.randn(batch, 3, pre.input_height, pre.input_width,
                    generator=torch.Generator().manual_seed(seed))
    with torch.no_grad():
        expected = dict(zip(wrapper.output_names, wrapper(x), strict=True))
    got = model.run(x.numpy())
    if set(got) != set(expected):
        raise InputError(f"the ONNX outputs {sorted(got)} differ from torch's "
                         f"{sorted(expected)}", model.path)
    return {name: float(np.max(np.abs(got[name] - expected[name].numpy())))
            for name in wrapper.output_names}


def _temporary_sibling(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(_TOKEN_BYTES)}")


def export_model(checkpoint: str | Path, out: str | Path, opset: int | None = None,
                 atol: float = PARITY_ATOL, peak_params: PeakSettings | None = None,
                 peak_overrides: Sequence[str] = ()) -> ExportReport:
    """Export a `dream train` checkpoint to `out` (.onnx), checked against torch.

    Args:
        checkpoint: a .ckpt written by `dream train` (it carries its config).
        out: the .onnx file to write (atomically: complete or absent).
        opset: ONNX opset (None: the exporter's default); one outside `supported_opsets()`
            is refused.
        atol: largest absolute difference onnxruntime vs torch accepted, per output.
        peak_params: the peak finder's constants written into the model (None: those of the
            checkpoint's config, `eval.peaks`).
        peak_overrides: `NAME=VALUE` items (`dream export --peaks`) applied on top of
            `peak_params` (or of the config's `eval.peaks`).

    Raises:
        InputError: unsupported opset, bad peak override, unreadable checkpoint, bad output
            path, or onnxruntime disagreeing with torch (then no file is left behind).
    """
    out = Path(out)
    if out.suffix.lower() != ONNX_SUFFIX:
        raise InputError("the output must be a .onnx file", out, "name it e.g. model.onnx")
    check_output_file(out, parents_made=True)  # before the export and parity run (slow)
    opset = check_opset(opset)
    if peak_overrides:
        peak_params_from_overrides(list(peak_overrides), "--peaks")  # syntax, before loading
    net, config = load_checkpoint(checkpoint)
    metadata = metadata_for(config, checkpoint)
    peaks = peak_params if peak_params is not None else metadata.peak_params
    if peak_overrides:
        peaks = peak_params_from_overrides(list(peak_overrides), "--peaks", peaks)
    metadata = dataclasses.replace(metadata, peak_params=peaks)
    wrapper = KeypointExportWrapper(net).eval()
    pre = config.input
    proto = to_onnx_proto(wrapper, pre.input_width, pre.input_height, opset)
    written = model_opset(proto)
    if opset is not None and written != opset:
        raise InputError(f"torch's exporter wrote ONNX opset {written} instead of {opset}; "
                         "no model was written", out,
                         "leave --opset out, or give the exporter's default")
    onnx.helper.set_model_props(proto, metadata.to_props())
    onnx.checker.check_model(proto)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder ({os_reason(exc)})", out.parent,
                         "choose a writable location") from None
    tmp = _temporary_sibling(out)
    try:
        try:
            onnx.save_model(proto, str(tmp))
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot write the model ({one_line(exc)})", out,
                             "check that the folder is writable and the disk has space") from None
        diffs = parity(wrapper, OnnxKeypointModel(tmp))
        worst = max(diffs, key=diffs.get)
        if not diffs[worst] <= atol:
            raise InputError(f"onnxruntime's '{worst}' output differs from torch by "
                             f"{diffs[worst]:.3g} (> {atol:g}); no model was written", out,
                             "report it, or retry with another --opset")
        try:
            os.replace(tmp, out)
        except OSError as exc:
            raise InputError(f"cannot write the model ({os_reason(exc)})", out,
                             "check that the folder is writable and the disk has space"
                             ) from None
    finally:
        if tmp.exists():
            tmp.unlink()
    log.info("exported %s: outputs %s, max |onnxruntime - torch| %s", out,
             ", ".join(wrapper.output_names), diffs)
    return ExportReport(out, metadata, wrapper.output_names, diffs, config)


def export_onnx(checkpoint: str | Path, out: str | Path) -> Path:
    """Export a checkpoint to `out` (see `export_model`); returns the written path."""
    return export_model(checkpoint, out).path
