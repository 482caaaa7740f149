"""The depthwise convolution with a per-shape backward precision (`train.depthwise`) and the
"same"-padded convolution of the EfficientNet-Lite encoders that uses it."""

from __future__ import annotations

import doctest
import itertools
import math

import pytest
import torch
from torch.nn import functional as F

import train.depthwise
from train.depthwise import BackwardTuner, depthwise_conv2d
from train.efficientnet import SamePadConv

BF16_RTOL = 2e-2        # bfloat16 keeps 8 significant bits


def reference_grads(x, w, stride, padding, grad):
    """Input and weight gradients of the plain convolution in float64."""
    x64 = x.detach().double().requires_grad_()
    w64 = w.detach().double().requires_grad_()
    y = F.conv2d(x64, w64, None, stride, padding, 1, w.shape[0])
    return torch.autograd.grad(y, [x64, w64], grad.double())


def relative_error(a, b):
    return float((a.double() - b).norm() / b.norm())


@pytest.mark.parametrize("kernel,stride", [(3, 1), (3, 2), (5, 1), (5, 2)])
@pytest.mark.parametrize("channels_last", [False, True])
def test_gradients_match_the_plain_convolution_under_bf16_autocast(kernel, stride,
                                                                   channels_last):
    gen = torch.Generator().manual_seed(kernel * 10 + stride)
    x = torch.randn(2, 12, 17, 14, generator=gen)
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
    w = torch.randn(12, 1, kernel, kernel, generator=gen)
    x.requires_grad_()
    w.requires_grad_()
    padding = (kernel // 2, kernel // 2)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        y = depthwise_conv2d(x, w, (stride, stride), padding)
        plain = F.conv2d(x, w, None, stride, padding, 1, 12)
    assert y.dtype == torch.bfloat16 and "DepthwiseConv" in type(y.grad_fn).__name__
    torch.testing.assert_close(y, plain, rtol=0, atol=0)     # the same forward
    grad = torch.randn(y.shape, generator=gen)
    gx, gw = torch.autograd.grad(y, [x, w], grad.to(y.dtype))
    assert gx.dtype == x.dtype and gw.dtype == w.dtype      # float32, like the parameters
    rx, rw = reference_grads(x, w, (stride, stride), padding, grad)
    assert relative_error(gx, rx) < BF16_RTOL
    assert relative_error(gw, rw) < BF16_RTOL


def test_only_the_needed_gradient_is_computed():
    x = torch.randn(1, 4, 9, 9, requires_grad=True)
    w = torch.randn(4, 1, 3, 3)                              # frozen
    tuner = BackwardTuner()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        y = depthwise_conv2d(x, w, (1, 1), (1, 1), tuner=tuner)
    y.float().sum().backward()
    assert x.grad is not None and w.grad is None
    assert [key[0] for key in tuner.choices] == ["input"]


def test_outside_low_precision_training_it_is_the_plain_convolution():
    x = torch.randn(2, 6, 10, 10, requires_grad=True)
    w = torch.randn(6, 1, 5, 5, requires_grad=True)
    plain = F.conv2d(x, w, None, 2, 2, 1, 6)
    cases = [depthwise_conv2d(x, w, (2, 2), (2, 2))]          # float32 training
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        cases.append(depthwise_conv2d(x, w, (2, 2), (2, 2)))  # inference
    for y in cases:
        assert y.grad_fn is None or "DepthwiseConv" not in type(y.grad_fn).__name__
    torch.testing.assert_close(cases[0], plain, rtol=0, atol=0)


def test_docstring_example_runs():
    assert doctest.testmod(train.depthwise).failed == 0


def test_a_kernel_that_is_not_depthwise_is_refused():
    with pytest.raises(ValueError, match=r"\(C, 1, kh, kw\)"):
        depthwise_conv2d(torch.zeros(1, 4, 8, 8), torch.zeros(4, 4, 3, 3), (1, 1), (1, 1))


class FakeClock:
    """A clock that each candidate advances by its own cost when it runs."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_tuner_keeps_the_faster_candidate_and_times_each_key_once():
    clock = FakeClock()
    calls = {"slow": 0, "fast": 0}

    def candidate(name, cost):
        def run():
            calls[name] += 1
            clock.now += cost
            return torch.tensor(cost)
        return run

    tuner = BackwardTuner(timer=clock)
    candidates = {torch.bfloat16: candidate("slow", 3.0), torch.float32: candidate("fast", 1.0)}
    assert float(tuner.run(("weight", 1), candidates)) == 1.0
    assert tuner.choices == {("weight", 1): torch.float32}
    assert calls == {"slow": 2, "fast": 2}                   # warm-up and timed run each
    for _ in range(3):
        assert float(tuner.run(("weight", 1), candidates)) == 1.0
    assert calls == {"slow": 2, "fast": 5}                   # the choice, untimed
    tuner.run(("weight", 2), candidates)                     # a new shape is timed again
    assert calls == {"slow": 4, "fast": 7}


def tf_same(x, conv):
    """TensorFlow's "same" padding as an explicit F.pad before the convolution."""
    pads = []
    for size, k, s in zip(x.shape[:-3:-1], conv.kernel_size[::-1], conv.stride[::-1],
                          strict=True):
        total = max((math.ceil(size / s) - 1) * s + k - size, 0)
        pads += [total // 2, total - total // 2]
    return F.conv2d(F.pad(x, pads), conv.weight, conv.bias, conv.stride, 0, 1, conv.groups)


@pytest.mark.parametrize("kernel,stride,size,depthwise",
                         list(itertools.product((1, 3, 5), (1, 2), ((16, 12), (15, 11)),
                                                (False, True))))
def test_same_pad_conv_pads_like_tensorflow(kernel, stride, size, depthwise):
    torch.manual_seed(kernel + stride)
    conv = SamePadConv(8, 8, kernel, stride, groups=8 if depthwise else 1, bias=False)
    x = torch.randn(2, 8, *size)
    y = conv(x)
    assert y.shape[2:] == tuple(math.ceil(s / stride) for s in size)
    torch.testing.assert_close(y, tf_same(x, conv), rtol=1e-5, atol=1e-5)
