"""Per-frame inference cost: onnxruntime against torch eager, and the share of peak finding +
PnP, measured in one run on the same images, the same batch size and thread count.

    python benchmarks/inference.py --checkpoint RUN_DIR/best.ckpt --data DATA_DIR
        [--frames 50] [--batch 1] [--rounds 5] [--threads 2] [--peaks NAME=VALUE ...]
    python benchmarks/inference.py --model MODEL.onnx --data DATA_DIR [...]

`--model` (e.g. the bundled `dream/models/panda_cpu.onnx`, whose checkpoint is not in the
repository) times onnxruntime and peaks + PnP only: no torch eager row and no ratio.

`--batch 1` (streaming, a frame at a time): per frame the network, `find_peaks` and
`solve_pnp`. `--batch B` > 1 (as `dream calibrate` runs, B = 8 there): the network on B frames
per call and the peak finder on their B x K maps in one call (`find_peaks_batch`), then every
frame's single-frame PnP in one `solve_pnp_batch` call (calibrate's `solve_frames`; the same
poses as frame by frame). All figures are per frame.

`--peaks` overrides the peak finder's constants as `dream export --peaks` does (the bundled model
was exported with `ambiguity_ratio=1.0`, which passes every peak to the solver).

Each round times torch eager, onnxruntime and peaks + PnP in turn, each in its own loop over the
batches (as `dream calibrate` runs them: the network on every batch, then the geometry); the
figures are medians over batches, then over rounds, and the share is the median of the rounds'
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

from dream.detection import prepare_batch
from dream.io import load_image, read_sequence
from dream.peaks import find_peaks_batch, peak_params_from_overrides
from dream.pipeline import joints_in_robot_order, robot_for
from dream.pnp import solve_pnp, solve_pnp_batch
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
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--checkpoint", help="a dream train checkpoint (exported here)")
    source.add_argument("--model", help="an exported ONNX model (no torch comparison)")
    parser.add_argument("--data", required=True, help="DREAM-layout folder with images")
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--batch", type=int, default=1,
                        help="frames per network call and per peak-finder call (dream "
                             "calibrate: 8); figures are per frame")
    parser.add_argument("--rounds", type=int, default=5,
                        help="rounds of (torch, onnxruntime, peaks + PnP) timings")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--peaks", action="append", default=[], metavar="NAME=VALUE",
                        help="peak-finder constant (repeatable), e.g. ambiguity_ratio=1.0")
    args = parser.parse_args()
    if args.rounds < 1 or args.batch < 1 or args.frames < args.batch:
        parser.error("--rounds and --batch must be >= 1, --frames >= --batch")
    torch.set_num_threads(args.threads)
    net = None
    if args.checkpoint:
        net, _ = load_checkpoint(args.checkpoint)
        net.eval()
    with tempfile.TemporaryDirectory() as tmp:
        onnx_path = (Path(args.model) if args.model
                     else export_onnx(args.checkpoint, Path(tmp) / "model.onnx"))
        runner = OnnxKeypointModel(onnx_path, threads=args.threads)
        seq = read_sequence(args.data)
        n = args.frames // args.batch * args.batch       # whole batches
        frames = seq.frames[:n]
        images = [load_image(f, seq.camera) for f in frames]
        inputs = [prepare_batch(images[i:i + args.batch], runner.preprocess)
                  for i in range(0, n, args.batch)]
        batches = [b for b, _ in inputs]

        def torch_eager(x):
            with torch.inference_mode():
                return net(torch.from_numpy(x)).belief.numpy()

        def onnx(x):
            return runner.run(x)["belief"]

        peak_params = peak_params_from_overrides(args.peaks, "--peaks", runner.peak_params)
        robot = robot_for(seq, None, runner.keypoint_names)
        P_base = robot.forward_kinematics(joints_in_robot_order(seq, robot))
        cameras = [seq.frame_camera(i) for i in range(n)]  # each frame's own
        post = [(onnx(b), transforms, P_base[i:i + args.batch], cameras[i:i + args.batch])
                for (b, transforms), i in zip(inputs, range(0, n, args.batch), strict=True)]

        def peaks_in_image(item):
            belief, transforms, _, _ = item
            return [peaks.to_input(runner.stride).to_image(transform) for peaks, transform
                    in zip(find_peaks_batch(belief, peak_params), transforms, strict=True)]

        def peaks_and_pnp(item):                       # one frame (--batch 1)
            (peaks,), (_, _, P, (camera,)) = peaks_in_image(item), item
            return solve_pnp(P[0], peaks.uv_image, camera, confidence=peaks.confidence)

        def peaks_and_pnp_all(_):                      # every frame, as dream calibrate
            peaks = [p for item in post for p in peaks_in_image(item)]
            return solve_pnp_batch(P_base[:n], np.array([p.uv_image for p in peaks]), cameras,
                                   confidence=np.array([p.confidence for p in peaks]))

        def post_ms() -> float:                        # per batch
            if args.batch == 1:
                return median_ms(peaks_and_pnp, post)
            return median_ms(peaks_and_pnp_all, [None] * 3) * args.batch / n

        rounds = np.array([(median_ms(torch_eager, batches) if net is not None else np.nan,
                            median_ms(onnx, batches), post_ms()) for _ in range(args.rounds)])
        rounds /= args.batch                               # per frame
        found = np.mean([peaks.found.mean() for belief, _, _, _ in post
                         for peaks in find_peaks_batch(belief, peak_params)])
    t_torch, t_onnx, t_post = np.median(rounds, axis=0)
    ratio, share = rounds[:, 1] / rounds[:, 0], 100 * rounds[:, 2] / rounds[:, 1]
    pre = runner.preprocess
    print(f"{n} frames of {args.data}, input {pre.input_width}x{pre.input_height}, "
          f"batch {args.batch}, {args.threads} threads, {args.rounds} rounds (per frame: medians; "
          f"rounds' range)")
    if net is not None:
        print(f"torch eager:          {t_torch:7.2f} ms/frame")
        print(f"onnxruntime:          {t_onnx:7.2f} ms/frame   ratio {np.median(ratio):.2f} "
              f"({ratio.min():.2f}-{ratio.max():.2f}) (target <= 0.75)")
    else:
        print(f"onnxruntime:          {t_onnx:7.2f} ms/frame   ({onnx_path}; no torch eager "
              f"row without --checkpoint)")
    print(f"peaks + PnP:          {t_post:7.2f} ms/frame   {np.median(share):.1f} % "
          f"({share.min():.1f}-{share.max():.1f} %) of the onnxruntime network time "
          f"(target <= 10 %)")
    print(f"peak finder: {peak_params}; {100 * found:.0f} % of keypoints found")


if __name__ == "__main__":
    main()
