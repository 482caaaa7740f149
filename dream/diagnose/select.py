"""Model selection: which effects the data supports, judged on frames held out of the fit.

For the current model (at first the baseline: the extrinsic alone) every remaining effect of the
catalog is added in turn: its identifiable parameters are fitted jointly with the extrinsic and
the accepted effects over all frames, parameter groups that do not differ from zero are pruned,
and the model is cross-validated by frames (interleaved folds). The effect is significant only
when (1) the held-out cost per frame falls with a one-sided paired t-test p-value below
`alpha`, (2) the BIC falls by more than `bic_margin`, and (3) the held-out RMSE falls by at least
`min_relative_gain`. The most helpful significant effect is accepted and the search repeats on
top of it (greedy forward selection); on data without an effect the verdict is empty.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from dream.diagnose.fit import (
    FitResult,
    Identifiability,
    Model,
    Param,
    Problem,
    candidate_params,
    fit_model,
    group_p_values,
    huber_rho,
    identifiable_params,
)
from dream.errors import InputError
from dream.extension import EFFECT_NAMES, ModelExtension, distinct_readings

log = logging.getLogger(__name__)

# Effects whose parameter groups are chosen by forward selection (see _forward_groups): their
# groups are strongly correlated (k1 / k2), nearly unidentifiable in
# combination (link lengths), or numerous enough to mimic other effects (keypoint biases).
FORWARD_EFFECTS = ("link_length", "lens_distortion", "keypoint_bias")
PLAUSIBLE = {                      # largest plausible magnitude of each kind of parameter
    "joint_offset": np.deg2rad(10.0),  # rad: encoder zero errors are a few degrees at most
    "link_length": 0.05,               # m
    "keypoint_bias": 0.05,             # m (norm of a keypoint's offset)
    "lens_distortion.k": 0.5,          # k1, k2 (changes)
    "lens_distortion.p": 0.05,         # p1, p2 (changes)
    "intrinsics_error.f": 0.2,         # relative focal length change
    "intrinsics_error.c": 0.1,         # principal point change / focal length
    "time_offset": 0.5,                # s
    "camera_moved.r": np.deg2rad(10.0),  # rad (rotation vector norm)
    "camera_moved.t": 0.2,             # m (translation norm)
}


def implausible_effect(fit: FitResult, effects: SequenceOf[str],
                       limits: dict) -> tuple[str, str] | None:
    """The first of `effects` whose fitted parameters are implausible (`implausible`), and why."""
    for effect in effects:
        why = implausible(fit, effect, limits)
        if why is not None:
            return effect, why
    return None


def first_implausible(fit: FitResult, effects: tuple[str, ...], limits: dict) -> str | None:
    """`implausible` of the first of `effects` that is (its name prefixed after the first)."""
    found = implausible_effect(fit, effects, limits)
    if found is None:
        return None
    effect, why = found
    return why if effect == effects[0] else f"{effect}: {why}"


def implausible(fit: FitResult, effect: str, limits: dict) -> str | None:
    """Why the fitted parameters of `effect` are beyond physical plausibility (None: fine)."""
    params = [(p, fit.x[6 + i]) for i, p in enumerate(fit.model.params) if p.effect == effect]
    groups: dict[str, list[float]] = {}
    for p, v in params:
        if effect == "lens_distortion":
            kind = "lens_distortion.k" if p.name in ("k1", "k2") else "lens_distortion.p"
        elif effect == "intrinsics_error":
            kind = "intrinsics_error.f" if p.name in ("fx", "fy") else "intrinsics_error.c"
        elif effect == "camera_moved":
            kind = "camera_moved.r" if p.name[-2] == "r" else "camera_moved.t"
        else:
            kind = effect
        key = (kind, p.group) if effect in ("keypoint_bias", "camera_moved") else (kind, p.name)
        groups.setdefault(key, []).append(float(v))
    for (kind, name), values in groups.items():
        size = float(np.linalg.norm(values))
        if kind in limits and size > limits[kind]:
            return (f"implausible magnitude: {name} = {size:.3g} > {limits[kind]:.3g} "
                    f"({kind}); the misfit looks like wrong detections, not a model effect")
    return None


@dataclass(frozen=True)
class DiagnoseSettings:
    """Every constant of the diagnosis.

    Attributes:
        effects: catalog effects to test.
        folds: cross-validation folds (frames interleaved: frame i in fold i mod folds).
        alpha: one-sided p-value threshold of the paired held-out test.
        bic_margin: the BIC must fall by more than this.
        min_relative_gain: the held-out RMSE must fall by at least this fraction.
        group_alpha: a parameter group (a joint, a keypoint, k1...) is kept only when its
            chi-square test against zero has a p-value below this.
        huber_scale_sigmas: Huber scale = this x the robust residual sigma of the baseline.
        min_huber_scale_px: lower bound of the Huber scale.
        gross_outlier_fraction: observations farther than this fraction of the image diagonal
            from the current model's prediction are left out (wrong detections).
        min_effect_px: identifiability: a parameter at its typical magnitude must move the
            prediction by at least this RMS.
        collinearity_tol: identifiability: fraction of that motion the extrinsic and the other
            parameters must leave unexplained.
        min_segment_frames: camera_moved: frames on each side of the move.
        clear_null_p: groups with a p-value above this are pruned together before the
            one-at-a-time backward elimination of the rest.
        min_motion_rad_s: time_offset is tested only when the joints move at least this fast
            (median over the distinct joint readings of the fastest joint).
        max_rounds: at most this many effects are accepted.
        equivalence_tol: significant effects whose held-out RMSE is within this fraction of
            the accepted one's are reported as equivalent alternatives.
        plausible: largest physically plausible magnitude per parameter kind (rad, m, s, or a
            fraction): an effect fitted beyond it is not accepted (its "gain" is the fit
            absorbing wrong detections, not a property of the robot or camera).
    """

    effects: tuple[str, ...] = EFFECT_NAMES
    folds: int = 5
    alpha: float = 0.01
    bic_margin: float = 10.0
    min_relative_gain: float = 0.002
    group_alpha: float = 1e-3
    huber_scale_sigmas: float = 2.0
    min_huber_scale_px: float = 0.5
    gross_outlier_fraction: float = 0.08
    min_effect_px: float = 0.02
    collinearity_tol: float = 0.05
    min_segment_frames: int = 5
    clear_null_p: float = 0.2
    min_motion_rad_s: float = 0.05
    max_rounds: int = 4
    equivalence_tol: float = 0.01
    plausible: dict = field(default_factory=lambda: dict(PLAUSIBLE))

    def __post_init__(self) -> None:
        unknown = [e for e in self.effects if e not in EFFECT_NAMES]
        if unknown:
            raise InputError(f"unknown effects {unknown}", fix=f"use {', '.join(EFFECT_NAMES)}")
        if self.folds < 2:
            raise InputError(f"folds must be >= 2, got {self.folds}")
        for name in ("alpha", "group_alpha"):
            if not 0 < getattr(self, name) < 1:
                raise InputError(f"{name} must be in (0, 1)")
        for name in ("bic_margin", "min_relative_gain", "huber_scale_sigmas",
                     "min_huber_scale_px", "gross_outlier_fraction", "min_effect_px",
                     "collinearity_tol"):
            if not getattr(self, name) >= 0:
                raise InputError(f"{name} must be >= 0")


@dataclass(frozen=True)
class Evaluation:
    """A candidate model fitted on all frames and cross-validated."""

    name: str                       # the effect added ("baseline" for none)
    fit: FitResult
    heldout_cost: np.ndarray        # (F,) Huber cost of each frame when held out
    heldout_sq: np.ndarray          # (F,) sum of squared residuals of each frame held out
    heldout_n: np.ndarray           # (F,) residual components of each frame
    identifiability: Identifiability | None = None
    pruned: tuple[str, ...] = ()

    @property
    def heldout_rmse_px(self) -> float:
        """RMS pixel distance over the held-out keypoints."""
        n = self.heldout_n.sum()
        return float(np.sqrt(2 * self.heldout_sq.sum() / n)) if n else float("nan")


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


def _folds(num_frames: int, folds: int) -> np.ndarray:
    return np.arange(num_frames) % folds


def _frame_sums(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(F,) sums over the masked keypoints (both pixel components) of (F, K, 2) values."""
    return np.where(mask[..., None], values, 0.0).sum(axis=(1, 2))


