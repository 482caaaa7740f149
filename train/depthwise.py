"""Depthwise convolution whose backward pass runs in the faster of two precisions.

Under CPU bfloat16 autocast, oneDNN's depthwise-convolution backward is, for some shapes, many
times slower than its forward, and slower than the same backward in float32: on a Zen 4 CPU the
input gradient of a strided layer 1.2-15x, the weight gradient of a 5x5 kernel 2.5-4x (the
EfficientNet-Lite0 encoder at 256x192, batch 16; `benchmarks/train_step.py`).
`depthwise_conv2d` computes the forward in the autocast precision, as `F.conv2d` would, and each
gradient (input, weight) in whichever of the autocast precision and float32 was faster when
first timed for that layer's shapes, like cuDNN's benchmark mode. The gradients are the plain
convolution's up to the precision chosen; since the choice rests on timings, two runs with the
same seed may differ in the last bits.

Outside CPU low-precision autocast training (inference, ONNX export, float32, CUDA) it is
`F.conv2d`, so the exported graph and the float32 path are unchanged.

    >>> x = torch.randn(2, 8, 16, 16, requires_grad=True)
    >>> w = torch.randn(8, 1, 3, 3, requires_grad=True)
    >>> with torch.autocast("cpu", dtype=torch.bfloat16):
    ...     y = depthwise_conv2d(x, w, stride=(1, 1), padding=(1, 1))
    >>> y.dtype, y.shape
    (torch.bfloat16, torch.Size([2, 8, 16, 16]))
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch.nn import functional as F

log = logging.getLogger(__name__)

Pair = tuple[int, int]
NO_DILATION: Pair = (1, 1)
NO_OUTPUT_PADDING: Pair = (0, 0)


@dataclass
class BackwardTuner:
    """Which precision each gradient of a depthwise layer is computed in, timed once per shape.

    `run(key, candidates)` calls the cached choice for `key`; on the first call for a key it
    runs every candidate once to warm up (oneDNN builds its kernels then) and once timed by
    `timer`, keeps the fastest, and returns that candidate's result.
    """

    timer: Callable[[], float] = time.perf_counter
    choices: dict[tuple, torch.dtype] = field(default_factory=dict)

    def run(self, key: tuple, candidates: dict[torch.dtype, Callable[[], torch.Tensor]]
            ) -> torch.Tensor:
        if key in self.choices:
            return candidates[self.choices[key]]()
        timed = {}
        for dtype, compute in candidates.items():
            compute()
            start = self.timer()
            result = compute()
            timed[dtype] = (self.timer() - start, result)
        best = min(timed, key=lambda dtype: timed[dtype][0])
        self.choices[key] = best
        log.debug("depthwise %s: %s (%s)", key[0], best,
                  ", ".join(f"{d}: {s * 1e3:.1f} ms" for d, (s, _) in timed.items()))
        return timed[best][1]


TUNER = BackwardTuner()


def _convolution_backward(grad: torch.Tensor, x: torch.Tensor, weight: torch.Tensor,
                          stride: Pair, padding: Pair, dtype: torch.dtype, which: str
                          ) -> torch.Tensor:
    """The depthwise convolution's input or weight gradient, computed in `dtype`."""
    def cast(t: torch.Tensor) -> torch.Tensor:
        return t if t.dtype == dtype else t.to(dtype)   # keeps the memory format

    mask = [which == "input", which == "weight", False]
    grads = torch.ops.aten.convolution_backward(
        cast(grad), cast(x), cast(weight), None, list(stride), list(padding), list(NO_DILATION),
        False, list(NO_OUTPUT_PADDING), weight.shape[0], mask)
    return grads[0] if which == "input" else grads[1]


class _DepthwiseConv(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, weight, stride, padding, tuner):
        ctx.save_for_backward(x, weight)
        ctx.conv = (stride, padding, tuner)
        return F.conv2d(x, weight, None, stride, padding, NO_DILATION, weight.shape[0])

    @staticmethod
    def backward(ctx, grad):
        x, weight = ctx.saved_tensors
        stride, padding, tuner = ctx.conv
        grads = []
        for which, needed, like in (("input", ctx.needs_input_grad[0], x),
                                    ("weight", ctx.needs_input_grad[1], weight)):
            if not needed:
                grads.append(None)
                continue
            key = (which, tuple(x.shape), tuple(weight.shape), stride, padding, x.dtype,
                   x.is_contiguous(memory_format=torch.channels_last))
            candidates = {dtype: (lambda dtype=dtype, which=which: _convolution_backward(
                grad, x, weight, stride, padding, dtype, which)) for dtype in (x.dtype,
                                                                               torch.float32)}
            grads.append(tuner.run(key, candidates).to(like.dtype))
        return grads[0], grads[1], None, None, None


def _tuned_backward_applies(x: torch.Tensor, weight: torch.Tensor) -> bool:
    """CPU training under a low-precision autocast, not an export or a trace."""
    return (x.device.type == "cpu" and torch.is_autocast_enabled("cpu")
            and torch.get_autocast_dtype("cpu") != torch.float32
            and torch.is_grad_enabled() and (x.requires_grad or weight.requires_grad)
            and not torch.onnx.is_in_onnx_export() and not torch.jit.is_tracing()
            and not torch.jit.is_scripting())


def depthwise_conv2d(x: torch.Tensor, weight: torch.Tensor, stride: Pair, padding: Pair,
                     tuner: BackwardTuner = TUNER) -> torch.Tensor:
    """`F.conv2d(x, weight, None, stride, padding, groups=C)` for (N, C, H, W) `x` and a
    (C, 1, kh, kw) `weight`, its backward in the faster precision per gradient (module doc).

    Raises:
        ValueError: `weight` is not a depthwise kernel for `x`'s channels.
    """
    channels = x.shape[1] if x.dim() == 4 else None
    if weight.dim() != 4 or weight.shape[:2] != (channels, 1):
        raise ValueError(f"a depthwise kernel for (N, C, H, W) input {tuple(x.shape)} is "
                         f"(C, 1, kh, kw); got {tuple(weight.shape)}")
    stride, padding = tuple(stride), tuple(padding)
    if not _tuned_backward_applies(x, weight):
        return F.conv2d(x, weight, None, stride, padding, NO_DILATION, channels)
    dtype = torch.get_autocast_dtype("cpu")
    with torch.autocast("cpu", enabled=False):
        return _DepthwiseConv.apply(x.to(dtype), weight.to(dtype), stride, padding, tuner)
