"""Greedy forward selection of the effects the data supports, judged on held-out frames.

For the current model (at first the baseline: the extrinsic alone) every remaining effect of the
catalog is added in turn (`dream.diagnosis.select.prune.try_effect`). The effect is significant
only when (1) the held-out cost per frame falls with a one-sided paired t-test p-value below
`alpha`, (2) the BIC falls by more than `bic_margin`, and (3) the held-out RMSE falls by at least
`min_relative_gain`, with every fitted effect physically plausible, and (4) no `veto` from
other evidence (the images: `dream.diagnosis.images.OutlineJudge.veto`). The most helpful
significant effect is accepted, the groups of the accepted effects that it has made redundant
are dropped (`dream.diagnosis.select.prune.prune_accepted`), and the search repeats on top of
the result; on data without an effect the verdict is empty.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from dream.diagnosis.fit.model import FitResult, Model, fit_model
from dream.diagnosis.fit.problem import Problem
from dream.diagnosis.select.crossval import Evaluation, evaluate
from dream.diagnosis.select.plausible import first_implausible, implausible_effect
from dream.diagnosis.select.prune import prune_accepted, redundant_effects, try_effect
from dream.diagnosis.select.settings import DiagnoseSettings
from dream.extended import distinct_readings
from dream.extension import ModelExtension

log = logging.getLogger(__name__)

_FIRST_FIT_SCALE_PX = 3.0   # Huber scale of the first fit (at least `min_huber_scale_px`)
_MAD_TO_SIGMA = 1.4826      # median absolute deviation -> standard deviation of a Gaussian


@dataclass(frozen=True)
class Verdict:
    """One effect tested against the model it was added to."""

    name: str
    evaluation: Evaluation | None
    significant: bool
    evidence: str
    p_value: float = float("nan")
    bic_delta: float = float("nan")
    round: int = 0


@dataclass
class Diagnosis:
    """The outcome of `diagnose`."""

    baseline: Evaluation
    final: Evaluation
    accepted: list[str]
    tested: list[Verdict]
    extension: ModelExtension
    mask: np.ndarray
    scale_px: float
    seconds: float
    notes: list[str] = field(default_factory=list)
    alternatives: dict[str, list[str]] = field(default_factory=dict)
    baseline_as_logged: Evaluation | None = None   # with held readings: before interpolating
    dropped_later: dict[str, list[str]] = field(default_factory=dict)  # effect -> groups
    step_fits: list[FitResult] = field(default_factory=list)  # after each accepted effect


def _motion_rad_s(problem: Problem) -> float:
    """Median over the joint readings (repeated stale readings dropped) of the fastest joint's
    speed, rad/s."""
    if problem.times_s is None or problem.num_frames < 3:
        return 0.0
    t, q = distinct_readings(problem.times_s, problem.joints)
    if len(t) < 2:
        return 0.0
    speed = np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None]
    return float(np.median(speed.max(axis=1)))


def applicable(effect: str, problem: Problem, settings: DiagnoseSettings) -> str | None:
    """Why `effect` cannot be tested on this data (None when it can)."""
    if effect == "time_offset":
        if problem.times_s is None:
            return "the data has no timestamps"
        motion = _motion_rad_s(problem)
        if motion < settings.min_motion_rad_s:
            return (f"the joints barely move between frames (median fastest joint "
                    f"{motion:.3g} rad/s < {settings.min_motion_rad_s})")
    if effect == "camera_moved" and problem.num_frames < 2 * settings.min_segment_frames + 1:
        return f"{problem.num_frames} frames are too few to locate a move"
    return None


def _compare(current: Evaluation, candidate: Evaluation, mask: np.ndarray, scale_px: float,
             settings: DiagnoseSettings) -> tuple[bool, str, float, float]:
    """Whether `candidate` beats `current` (held-out test, BIC, RMSE gain): (significant,
    evidence, p-value, BIC change)."""
    d = current.heldout_cost - candidate.heldout_cost
    d = d[current.heldout_n > 0]
    if len(d) < 3 or np.all(d == d[0]):
        p = 1.0 if len(d) < 3 or d[0] <= 0 else 0.0
    else:
        t = float(np.mean(d) / (np.std(d, ddof=1) / np.sqrt(len(d))))
        p = float(stats.t.sf(t, len(d) - 1))
    bic_delta = candidate.fit.bic(mask, scale_px) - current.fit.bic(mask, scale_px)
    gain = 1 - candidate.heldout_rmse_px / current.heldout_rmse_px
    significant = (p < settings.alpha and bic_delta < -settings.bic_margin
                   and gain >= settings.min_relative_gain)
    evidence = (f"held-out RMSE {current.heldout_rmse_px:.3f} -> {candidate.heldout_rmse_px:.3f}"
                f" px ({100 * gain:+.1f} %), paired held-out test p = {p:.2g} over {len(d)} "
                f"frames, BIC change {bic_delta:+.1f}")
    return significant, evidence, p, bic_delta


def _gross_mask(problem: Problem, residual: np.ndarray,
                settings: DiagnoseSettings) -> np.ndarray:
    """Observations whose (F, K, 2) residual lies within the gross-outlier limit."""
    limit = settings.gross_outlier_fraction * np.hypot(problem.camera.width,
                                                       problem.camera.height)
    dist = np.linalg.norm(residual, axis=-1)
    return problem.observed & np.isfinite(dist) & (dist <= limit)


def _first_fit(problem: Problem, T_cam_base_init: np.ndarray,
               settings: DiagnoseSettings) -> tuple[FitResult, np.ndarray, float]:
    """The robust fit of the extrinsic alone from `T_cam_base_init`, the gross-outlier mask at
    it and the Huber scale of the diagnosis: (fit, mask, scale_px)."""
    # the gross outliers are first cut at the robust starting extrinsic: a Huber fit over every
    # detection is pulled away by many wrong ones (a detector that puts the wrist on a held
    # board), and a cut after such a fit keeps them
    start = Model(problem, (), T_cam_base_init)
    near = _gross_mask(problem, problem.uv - start.predict(np.zeros(start.size)), settings)
    if near.sum() < start.size:   # a start too poor to cut at: begin with every detection
        near = problem.observed
    first = fit_model(start, near, scale_px=max(settings.min_huber_scale_px, _FIRST_FIT_SCALE_PX))
    mask = _gross_mask(problem, first.residual, settings)
    sigma = _MAD_TO_SIGMA * float(np.median(np.abs(first.residual[mask])))
    scale = max(settings.min_huber_scale_px, settings.huber_scale_sigmas * sigma)
    return first, mask, scale


Veto = Callable[[FitResult, FitResult], "str | None"]   # (candidate, current) -> why not


def _test_round(round_: int, remaining: list[str], current: Evaluation, accepted: list[str],
                mask: np.ndarray, scale_px: float, settings: DiagnoseSettings,
                say: Callable[[str], None], veto: Veto | None = None) -> list[Verdict]:
    """The verdict of every remaining effect added to `current`, in the order tested; a
    significant effect that `veto` objects to is not significant."""
    problem = current.fit.model.problem
    verdicts = []
    for effect in remaining:
        outcome = try_effect(effect, current, problem, mask, scale_px, settings)
        if isinstance(outcome, str):
            verdicts.append(Verdict(effect, None, False, outcome, round=round_))
            say(f"round {round_}: {effect}: {outcome}")
            continue
        significant, evidence, p, bic_delta = _compare(current, outcome, mask, scale_px,
                                                       settings)
        # the new effect's fit must keep every effect plausible, the accepted ones too (their
        # parameters are refitted with it)
        why_not = first_implausible(outcome.fit, (effect, *accepted), settings.plausible)
        if why_not is None and significant and veto is not None:
            why_not = veto(outcome.fit, current.fit)
        if why_not is not None:
            significant, evidence = False, f"{why_not}; {evidence}"
        verdicts.append(Verdict(effect, outcome, significant, evidence, p, bic_delta, round_))
        say(f"round {round_}: {effect}: {'SIGNIFICANT ' if significant else ''}{evidence}")
    return verdicts


def _equivalent(best: Verdict, results: list[Verdict], settings: DiagnoseSettings) -> list[str]:
    """The significant effects other than `best` that predict the held-out frames as well."""
    return [v.name for v in results if v is not best and v.evaluation.heldout_rmse_px
            <= best.evaluation.heldout_rmse_px * (1 + settings.equivalence_tol)]


def diagnose(problem: Problem, T_cam_base_init: np.ndarray,
             settings: DiagnoseSettings | None = None, progress=None,
             veto: Veto | None = None) -> Diagnosis:
    """Greedy, cross-validated search of the effects the data supports.

    Args:
        problem: the measured data.
        T_cam_base_init: a starting extrinsic (e.g. the robust `calibrate_all` solution).
        settings: the constants (`DiagnoseSettings()` by default).
        progress: optional callable(str) told about each step.
        veto: optional callable(candidate fit, current fit) -> why the effect is not accepted
            though significant (other evidence contradicts it), or None.
    """
    settings = settings or DiagnoseSettings()
    say = progress or (lambda message: log.info(message))
    started = time.perf_counter()
    first, mask, scale = _first_fit(problem, T_cam_base_init, settings)
    baseline = evaluate("baseline", Model(problem, (), first.T_cam_base), mask, scale, settings)
    say(f"baseline: RMSE {baseline.heldout_rmse_px:.3f} px held out "
        f"({int(mask.sum())} keypoints of {problem.num_frames} frames)")
    current = baseline
    accepted: list[str] = []
    tested: list[Verdict] = []
    notes: list[str] = []
    alternatives: dict[str, list[str]] = {}
    dropped_later: dict[str, list[str]] = {}
    step_fits: list[FitResult] = []
    # held_readings is read from the data before the search (dream.diagnosis.held)
    remaining = [e for e in settings.effects if e != "held_readings"]
    for effect in list(remaining):
        why = applicable(effect, problem, settings)
        if why is not None:
            tested.append(Verdict(effect, None, False, f"not testable: {why}"))
            remaining.remove(effect)
    for round_ in range(1, settings.max_rounds + 1):
        if not remaining:
            break
        verdicts = _test_round(round_, remaining, current, accepted, mask, scale, settings, say,
                               veto)
        tested.extend(verdicts)
        results = [v for v in verdicts if v.significant]
        if not results:
            break
        best = min(results, key=lambda v: v.bic_delta)  # equal fits: the fewer parameters
        close = _equivalent(best, results, settings)
        if close:
            alternatives[best.name] = close
            notes.append(f"{best.name} was chosen, but {', '.join(close)} explain(s) the "
                         f"held-out frames as well (within {100 * settings.equivalence_tol:g} %):"
                         f" this data cannot tell them apart")
        accepted.append(best.name)
        remaining.remove(best.name)
        current, dropped = prune_accepted(best.evaluation, accepted, mask, scale, settings)
        if dropped:
            notes.append(f"with {best.name} accepted, these parameter groups no longer differ "
                         f"from zero (p > {settings.group_alpha:g}) and were dropped: "
                         f"{'; '.join(f'{e}: {g}' for e, g in dropped)}")
            say(notes[-1])
            for effect, group in dropped:
                dropped_later.setdefault(effect, []).append(group)
        current, baseline, mask, note = refit_on_new_mask(problem, current, baseline,
                                                          mask, accepted, scale, settings)
        if note is not None:
            notes.append(note)
            say(note)
        step_fits.append(current.fit)
    for effect in redundant_effects(current.fit, accepted, settings.group_alpha):
        notes.append(f"{effect} no longer differs from zero beside the effects accepted after "
                     f"it (p > {settings.group_alpha:g}); it stays, as it was accepted on the "
                     f"held-out frames, but the later effects may explain what it did")
        say(notes[-1])
    extension = current.fit.model.extension(current.fit.x)
    return Diagnosis(baseline, current, accepted, tested, extension, mask, scale,
                     time.perf_counter() - started, notes, alternatives,
                     dropped_later=dropped_later, step_fits=step_fits)


def refit_on_new_mask(problem: Problem, current: Evaluation, baseline: Evaluation,
                      mask: np.ndarray, accepted: list[str], scale_px: float,
                      settings: DiagnoseSettings
                      ) -> tuple[Evaluation, Evaluation, np.ndarray, str | None]:
    """After an effect is accepted: the gross-outlier mask at its fit, and `current` and
    `baseline` refitted on it when it changed. A refit that would carry an accepted effect
    beyond its plausible size (`implausible`) is not taken: the previous mask and fits stay,
    with a note saying why. Returns (current, baseline, mask, note or None)."""
    new_mask = _gross_mask(problem, current.fit.residual, settings)
    if np.array_equal(new_mask, mask):
        return current, baseline, mask, None
    refit = evaluate(current.name, current.fit.model, new_mask, scale_px, settings,
                     x0=current.fit.x, identifiability=current.identifiability,
                     pruned=current.pruned)
    found = implausible_effect(refit.fit, accepted, settings.plausible)
    if found is not None:
        return current, baseline, mask, (
            f"the refit on the outlier mask of the accepted model ({int(new_mask.sum())} "
            f"instead of {int(mask.sum())} keypoints) was not taken: {found[0]}: {found[1]}")
    baseline = evaluate("baseline", baseline.fit.model, new_mask, scale_px, settings,
                        x0=baseline.fit.x)
    return refit, baseline, new_mask, None
