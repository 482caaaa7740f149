"""Identification rate of `dream diagnose` on sequences with hidden effects.

Each trial draws a keypoint-only measured-like sequence (`dream.inject`: a fixed camera, a
smooth random arm trajectory, 1-2 px label noise) with one hidden effect of the catalog (random
magnitude in a realistic range, `random_effects`), held readings with a time offset, two
effects together, or none, runs the
diagnosis (labels as observations) and scores it (`dream.diagnosis.score`): identified = the
verdict names the hidden effects and recovers their parameters within 10 % or 3 stated sigmas;
exact = that, and nothing else in the verdict. Null trials must give an empty verdict.

Each trial also states the signal its hidden effects leave in the keypoints: the same sequence
without label noise, fitted with one extrinsic (and the held readings interpolated, as the
diagnosis does), leaves residuals r; signal = sum(r^2) / noise^2, the expected chi-square
drop of the true model over the baseline (the noncentrality). Below a few tens no test at the
diagnosis's false-alarm level can name the effect reliably; the table splits the rates there
(held readings alone are read from the data, not from this signal, and are left out of it).
It ends with a check of the stated sigmas: (estimate - truth) / sigma over every parameter of
the named effects, which has unit spread where they are honest.

A trial with held readings films at 30 frames/s (a joint log of 3-10 Hz against the camera)
for as long as the others (`--frames` at 10 frames/s).

    python benchmarks/diagnose_identification.py [--trials-per-effect 12] [--null-trials 16]
        [--pair-trials 8] [--seed 0] [--frames 100] [--workers 2] [--only EFFECT,...]
        [--json OUT.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy import stats

from dream.calibration import Observations  # noqa: F401  (imported for workers' warm-up)
from dream.diagnosis.fit.model import Model, fit_model
from dream.diagnosis.held import corrected_problem, held_readings_in
from dream.diagnosis.run import diagnose_sequence, problem_from
from dream.diagnosis.score import score_diagnosis
from dream.extension import EFFECT_NAMES, ModelExtension
from dream.inject import InjectionSettings, make_injected_sequence, random_effects
from dream.pipeline import observations_from_labels, robot_for, truth_poses
from dream.robot import load_robot

NOISE_RANGE_PX = (1.0, 2.0)
HELD_FRAME_PERIOD_S = 1 / 30   # the camera of a trial with held readings
BASE_FRAME_PERIOD_S = 0.1      # the other trials' (InjectionSettings' default)
HELD_WITH_OFFSET = ("held_readings", "time_offset")
SIGNAL_BINS = (25.0, 100.0)    # the table's signal classes: weak < 25 <= moderate < 100 <= strong
LEAST_SQUARES_SCALE_PX = 1e6   # a Huber scale no residual reaches: plain least squares


def effect_signal(spec: InjectionSettings, truth: ModelExtension) -> float:
    """The hidden effects' signal in the keypoints of `spec`'s sequence (module doc)."""
    clean = make_injected_sequence(dataclasses.replace(spec, pixel_noise_px=0.0), truth)
    robot = robot_for(clean, None, clean.keypoint_names)
    problem = problem_from(clean, robot, observations_from_labels(clean, robot))
    held = held_readings_in(problem)
    if held is not None:
        problem = corrected_problem(problem, held)
    fit = fit_model(Model(problem, (), truth_poses(clean)[0]), problem.observed,
                    LEAST_SQUARES_SCALE_PX)
    r = fit.residual[problem.observed]
    return float(np.sum(r * r) / spec.pixel_noise_px ** 2)


def signal_class(signal: float) -> str:
    weak, strong = SIGNAL_BINS
    if signal < weak:
        return f"signal < {weak:g}"
    return f"signal {weak:g}-{strong:g}" if signal < strong else f"signal >= {strong:g}"


def run_trial(effects: tuple[str, ...], seed: int, frames: int) -> dict:
    """One seeded trial: hidden `effects` (may be empty) -> scored diagnosis."""
    rng = np.random.default_rng(seed)
    period = HELD_FRAME_PERIOD_S if "held_readings" in effects else BASE_FRAME_PERIOD_S
    spec = InjectionSettings(num_frames=round(frames * BASE_FRAME_PERIOD_S / period),
                             frame_period_s=period,
                             pixel_noise_px=float(rng.uniform(*NOISE_RANGE_PX)), seed=seed)
    robot = load_robot(spec.robot)
    truth = random_effects(list(effects), rng, robot, spec) if effects else ModelExtension()
    seq = make_injected_sequence(spec, truth)
    robot = robot_for(seq, None, seq.keypoint_names)
    obs = observations_from_labels(seq, robot)
    started = time.perf_counter()
    doc, _, _ = diagnose_sequence(seq, robot, obs)
    seconds = time.perf_counter() - started
    score = score_diagnosis(truth, seq.camera, tuple(f.name for f in seq.frames), doc)
    identified = all(s.recovered for s in score["scores"]) if effects else not doc["verdict"]
    signal = effect_signal(spec, truth) if effects else 0.0
    return {"hidden": list(effects), "seed": seed, "noise_px": spec.pixel_noise_px,
            "signal": signal,
            "verdict": doc["verdict"], "identified": identified, "exact": score["exact"],
            "named": all(s.named for s in score["scores"]),
            "details": [f"{s.name}: {s.detail}" for s in score["scores"]],
            "extra": score["extra"], "seconds": seconds,
            "z": [v for s in score["scores"] for v in s.z],
            "gain": doc["gain"], "truth": doc.get("truth")}


def print_sigma_check(z: list[float]) -> None:
    """Whether the stated sigmas are honest: the spread of (estimate - truth) / sigma over every
    parameter of the effects named (unit and normal where they are)."""
    if not z:
        return
    a = np.abs(np.asarray(z))
    beyond2, beyond3 = 2 * stats.norm.sf(2.0), 2 * stats.norm.sf(3.0)   # two-sided, Gaussian
    print(f"stated sigmas: {len(a)} parameters of named effects, RMS (estimate - truth) / sigma "
          f"{np.sqrt(np.mean(a ** 2)):.2f} (honest: 1), beyond 2 sigma {np.mean(a > 2):.1%} "
          f"({beyond2:.1%}), beyond 3 sigma {int(np.sum(a > 3))} "
          f"({len(a) * beyond3:.1f} expected)")


def trials(args: argparse.Namespace) -> list[tuple[tuple[str, ...], int]]:
    out = []
    seed = args.seed * 100_000
    only = tuple(args.only.split(",")) if args.only else None
    for effects in [(e,) for e in EFFECT_NAMES] + [HELD_WITH_OFFSET]:
        for _ in range(args.trials_per_effect):
            seed += 1
            if only is None or set(effects) <= set(only):
                out.append((effects, seed))
    rng = np.random.default_rng(args.seed)
    for _ in range(args.pair_trials):
        seed += 1
        pair = tuple(rng.choice(EFFECT_NAMES, 2, replace=False).tolist())
        if only is None:
            out.append((pair, seed))
    for _ in range(args.null_trials):
        seed += 1
        if only is None:
            out.append(((), seed))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials-per-effect", type=int, default=12)
    parser.add_argument("--pair-trials", type=int, default=8)
    parser.add_argument("--null-trials", type=int, default=16)
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--only", help="comma-separated effects: only the trials hiding these "
                        "(no pairs, no null trials)")
    parser.add_argument("--json", type=Path, help="write every trial here")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    todo = trials(args)
    print(f"{len(todo)} trials, {args.frames} frames each, {args.workers} workers",
          flush=True)
    started = time.perf_counter()
    results = []
    with ProcessPoolExecutor(args.workers) as pool:
        futures = [pool.submit(run_trial, effects, seed, args.frames) for effects, seed in todo]
        for i, future in enumerate(futures):
            r = future.result()
            results.append(r)
            mark = "ok " if r["identified"] else "MISS"
            print(f"[{i + 1:3d}/{len(todo)}] {mark} hidden={','.join(r['hidden']) or 'none':32s}"
                  f" verdict={','.join(r['verdict']) or '[]':32s} {r['seconds']:.1f} s"
                  f" signal {r['signal']:.0f}",
                  flush=True)
            if not r["identified"]:
                for d in r["details"]:
                    print(f"        {d}", flush=True)
    print(f"\n{'hidden':34s} {'trials':>6s} {'named':>6s} {'identified':>10s} {'exact':>6s}")
    groups: dict[str, list[dict]] = {}
    for r in results:
        key = ("pair: " if len(r["hidden"]) == 2 else "") + (",".join(r["hidden"]) or "none")
        key = "pairs" if len(r["hidden"]) == 2 and tuple(r["hidden"]) != HELD_WITH_OFFSET \
            else key
        groups.setdefault(key, []).append(r)
    for key, rs in groups.items():
        n = len(rs)
        print(f"{key:34s} {n:6d} {sum(r['named'] or not r['hidden'] for r in rs) / n:6.0%} "
              f"{sum(r['identified'] for r in rs) / n:10.0%} "
              f"{sum(r['exact'] or (not r['hidden'] and not r['verdict']) for r in rs) / n:6.0%}")
    n = len(results)
    print(f"{'all':34s} {n:6d} {'':6s} {sum(r['identified'] for r in results) / n:10.0%}")
    hidden = [r for r in results if r["hidden"] and r["hidden"] != ["held_readings"]]
    for label in dict.fromkeys(signal_class(r["signal"]) for r in sorted(hidden, key=lambda
                                                                           r: r["signal"])):
        rs = [r for r in hidden if signal_class(r["signal"]) == label]
        print(f"{'hidden, ' + label:34s} {len(rs):6d} {'':6s} "
              f"{sum(r['identified'] for r in rs) / len(rs):10.0%}")
    print_sigma_check([v for r in results for v in r["z"]])
    print(f"median diagnosis time {np.median([r['seconds'] for r in results]):.1f} s; "
          f"wall {time.perf_counter() - started:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
