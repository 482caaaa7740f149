"""Where a keypoint network fails: per-keypoint PCK on held-out frames and what each miss is.

Runs a checkpoint on (a subset of) a DREAM-layout held-out set through the real peak finder and
prints, per keypoint: the in-frame count, the found rate, the median error and PCK@`--pck-px`
(network-input pixels, as `benchmarks/train_curve.py`), the median distance to the nearest other
keypoint, the misses split into: the peak sits on another keypoint, the true position is
one of the map's next `--candidates` peaks, elsewhere; and the bias: the mean signed error
(found - true, x and y) of the hits, the part that does not average out over many frames.

    python benchmarks/keypoint_errors.py --checkpoint RUN/best.ckpt --heldout DATA_DIR
        [--frames 200] [--peaks NAME=VALUE ...] [--pck-px 5]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch

from dream.errors import DreamError
from dream.peaks import find_peaks, input_to_map, peak_candidates, peak_params_from_overrides
from train.checkpoint import load_checkpoint
from train.data import KeypointDataset, read_folders
from train.metrics import keypoint_errors

BATCH = 16


def heldout_maps(checkpoint: str, heldout: str, frames: int):
    """(belief (N, K, h, w), uv_true_input (N, K, 2), config) on `frames` evenly spaced frames."""
    net, config = load_checkpoint(checkpoint)
    net.eval()
    seqs = read_folders([heldout])
    args = (seqs, config.data.keypoints, config.input, config.model.output_stride,
            config.data.belief_sigma)
    total = len(KeypointDataset(*args, augment=None, use_masks=False))
    keep = np.zeros(total, bool)
    keep[np.unique(np.linspace(0, total - 1, min(frames, total)).round().astype(int))] = True
    dataset = KeypointDataset(*args, augment=None, use_masks=False, frame_filter=keep)
    beliefs, uvs = [], []
    with torch.inference_mode():
        for start in range(0, len(dataset), BATCH):
            items = [dataset[i] for i in range(start, min(start + BATCH, len(dataset)))]
            beliefs.append(net(torch.stack([it["image"] for it in items])).belief.float().numpy())
            uvs.append(np.stack([it["uv_input"].numpy() for it in items]))
    return np.concatenate(beliefs), np.concatenate(uvs), config


def classify_misses(belief, uv_true, found_uv, scored, stride, params, pck_px, candidates):
    """(N, K) codes: 0 hit, 1 on another keypoint, 2 true position among the next peaks,
    3 elsewhere (not found counts as elsewhere unless a candidate is right), -1 not scored."""
    N, K = scored.shape
    code = np.full((N, K), -1)
    for n in range(N):
        cands = peak_candidates(belief[n], params, candidates + 1)
        for k in np.flatnonzero(scored[n]):
            error = np.linalg.norm(found_uv[n, k] - uv_true[n, k])
            if error <= pck_px:
                code[n, k] = 0
                continue
            others = np.delete(uv_true[n], k, axis=0)
            if np.isfinite(error) and np.min(np.linalg.norm(others - found_uv[n, k], axis=1)) \
                    <= pck_px:
                code[n, k] = 1
                continue
            uv_map, _ = cands[k]
            truth_map = input_to_map(uv_true[n, k], stride)
            near = np.linalg.norm(uv_map[1:] - truth_map, axis=1) * stride <= pck_px
            code[n, k] = 2 if near.any() else 3
    return code


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--heldout", required=True, help="DREAM-layout folder with labels")
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--peaks", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--pck-px", type=float, default=5.0)
    parser.add_argument("--candidates", type=int, default=2,
                        help="next peaks of a map searched for the true position")
    args = parser.parse_args(argv)
    try:
        belief, uv_true, config = heldout_maps(args.checkpoint, args.heldout, args.frames)
        params = peak_params_from_overrides(args.peaks, "--peaks", config.eval.peaks)
    except DreamError as exc:
        print(f"keypoint_errors: error: {exc}", file=sys.stderr)
        return 2
    stride = config.model.output_stride
    result = keypoint_errors(belief, uv_true, stride, config.input.input_width,
                             config.input.input_height, params)
    # the peaks themselves (keypoint_errors keeps only their distance to the truth)
    found_uv = np.stack([find_peaks(b, params).to_input(stride).uv_input for b in belief])
    code = classify_misses(belief, uv_true, found_uv, result.scored, stride, params,
                           args.pck_px, args.candidates)
    names = config.data.keypoints
    print(f"{len(belief)} frames of {args.heldout}; peak finder {params}")
    print(f"{'keypoint':<16} {'in frame':>8} {'found':>6} {'median px':>9} "
          f"{'PCK@' + format(args.pck_px, 'g'):>7} {'nearest kp px':>13} {'on other kp':>11} "
          f"{'in next ' + str(args.candidates):>9} {'elsewhere':>9} {'bias x, y px':>13}")
    for k, name in enumerate(names):
        s = result.scored[:, k]
        n = int(s.sum())
        errors = result.error_px[s, k]
        errors = errors[np.isfinite(errors)]
        others = np.delete(uv_true, k, axis=1)
        nearest = np.min(np.linalg.norm(others - uv_true[:, k:k + 1], axis=2), axis=1)[s]
        counts = [int(np.sum(code[:, k] == c)) for c in (0, 1, 2, 3)]
        # mean signed error of the hits: the part that does not average out over many frames
        hits = code[:, k] == 0
        bias = (np.mean(found_uv[hits, k] - uv_true[hits, k], axis=0) if hits.any()
                else np.full(2, np.nan))
        print(f"{name:<16} {n:>8d} {np.mean(result.found[s, k]):>6.2f} "
              f"{np.median(errors) if len(errors) else float('nan'):>9.2f} "
              f"{counts[0] / max(n, 1):>7.3f} {np.median(nearest):>13.1f} {counts[1]:>11d} "
              f"{counts[2]:>9d} {counts[3]:>9d} {bias[0]:>6.2f},{bias[1]:>6.2f}")
    scored = result.scored
    print(f"all: PCK@{args.pck_px:g} {np.sum(code == 0) / scored.sum():.3f}, found "
          f"{np.sum(result.found & scored) / scored.sum():.3f}; misses on another keypoint "
          f"{np.sum(code == 1)}, true position in the next {args.candidates} peaks "
          f"{np.sum(code == 2)}, elsewhere {np.sum(code == 3)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
