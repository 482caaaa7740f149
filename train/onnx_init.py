"""Start training from an exported model: the network weights of a `dream export` ONNX file.

A bundled or shared model may come without its checkpoint. Its ONNX file holds every weight of
the network, but the exporter folds each batch norm into the convolution before it: the file has
`W' = W * g / sqrt(v + eps)` and `b' = beta + (b - m) * g / sqrt(v + eps)` where the network has a
bias-free convolution `W` and a batch norm (gamma `g`, beta, running mean `m` and variance `v`).
The split cannot be undone from the file alone, but any split that computes the same function
will do. This module takes `W = W'` and chooses the batch norm from data: with `mu` and `var` the
per-channel mean and (biased) variance of the convolution's outputs over a few training batches,

    running_mean = mu, running_var = var, gamma = sqrt(var + eps), beta = mu + b'.

In eval mode that is exactly the exported function; in training mode the batch statistics are
close to `mu` and `var`, so training starts from the exported network instead of from a
different one. The ONNX file's metadata must name the run's robot, keypoints and preprocessing,
and every weight must fit the run's `model` settings.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import onnx
import torch
from google.protobuf.message import DecodeError
from onnx import numpy_helper
from torch import nn
from torch.utils.data import DataLoader, Dataset, Subset

from dream.errors import InputError
from export.runner import ModelMetadata
from train.config import TrainConfig
from train.model import BeliefNet

logger = logging.getLogger(__name__)

ONNX_SUFFIX = ".onnx"
FOLDED_BIAS_SUFFIX = "_bias"   # the exporter names a folded bias `<conv>.weight_bias`
INIT_IMAGES = 256             # training images that choose the batch-norm split
_NET_PREFIX = "net."           # the export wrapper's attribute holding the network
_FIX = "give the .onnx written by dream export for a network of this recipe"


def sample_images(dataset: Dataset, batch_size: int, seed: int,
                  count: int = INIT_IMAGES) -> list[torch.Tensor]:
    """Batches of `count` images of `dataset` (as training sees them: augmented), drawn with
    `seed`: what `init_from_onnx` splits the batch norms on."""
    rng = np.random.default_rng(seed)
    count = min(count, len(dataset))
    subset = Subset(dataset, rng.choice(len(dataset), size=count, replace=False).tolist())
    return [batch["image"] for batch in DataLoader(subset, batch_size=batch_size, num_workers=0)]


def is_onnx_model(path: str | Path) -> bool:
    """True for an ONNX file name (`trainer.init_from` then takes `init_from_onnx`)."""
    return Path(path).suffix.lower() == ONNX_SUFFIX


def read_onnx_weights(path: str | Path) -> tuple[dict[str, np.ndarray], ModelMetadata]:
    """The named weights (initializers) of an exported model and its dream metadata."""
    path = Path(path)
    if not path.is_file():
        raise InputError("model file not found", path, _FIX)
    try:
        proto = onnx.load(str(path))
    except (DecodeError, OSError, ValueError, RuntimeError) as exc:
        raise InputError(f"cannot read the ONNX model ({type(exc).__name__})", path,
                         _FIX) from None
    metadata = ModelMetadata.from_props({p.key: p.value for p in proto.metadata_props}, path)
    weights = {init.name.removeprefix(_NET_PREFIX): numpy_helper.to_array(init)
               for init in proto.graph.initializer if init.name.startswith(_NET_PREFIX)}
    return weights, metadata


def check_metadata(metadata: ModelMetadata, config: TrainConfig, path: str | Path) -> None:
    """The exported model must be one of this run's robot, keypoints and preprocessing."""
    checks = (("robot", metadata.robot, config.data.robot),
              ("keypoints", list(metadata.keypoint_names), list(config.data.keypoints or ())),
              ("preprocessing", metadata.preprocess, config.input),
              ("output stride", metadata.output_stride, config.model.output_stride))
    for what, theirs, ours in checks:
        if theirs != ours:
            raise InputError(f"cannot start from this model: its {what} ({theirs}) differs "
                             f"from the run's ({ours})", path,
                             "train with the recipe the model was exported from")


def conv_bn_pairs(model: nn.Module, example: torch.Tensor) -> dict[str, str]:
    """Convolution name -> name of the batch norm that normalises its output, found by running
    `example` through `model` (in eval mode) and matching each batch norm's input tensor."""
    names = {module: name for name, module in model.named_modules()}
    produced: dict[int, str] = {}
    pairs: dict[str, str] = {}

    def conv_hook(module, _inputs, output):
        produced[id(output)] = names[module]

    def bn_hook(module, inputs, _output):
        conv = produced.get(id(inputs[0]))
        if conv is not None:
            pairs[conv] = names[module]

    handles = [m.register_forward_hook(conv_hook) for m in model.modules()
               if isinstance(m, nn.Conv2d)]
    handles += [m.register_forward_hook(bn_hook) for m in model.modules()
                if isinstance(m, nn.BatchNorm2d)]
    try:
        with torch.no_grad():
            model.eval()(example)
    finally:
        for handle in handles:
            handle.remove()
    return pairs


