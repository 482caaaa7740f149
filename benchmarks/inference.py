"""Per-frame inference cost: onnxruntime against torch eager, and the share of peak finding +
PnP, measured in one run on the same images, batch 1, the same thread count.

    python benchmarks/inference.py --checkpoint RUN_DIR/best.ckpt --data DATA_DIR
        [--frames 50] [--rounds 5] [--threads 2] [--peaks NAME=VALUE ...]

`--peaks` overrides the peak finder's constants as `dream export --peaks` does (the bundled model
was exported with `ambiguity_ratio=1.0`, which passes every peak to the solver).

Each round times torch eager, onnxruntime and peaks + PnP in turn, each in its own loop over the
frames (as `dream calibrate` runs them: the network on every frame, then the geometry); the
figures are medians over frames, then over rounds, and the share is the median of the rounds'
shares (this cancels the drift of a shared machine's speed between rounds).

Targets: onnxruntime / torch eager latency <= 0.75; (peak finding + single-frame PnP) / network
time <= 10 %.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from dream.detect import prepare_batch
from dream.io import load_image, read_sequence
from dream.peaks import find_peaks_in_image, peak_params_from_overrides
from dream.pipeline import joints_in_robot_order, robot_for
from dream.pnp import solve_pnp
from export.onnx_export import export_onnx
from export.runner import OnnxKeypointModel
from train.checkpoint import load_checkpoint

WARMUP_FRAMES = 5


def median_ms(fn, inputs) -> float:
    for x in inputs[:WARMUP_FRAMES]:
        fn(x)
    times = []
    for x in inputs:
        start = time.perf_counter()
        fn(x)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--data", required=True, help="DREAM-layout folder with images")
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=5,
                        help="rounds of (torch, onnxruntime, peaks + PnP) timings")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--peaks", action="append", default=[], metavar="NAME=VALUE",
                        help="peak-finder constant (repeatable), e.g. ambiguity_ratio=1.0")
    args = parser.parse_args()
    if args.frames < 1 or args.rounds < 1:
        parser.error("--frames and --rounds must be >= 1")
    torch.set_num_threads(args.threads)
    net, config = load_checkpoint(args.checkpoint)
    net.eval()
    with tempfile.TemporaryDirectory() as tmp:
        onnx_path = export_onnx(args.checkpoint, Path(tmp) / "model.onnx")
        runner = OnnxKeypointModel(onnx_path, threads=args.threads)
        seq = read_sequence(args.data)
        frames = seq.frames[:args.frames]
        images = [load_image(f, seq.camera) for f in frames]
        inputs = [prepare_batch([im], runner.preprocess) for im in images]
        batches = [b for b, _ in inputs]

        def torch_eager(x):
            with torch.inference_mode():
                return net(torch.from_numpy(x)).belief.numpy()

        def onnx(x):
            return runner.run(x)["belief"]

        peak_params = peak_params_from_overrides(args.peaks, "--peaks", runner.peak_params)
        robot = robot_for(seq, None, runner.keypoint_names)
        P_base = robot.forward_kinematics(joints_in_robot_order(seq, robot))
        beliefs = [onnx(b)[0] for b in batches]
        cameras = [seq.frame_camera(i) for i in range(len(frames))]  # each frame's own
        post = list(zip(beliefs, [t[0] for _, t in inputs], P_base[:len(frames)], cameras,
                        strict=True))

        def peaks_and_pnp(item):
            belief, transform, P, camera = item
            peaks = find_peaks_in_image(belief, runner.stride, transform, peak_params)
            return solve_pnp(P, peaks.uv_image, camera, confidence=peaks.confidence)

        rounds = np.array([(median_ms(torch_eager, batches), median_ms(onnx, batches),
                            median_ms(peaks_and_pnp, post)) for _ in range(args.rounds)])
        found = np.mean([find_peaks_in_image(b, runner.stride, t, peak_params).found.mean()
                         for b, t, _, _ in post])
    t_torch, t_onnx, t_post = np.median(rounds, axis=0)
    ratio, share = rounds[:, 1] / rounds[:, 0], 100 * rounds[:, 2] / rounds[:, 1]
    i = config.input
    print(f"{len(frames)} frames of {args.data}, input {i.input_width}x{i.input_height}, "
          f"batch 1, {args.threads} threads, {args.rounds} rounds (medians; rounds' range)")
    print(f"torch eager:          {t_torch:7.2f} ms/frame")
    print(f"onnxruntime:          {t_onnx:7.2f} ms/frame   ratio {np.median(ratio):.2f} "
          f"({ratio.min():.2f}-{ratio.max():.2f}) (target <= 0.75)")
    print(f"peaks + PnP:          {t_post:7.2f} ms/frame   {np.median(share):.1f} % "
          f"({share.min():.1f}-{share.max():.1f} %) of the onnxruntime network time "
          f"(target <= 10 %)")
    print(f"peak finder: {peak_params}; {100 * found:.0f} % of keypoints found")


if __name__ == "__main__":
    main()
