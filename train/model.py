"""The belief-map network: an encoder (residual, or a pretrained EfficientNet-Lite), a decoder
with skip connections, belief and mask heads.

Pure `nn.Module`s and one factory, `build_model(ModelConfig) -> BeliefNet`. Only ONNX-friendly
ops: 3x3/1x1 convolutions, batch norm, ReLU, x2 upsampling (bilinear with align_corners=False, or
nearest), concatenation or addition, sigmoid.

Shapes: input (N, 3, H, W) normalised RGB (`dream.preprocess`), H and W multiples of
`ModelConfig.network_stride`; output `BeliefOutput(belief (N, K, H/s, W/s), mask (N, 1, H/s, W/s)
logits or None)`, s the output stride; the belief maps pass through a sigmoid when
`ModelConfig.belief_activation` says so (inside the network, so the ONNX file has it too).
Map pixel (i, j) covers input pixels s*i .. s*i+s-1
(`dream.peaks.map_to_input`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import nn
from torch.nn import functional as F

from dream.errors import InputError
from train.config import RESNET, ModelConfig

_UPSAMPLE_FACTOR = 2


class BeliefOutput(NamedTuple):
    """belief: (N, K, H/s, W/s) belief maps; mask: (N, 1, H/s, W/s) robot logits or None."""

    belief: torch.Tensor
    mask: torch.Tensor | None


def conv_bn_relu(in_ch: int, out_ch: int, stride: int = 1) -> nn.Sequential:
    """3x3 convolution, batch norm, ReLU."""
    return nn.Sequential(nn.Conv2d(in_ch, out_ch, 3, stride, 1, bias=False),
                         nn.BatchNorm2d(out_ch), nn.ReLU(inplace=True))


class BasicBlock(nn.Module):
    """ResNet basic block: two 3x3 convolutions and an identity (or 1x1 projection) shortcut."""

    def __init__(self, in_ch: int, out_ch: int, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(in_ch, out_ch, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.conv2 = nn.Conv2d(out_ch, out_ch, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.shortcut = nn.Identity() if stride == 1 and in_ch == out_ch else nn.Sequential(
            nn.Conv2d(in_ch, out_ch, 1, stride, bias=False), nn.BatchNorm2d(out_ch))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)), inplace=True)
        y = self.bn2(self.conv2(y))
        return F.relu(y + self.shortcut(x), inplace=True)


class Encoder(nn.Module):
    """Stem (stride 2) and `num_stages` residual stages (stride 2 each).

    `forward` returns the features at strides 2, 4, ..., 2^(num_stages + 1), and, when
    `full_resolution` is set, a light stride-1 feature first (for output stride 1).
    """

    def __init__(self, config: ModelConfig, full_resolution: bool):
        super().__init__()
        w0 = config.base_width
        self.full = conv_bn_relu(3, max(w0 // 2, 1)) if full_resolution else None
        self.stem = nn.Sequential(conv_bn_relu(3, w0, stride=2), conv_bn_relu(w0, w0))
        self.widths = [max(w0 // 2, 1)] if full_resolution else []
        self.widths.append(w0)
        stages = []
        in_ch = w0
        for i in range(config.num_stages):
            out_ch = min(w0 * 2 ** i, config.max_width)
            blocks = [BasicBlock(in_ch, out_ch, stride=2)]
            blocks += [BasicBlock(out_ch, out_ch) for _ in range(config.blocks_per_stage - 1)]
            stages.append(nn.Sequential(*blocks))
            self.widths.append(out_ch)
            in_ch = out_ch
        self.stages = nn.ModuleList(stages)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        features = [self.full(x)] if self.full is not None else []
        y = self.stem(x)
        features.append(y)
        for stage in self.stages:
            y = stage(y)
            features.append(y)
        return features


class LiteEncoder(nn.Module):
    """An EfficientNet-Lite's features at strides 2-32 (`train.efficientnet`), its ImageNet
    weights loaded when `load_weights` (a checkpoint brings its own), its classifier dropped,
    and the layers `freeze` names kept as they are (weights and batch-norm statistics)."""

    def __init__(self, config: ModelConfig, load_weights: bool):
        super().__init__()
        from train.efficientnet import EfficientNetLite, pretrained

        net = pretrained(config.encoder) if load_weights and config.pretrained else \
            EfficientNetLite(config.encoder)
        del net._conv_head, net._bn1, net._fc          # the classifier: not used here
        self.net = net
        self.widths = list(net.widths)
        self.frozen: list[nn.Module] = []
        if config.freeze_encoder == "all":
            self.frozen = [net]
        elif config.freeze_encoder == "partial":     # the stem and the stride-2 and -4 blocks
            self.frozen = [net._conv_stem, net._bn0, *net._blocks[:net.taps[1] + 1]]
        for module in self.frozen:     # eval from the start: Lightning's fit keeps the modes
            module.requires_grad_(False)
            module.eval()

    def train(self, mode: bool = True) -> LiteEncoder:
        super().train(mode)
        for module in self.frozen:                     # frozen batch norms keep their stats
            module.eval()
        return self

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        return self.net.features(x)


class DecoderLevel(nn.Module):
    """x2 upsampling of the coarser features, merged with the skip features, then two 3x3
    convolutions."""

    def __init__(self, in_ch: int, skip_ch: int, out_ch: int, skip: str, upsample: str):
        super().__init__()
        self.skip, self.upsample = skip, upsample
        if skip == "add":
            self.project = nn.Conv2d(skip_ch, in_ch, 1, bias=False)
            merged = in_ch
        else:
            self.project = None
            merged = in_ch + skip_ch
        self.convs = nn.Sequential(conv_bn_relu(merged, out_ch), conv_bn_relu(out_ch, out_ch))

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        if self.upsample == "bilinear":
            x = F.interpolate(x, scale_factor=_UPSAMPLE_FACTOR, mode="bilinear",
                              align_corners=False)
        else:
            x = F.interpolate(x, scale_factor=_UPSAMPLE_FACTOR, mode="nearest")
        x = x + self.project(skip) if self.project is not None else torch.cat([x, skip], dim=1)
        return self.convs(x)


class BeliefNet(nn.Module):
    """Encoder-decoder producing K belief maps (and optionally robot-mask logits).

    Args:
        config: `ModelConfig` with `num_keypoints` set.
        load_weights: load a pretrained encoder's ImageNet weights (`config.pretrained`);
            False where a checkpoint's weights follow.
    """

    def __init__(self, config: ModelConfig, load_weights: bool = True):
        super().__init__()
        if config.num_keypoints is None:
            raise InputError("model.num_keypoints is not set",
                             fix="set it, or let training take it from the data")
        self.config = config
        self.encoder = (Encoder(config, full_resolution=config.output_stride == 1)
                        if config.encoder == RESNET else LiteEncoder(config, load_weights))
        widths = self.encoder.widths  # strides: [1,] 2, 4, ..., network stride
        first_stride = 1 if config.output_stride == 1 else 2
        strides = [first_stride * 2 ** i for i in range(len(widths))]
        out_level = strides.index(config.output_stride)
        levels = []
        in_ch = widths[-1]
        for level in range(len(widths) - 2, out_level - 1, -1):
            out_ch = min(config.decoder_width, widths[level])
            levels.append(DecoderLevel(in_ch, widths[level], out_ch, config.skip,
                                       config.upsample))
            in_ch = out_ch
        self.decoder = nn.ModuleList(levels)
        self.skip_levels = list(range(len(widths) - 2, out_level - 1, -1))
        self.belief_head = nn.Conv2d(in_ch, config.num_keypoints, 1)
        self.sigmoid = config.belief_activation == "sigmoid"
        if self.sigmoid:
            nn.init.constant_(self.belief_head.bias, math.log(config.belief_prior
                                                              / (1 - config.belief_prior)))
        self.mask_head = nn.Conv2d(in_ch, 1, 1) if config.mask_head else None

    @property
    def output_stride(self) -> int:
        return self.config.output_stride

    def _check_input(self, x: torch.Tensor) -> None:
        stride = self.config.network_stride
        if x.ndim != 4 or x.shape[1] != 3:
            raise InputError(f"network input has shape {tuple(x.shape)}, expected (N, 3, H, W)")
        if x.shape[2] % stride or x.shape[3] % stride:
            raise InputError(f"network input {x.shape[3]}x{x.shape[2]} is not a multiple of "
                             f"the network stride {stride}")

    def forward(self, x: torch.Tensor) -> BeliefOutput:
        """(N, 3, H, W) -> BeliefOutput((N, K, H/s, W/s), (N, 1, H/s, W/s) or None)."""
        if not (torch.jit.is_tracing() or torch.onnx.is_in_onnx_export()):
            self._check_input(x)
        features = self.encoder(x)
        y = features[-1]
        for level, decoder in zip(self.skip_levels, self.decoder, strict=True):
            y = decoder(y, features[level])
        mask = self.mask_head(y) if self.mask_head is not None else None
        belief = self.belief_head(y)
        if belief.dtype != torch.float32:  # under mixed precision: maps and losses in float32
            belief = belief.float()
            mask = mask.float() if mask is not None else None
        return BeliefOutput(torch.sigmoid(belief) if self.sigmoid else belief, mask)


def build_model(config: ModelConfig, load_weights: bool = True) -> BeliefNet:
    """The network of `config` (num_keypoints must be set); `load_weights`: a pretrained
    encoder's ImageNet weights (False where a checkpoint's weights follow)."""
    return BeliefNet(config, load_weights)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