def _take(weights: dict[str, np.ndarray], name: str, like: torch.Tensor,
          path: Path) -> torch.Tensor:
    """Weight `name` of the file as a tensor shaped like `like`; missing or misshapen: an error."""
    if name not in weights:
        raise InputError(f"cannot start from this model: it has no weight {name!r} (another "
                         f"network)", path, "set the recipe's model settings to the exported "
                         "model's")
    value = torch.from_numpy(np.array(weights[name], dtype=np.float32))
    if tuple(value.shape) != tuple(like.shape):
        raise InputError(f"cannot start from this model: its {name} is {tuple(value.shape)}, "
                         f"the recipe's network has {tuple(like.shape)}", path,
                         "set the recipe's model settings to the exported model's")
    return value


class _ChannelMoments:
    """Per-channel mean and biased variance of a convolution's outputs over several batches."""

    def __init__(self) -> None:
        self.count = 0
        self.total: torch.Tensor | None = None
        self.squares: torch.Tensor | None = None

    def __call__(self, _module, _inputs, output: torch.Tensor) -> None:
        y = output.detach().to(torch.float64).transpose(0, 1).reshape(output.shape[1], -1)
        s, s2 = y.sum(dim=1), (y * y).sum(dim=1)
        self.total = s if self.total is None else self.total + s
        self.squares = s2 if self.squares is None else self.squares + s2
        self.count += y.shape[1]

    def moments(self) -> tuple[torch.Tensor, torch.Tensor]:
        mean = self.total / self.count
        return mean, (self.squares / self.count - mean * mean).clamp_min(0.0)


def init_from_onnx(model: BeliefNet, path: str | Path, config: TrainConfig,
                   batches: Iterable[torch.Tensor]) -> None:
    """Set `model`'s weights to the exported model at `path` (see the module docstring).

    Args:
        model: the run's network, built from `config.model`.
        path: a `dream export` ONNX file of the same network, robot, keypoints and input.
        config: the run's resolved config.
        batches: normalised input images (N, 3, H, W) that choose the batch-norm split
            (training batches; a few hundred images are plenty).

    Raises:
        InputError: the file is missing or unreadable, or its metadata or weights do not fit.
    """
    path = Path(path)
    weights, metadata = read_onnx_weights(path)
    check_metadata(metadata, config, path)
    batches = list(batches)
    if not batches:
        raise InputError("no training images to start from the exported model", path,
                         "give training data")
    modes = {module: module.training for module in model.modules()}
    try:
        _load_and_split(model, weights, batches, path)
    finally:
        for module, training in modes.items():   # train or eval, as the caller left them
            module.train(training)
    logger.info("%s: batch norms split on %d training images", path,
                sum(len(b) for b in batches))


def _load_and_split(model: BeliefNet, weights: dict[str, np.ndarray],
                    batches: list[torch.Tensor], path: Path) -> None:
    """`init_from_onnx` after its checks; leaves `model` in eval mode."""
    pairs = conv_bn_pairs(model, batches[0][:1])
    modules = dict(model.named_modules())
    moments: dict[str, _ChannelMoments] = {}
    with torch.no_grad():
        for name, module in modules.items():
            if isinstance(module, nn.Conv2d):
                module.weight.copy_(_take(weights, f"{name}.weight", module.weight, path))
                if name in pairs:
                    bias = _take(weights, f"{name}.weight{FOLDED_BIAS_SUFFIX}",
                                 modules[pairs[name]].bias, path)
                    _set_bn(modules[pairs[name]], torch.zeros_like(bias),
                            torch.ones_like(bias), bias)
                    moments[name] = _ChannelMoments()
                elif module.bias is not None:
                    module.bias.copy_(_take(weights, f"{name}.bias", module.bias, path))
        unpaired = [n for n, m in modules.items()
                    if isinstance(m, nn.BatchNorm2d) and n not in pairs.values()]
        if unpaired:
            raise InputError(f"cannot start from this model: batch norms {unpaired} follow no "
                             "convolution", path, _FIX)
        handles = [modules[name].register_forward_hook(m) for name, m in moments.items()]
        try:
            model.eval()
            for image in batches:
                model(image)
        finally:
            for handle in handles:
                handle.remove()
        for name, stats in moments.items():
            bn = modules[pairs[name]]
            mean, var = stats.moments()
            bias = bn.bias.detach().to(torch.float64).clone()
            _set_bn(bn, mean, var, mean + bias)


def _set_bn(bn: nn.BatchNorm2d, mean: torch.Tensor, var: torch.Tensor,
            beta: torch.Tensor) -> None:
    """Batch norm with these running statistics whose eval-mode output is `y - mean + beta`
    for input `y`: gamma = sqrt(var + eps)."""
    bn.running_mean.copy_(mean.to(bn.running_mean.dtype))
    bn.running_var.copy_(var.to(bn.running_var.dtype))
    bn.weight.copy_(torch.sqrt(var.to(torch.float64) + bn.eps).to(bn.weight.dtype))
    bn.bias.copy_(beta.to(bn.bias.dtype))
    bn.num_batches_tracked.zero_()
