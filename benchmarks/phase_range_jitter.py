"""Does the sampling-phase range of a held joint log hold the true placement of its updates
when the timestamps jitter?

Each trial simulates a joint log on a regular clock (period 0.1-0.3 s, a quarter of them a
whole number of frames, random phase) beside a 30 frames/s camera, finds the frame where each
reading first appears, and computes `dream.readings.clock_phase_range`: the range of the mean
time by which `update_times` places the updates after their true instants. The frame stamps
scatter by `jitter` (Gaussian, 1-sigma) about the instants the frames were taken, and with
`--log-jitter` the log's own ticks scatter as much. It reports, without and with the widening
by the stamps' scatter (`tail_probability`, the diagnosis's `group_alpha`), how often no range
is found, the median width, and how often the range holds the true mean placement.

    python benchmarks/phase_range_jitter.py [--trials 200] [--frames 150] [--log-jitter]
"""

from __future__ import annotations

import argparse

import numpy as np

from dream.diagnosis.select import DiagnoseSettings
from dream.readings import clock_phase_range, log_clock, update_times

FRAME_PERIOD_S = 1.0 / 30.0
PERIOD_RANGE_S = (0.1, 0.3)
WHOLE_FRAMES_EVERY = 4          # every 4th log has a period of a whole number of frames
JITTERS_S = (0.0, 0.0001, 0.0003, 0.001, 0.002)
INSIDE_TOL_S = 1e-9


def _trial(rng: np.random.Generator, k: int, frames: int, jitter_s: float, log_jitter: bool):
    """(stamps, update frame indices, true mean placement lag), or None without a clock."""
    taken = np.arange(frames) * FRAME_PERIOD_S
    stamps = taken + rng.normal(0.0, jitter_s, frames)
    period = rng.uniform(*PERIOD_RANGE_S)
    if k % WHOLE_FRAMES_EVERY == 0:
        period = round(period / FRAME_PERIOD_S) * FRAME_PERIOD_S
    ticks = taken[0] - rng.uniform(0.0, period) + period * np.arange(1, frames)
    if log_jitter:
        ticks = ticks + rng.normal(0.0, jitter_s, len(ticks))
    ticks = np.sort(ticks[ticks <= taken[-1]])
    shown, first = np.unique(np.searchsorted(taken, ticks), return_index=True)
    later = shown > 0
    index = np.concatenate([[0], shown[later]])
    if log_clock(stamps, index) is None:
        return None
    lag = float(np.mean(update_times(stamps, index)[1:] - ticks[first][later]))
    return stamps, index, lag


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--log-jitter", action="store_true")
    args = parser.parse_args()
    alpha = DiagnoseSettings().group_alpha
    print("| stamp jitter | logs with a clock | widened | no range | median width | "
          "holds the true placement |")
    print("|---|---|---|---|---|---|")
    for jitter in JITTERS_S:
        rng = np.random.default_rng(args.seed)
        trials = [t for k in range(args.trials)
                  if (t := _trial(rng, k, args.frames, jitter, args.log_jitter)) is not None]
        for tail in (None, alpha):
            ranges = [clock_phase_range(s, i, tail) for s, i, _ in trials]
            found = [(r, lag) for r, (_, _, lag) in zip(ranges, trials, strict=True)
                     if r is not None]
            widths = [1e3 * (hi - lo) for (lo, hi), _ in found]
            inside = sum(lo - INSIDE_TOL_S <= lag <= hi + INSIDE_TOL_S
                         for (lo, hi), lag in found)
            print(f"| {jitter * 1e3:.1f} ms | {len(trials)} | {'yes' if tail else 'no'} | "
                  f"{len(trials) - len(found)} | {np.median(widths):.1f} ms | "
                  f"{inside} of {len(found)} |")


if __name__ == "__main__":
    main()