def cross_validate(fit: FitResult, mask: np.ndarray, scale_px: float, settings: DiagnoseSettings,
                   rescan_change: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame held-out Huber cost, squared error and residual count of `fit`'s model."""
    problem = fit.model.problem
    F = problem.num_frames
    fold = _folds(F, settings.folds)
    cost, sq, n = np.zeros(F), np.zeros(F), np.zeros(F)
    for k in range(settings.folds):
        held = fold == k
        train = mask & ~held[:, None]
        model = fit.model
        if rescan_change:
            model = best_change(problem, fit, train, scale_px, settings)
        sub = fit_model(model, train, scale_px, x0=fit.x, max_evaluations=20)
        r = np.where(np.isfinite(sub.residual), sub.residual, 0.0)
        test = mask & held[:, None]
        cost[held] = _frame_sums(huber_rho(r, scale_px), test)[held]
        sq[held] = _frame_sums(r * r, test)[held]
        n[held] = 2 * test.sum(axis=1)[held]
    return cost, sq, n


def evaluate(name: str, model: Model, mask: np.ndarray, scale_px: float,
             settings: DiagnoseSettings, x0: np.ndarray | None = None,
             identifiability: Identifiability | None = None,
             pruned: tuple[str, ...] = ()) -> Evaluation:
    fit = fit_model(model, mask, scale_px, x0=x0)
    rescan = model.change_index is not None
    cost, sq, n = cross_validate(fit, mask, scale_px, settings, rescan)
    return Evaluation(name, fit, cost, sq, n, identifiability, pruned)


def best_change(problem: Problem, fit: FitResult, mask: np.ndarray, scale_px: float,
                settings: DiagnoseSettings) -> Model:
    """The camera_moved model of `fit` with the change frame that fits `mask` best.

    Every candidate frame is scored in one pass by the linearised fit at `fit`'s solution: the
    model's parameters for all frames plus a camera move for the frames from the candidate on
    (normal equations from per-frame prefix sums, Huber weights of the current residuals).
    """
    F = problem.num_frames
    lo, hi = settings.min_segment_frames, F - settings.min_segment_frames
    if hi <= lo:
        raise InputError(f"{F} frames are too few to locate a camera move")
    base = fit.model
    move = tuple(candidate_params("camera_moved", problem))
    own = tuple(p for p in base.params if p.effect != "camera_moved")
    keep = [i for i, p in enumerate(base.params) if p.effect != "camera_moved"]
    x = np.concatenate([fit.x[:6], fit.x[6:][keep], np.zeros(len(move))])
    model = Model(problem, own + move, base.T0, 0)
    use = mask & problem.observed
    J = model.jacobian(x, use)
    r = (problem.uv - model.predict(x))[use].ravel()
    w = np.minimum(1.0, scale_px / np.maximum(np.abs(r), 1e-12))
    frame_of_row = np.repeat(np.nonzero(use)[0], 2)
    n = J.shape[1]
    A = np.zeros((F, n, n))
    b = np.zeros((F, n))
    np.add.at(A, frame_of_row, (w[:, None, None] * J[:, :, None] * J[:, None, :]))
    np.add.at(b, frame_of_row, w[:, None] * J * r[:, None])
    total_A, total_b = A.sum(0), b.sum(0)
    tail_A = np.cumsum(A[::-1], axis=0)[::-1]   # tail_A[m] = sum over frames >= m
    tail_b = np.cumsum(b[::-1], axis=0)[::-1]
    m_cols = slice(n - len(move), n)
    g_cols = slice(0, n - len(move))
    best, best_gain = lo, -np.inf
    for m in range(lo, hi + 1):
        N = total_A.copy()
        N[m_cols, :] = tail_A[m][m_cols, :]
        N[:, m_cols] = tail_A[m][:, m_cols]
        N[g_cols, g_cols] = total_A[g_cols, g_cols]
        rhs = total_b.copy()
        rhs[m_cols] = tail_b[m][m_cols]
        try:
            gain = float(rhs @ np.linalg.solve(N, rhs))
        except np.linalg.LinAlgError:
            continue
        if gain > best_gain:
            best, best_gain = m, gain
    return Model(problem, base.params, base.T0, best)


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


def _try_effect(effect: str, current: Evaluation, problem: Problem, mask: np.ndarray,
                scale_px: float, settings: DiagnoseSettings) -> Evaluation | str:
    """The current model plus `effect`, fitted, pruned and cross-validated; or why not."""
    base = current.fit
    candidates = candidate_params(effect, problem)
    forward = effect in FORWARD_EFFECTS
    ident = identifiable_params(problem, base, candidates, mask, settings.min_effect_px,
                                settings.collinearity_tol, against_each_other=not forward)
    if not ident.kept:
        return "no identifiable parameter: " + "; ".join(
            f"{k}: {v}" for k, v in ident.dropped.items())
    if forward:
        outcome = _forward_groups(effect, base, list(ident.kept), problem, mask, scale_px,
                                  settings)
        if isinstance(outcome, str):
            return outcome
        cost, sq, n = cross_validate(outcome, mask, scale_px, settings,
                                     rescan_change=outcome.model.change_index is not None)
        return Evaluation(effect, outcome, cost, sq, n, ident, ())
    params = list(ident.kept)
    pruned: list[str] = []
    change = base.model.change_index
    while True:
        x0 = np.concatenate([base.x, np.zeros(len(params))])
        all_params = base.model.params + tuple(params)
        if effect == "camera_moved":
            probe = FitResult(Model(problem, all_params, base.model.T0, 0), x0,
                              np.empty((0, 0)), base.residual, base.cost, base.num_points)
            model = best_change(problem, probe, mask, scale_px, settings)
            change = model.change_index
        else:
            model = Model(problem, all_params, base.model.T0, change)
        fit = fit_model(model, mask, scale_px, x0=x0)
        p_values = group_p_values(fit, effect)
        worst = max(p_values, key=p_values.get)
        if p_values[worst] <= settings.group_alpha:
            break
        drop = {g for g, v in p_values.items() if v > settings.clear_null_p} or {worst}
        if len(drop) == len(p_values):
            drop = {worst}
        pruned.extend(sorted(drop))
        params = [p for p in params if p.group not in drop]
        if not params:
            return (f"no parameter differs significantly from zero (group p-values "
                    f"{', '.join(f'{g} {v:.2g}' for g, v in p_values.items())})")
    cost, sq, n = cross_validate(fit, mask, scale_px, settings,
                                 rescan_change=model.change_index is not None)
    return Evaluation(effect, fit, cost, sq, n, ident, tuple(pruned))


def _forward_groups(effect: str, base: FitResult, params: list[Param], problem: Problem,
                    mask: np.ndarray, scale_px: float,
                    settings: DiagnoseSettings) -> FitResult | str:
    """Forward selection of `effect`'s parameter groups: add the group that lowers the cost
    most while its p-value stays below `group_alpha`. Used where combinations of groups are
    (nearly) unidentifiable, e.g. link lengths: stretching every link in proportion scales the
    robot, which a camera farther away absorbs exactly; the sparsest explanation is kept."""
    groups = list(dict.fromkeys(p.group for p in params))
    chosen: list[str] = []
    best_fit: FitResult | None = None
    while len(chosen) < len(groups):
        trials = []
        for g in groups:
            if g in chosen:
                continue
            kept = [p for c in chosen for p in params if p.group == c]
            added = [p for p in params if p.group == g]
            model = Model(problem, base.model.params + tuple(kept + added), base.model.T0,
                          base.model.change_index)
            start = base.x if best_fit is None else best_fit.x
            x0 = np.concatenate([start, np.zeros(len(added))])
            trials.append((g, fit_model(model, mask, scale_px, x0=x0)))
        g, fit = min(trials, key=lambda t: t[1].cost)
        if group_p_values(fit, effect)[g] > settings.group_alpha:
            break
        chosen.append(g)
        best_fit = fit
    if best_fit is None:
        return "no parameter group differs significantly from zero"
    return best_fit


def _compare(current: Evaluation, candidate: Evaluation, mask: np.ndarray, scale_px: float,
             settings: DiagnoseSettings) -> tuple[bool, str, float, float]:
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


def diagnose(problem: Problem, T_cam_base_init: np.ndarray,
             settings: DiagnoseSettings | None = None, progress=None) -> Diagnosis:
    """Greedy, cross-validated search of the effects the data supports.

    Args:
        problem: the measured data.
        T_cam_base_init: a starting extrinsic (e.g. the robust `calibrate_all` solution).
        settings: the constants (`DiagnoseSettings()` by default).
        progress: optional callable(str) told about each step.
    """
    settings = settings or DiagnoseSettings()
    say = progress or (lambda message: log.info(message))
    started = time.perf_counter()
    # the gross outliers are first cut at the robust starting extrinsic: a Huber fit over every
    # detection is pulled away by many wrong ones (a detector that puts the wrist on a held
    # board), and a cut after such a fit keeps them
    start = Model(problem, (), T_cam_base_init)
    near = _gross_mask(problem, problem.uv - start.predict(np.zeros(start.size)), settings)
    if near.sum() < start.size:   # a start too poor to cut at: begin with every detection
        near = problem.observed
    first = fit_model(start, near, scale_px=max(settings.min_huber_scale_px, 3.0))
    mask = _gross_mask(problem, first.residual, settings)
    sigma = 1.4826 * float(np.median(np.abs(first.residual[mask])))
    scale = max(settings.min_huber_scale_px, settings.huber_scale_sigmas * sigma)
    baseline = evaluate("baseline", Model(problem, (), first.T_cam_base), mask, scale, settings)
    say(f"baseline: RMSE {baseline.heldout_rmse_px:.3f} px held out "
        f"({int(mask.sum())} keypoints of {problem.num_frames} frames)")
    current = baseline
    accepted: list[str] = []
    tested: list[Verdict] = []
    notes: list[str] = []
    alternatives: dict[str, list[str]] = {}
    remaining = [e for e in settings.effects]
    for effect in list(remaining):
        why = applicable(effect, problem, settings)
        if why is not None:
            tested.append(Verdict(effect, None, False, f"not testable: {why}"))
            remaining.remove(effect)
    for round_ in range(1, settings.max_rounds + 1):
        if not remaining:
            break
        results = []
        for effect in remaining:
            outcome = _try_effect(effect, current, problem, mask, scale, settings)
            if isinstance(outcome, str):
                tested.append(Verdict(effect, None, False, outcome, round=round_))
                say(f"round {round_}: {effect}: {outcome}")
                continue
            significant, evidence, p, bic_delta = _compare(current, outcome, mask, scale,
                                                           settings)
            # the new effect's fit must keep every effect plausible, the accepted ones too (their
            # parameters are refitted with it)
            why_not = first_implausible(outcome.fit, (effect, *accepted), settings.plausible)
            if why_not is not None:
                significant, evidence = False, f"{why_not}; {evidence}"
            verdict = Verdict(effect, outcome, significant, evidence, p, bic_delta, round_)
            tested.append(verdict)
            say(f"round {round_}: {effect}: {'SIGNIFICANT ' if significant else ''}{evidence}")
            if significant:
                results.append(verdict)
        if not results:
            break
        best = min(results, key=lambda v: v.bic_delta)  # equal fits: the fewer parameters
        close = [v.name for v in results if v is not best and v.evaluation.heldout_rmse_px
                 <= best.evaluation.heldout_rmse_px * (1 + settings.equivalence_tol)]
        if close:
            alternatives[best.name] = close
            notes.append(f"{best.name} was chosen, but {', '.join(close)} explain(s) the "
                         f"held-out frames as well (within {100 * settings.equivalence_tol:g} %):"
                         f" this data cannot tell them apart")
        accepted.append(best.name)
        remaining.remove(best.name)
        current, baseline, mask, note = refit_on_new_mask(problem, best.evaluation, baseline,
                                                          mask, accepted, scale, settings)
        if note is not None:
            notes.append(note)
            say(note)
    extension = current.fit.model.extension(current.fit.x)
    return Diagnosis(baseline, current, accepted, tested, extension, mask, scale,
                     time.perf_counter() - started, notes, alternatives)


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


def param_table(fit: FitResult) -> list[dict[str, Any]]:
    """Rows (effect, name, value, sigma, typical) of a fitted model's effect parameters."""
    rows = []
    sigma = fit.sigma
    for i, p in enumerate(fit.model.params):
        rows.append({"effect": p.effect, "group": p.group, "name": p.name,
                     "value": float(fit.x[6 + i]), "sigma": float(sigma[6 + i])})
    return rows


def params_of(fit: FitResult, effect: str) -> tuple[list[Param], np.ndarray, np.ndarray]:
    idx = [i for i, p in enumerate(fit.model.params) if p.effect == effect]
    return ([fit.model.params[i] for i in idx], fit.x[[6 + i for i in idx]],
            fit.sigma[[6 + i for i in idx]])
