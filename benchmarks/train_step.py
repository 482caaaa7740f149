"""Training-step speed of a recipe's network: forward, backward and AdamW on random batches.

The network alone, without data loading, augmentation, targets or validation (those make the
end-to-end rate of `benchmarks/train_curve.py` lower): the compute that a change of the
architecture, the precision or the memory order buys. Each `--variant` is a set of
comma-separated overrides applied on top of the recipe and `--set`; the recipe itself is the
first row. The precision and memory order are the recipe's (`trainer.precision`, `auto`
resolved as in training; `trainer.channels_last`), the threads `trainer.num_threads`.

    python benchmarks/train_step.py [--config YAML] [--set KEY=VALUE ...]
        [--variant "model.skip=add" ...] [--steps 8] [--warmup 2]

Prints per variant: the forward multiply-accumulates per image (convolutions) and the median
images per second over the timed steps.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

from dream.errors import DreamError
from train.budget import BF16, resolve_precision
from train.config import ModelConfig, TrainConfig, load_config
from train.model import build_model

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = REPO / "configs" / "train" / "panda_cpu.yaml"
DEFAULT_KEYPOINTS = 7  # the Panda's; the head's size barely matters to the speed


def _model_config(config: TrainConfig) -> ModelConfig:
    """The recipe's network, with the Panda's keypoint count where the data would set it."""
    if config.model.num_keypoints is not None:
        return config.model
    return replace(config.model, num_keypoints=DEFAULT_KEYPOINTS)


def forward_macs(net: torch.nn.Module, height: int, width: int) -> int:
    """Multiply-accumulates of the convolutions in one forward pass of one image."""
    total = 0

    def count(module, inputs, output):
        nonlocal total
        kh, kw = module.kernel_size
        total += output[0].numel() * (module.in_channels // module.groups) * kh * kw

    hooks = [m.register_forward_hook(count) for m in net.modules()
             if isinstance(m, torch.nn.Conv2d)]
    try:
        with torch.no_grad():
            net(torch.zeros(1, 3, height, width))
    finally:
        for hook in hooks:
            hook.remove()
    return total


def step_rate(net: torch.nn.Module, config: TrainConfig, steps: int, warmup: int) -> float:
    """Median images per second of `steps` timed training steps of `net` (`config`'s network)
    after `warmup` untimed ones."""
    batch, pre = config.data.batch_size, config.input
    x = torch.randn(batch, 3, pre.input_height, pre.input_width)
    if config.trainer.channels_last:
        net = net.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    optimizer = torch.optim.AdamW(net.parameters(), lr=config.optim.lr)
    bf16 = config.trainer.precision == BF16
    times = []
    for i in range(warmup + steps):
        start = time.perf_counter()
        autocast = (torch.autocast("cpu", dtype=torch.bfloat16) if bf16
                    else contextlib.nullcontext())
        with autocast:
            out = net(x)
        loss = out.belief.float().mean()
        if out.mask is not None:
            loss = loss + out.mask.float().mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if i >= warmup:
            times.append(time.perf_counter() - start)
    return batch / statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--variant", action="append", default=[],
                        metavar="KEY=VALUE[,KEY=VALUE]")
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--warmup", type=int, default=2)
    args = parser.parse_args(argv)
    if args.steps < 1 or args.warmup < 0:
        print("train_step: error: --steps must be >= 1 and --warmup >= 0", file=sys.stderr)
        return 2
    rows = [("recipe", [])] + [(v, [o for o in v.split(",") if o]) for v in args.variant]
    try:
        configs = [(name, resolve_precision(load_config(args.config, [*args.set, *extra])))
                   for name, extra in rows]
    except DreamError as exc:
        print(f"train_step: error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.config.name}, batch {configs[0][1].data.batch_size}, "
          f"{configs[0][1].trainer.threads} threads")
    print(f"{'variant':<40} {'precision':>10} {'GMAC/img':>9} {'images/s':>9}")
    for name, config in configs:
        torch.set_num_threads(config.trainer.threads)
        net = build_model(_model_config(config))
        macs = forward_macs(net, config.input.input_height, config.input.input_width)
        rate = step_rate(net, config, args.steps, args.warmup)
        print(f"{name:<40} {config.trainer.precision:>10} {macs / 1e9:9.3f} {rate:9.1f}",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
