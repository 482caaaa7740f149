"""One effect added to the current model: its identifiable parameters, fitted, pruned to the
parameter groups that differ from zero, and cross-validated.

Groups are pruned by backward elimination (groups clearly null first, then the least
significant one at a time), or chosen by forward selection for `FORWARD_EFFECTS`. Once a later
effect is accepted, `prune_accepted` drops the groups of the accepted effects that it has made
redundant.
"""

from __future__ import annotations

import numpy as np

from dream.diagnosis.fit.identify import group_p_values, identifiable_params
from dream.diagnosis.fit.model import FitResult, Model, fit_model
from dream.diagnosis.fit.problem import Param, Problem, candidate_params
from dream.diagnosis.select.camera_move import best_change
from dream.diagnosis.select.crossval import Evaluation, cross_validate
from dream.diagnosis.select.plausible import first_implausible
from dream.diagnosis.select.settings import DiagnoseSettings

# Effects whose parameter groups are chosen by forward selection (`_forward_groups`): their
# groups are strongly correlated (k1 / k2), nearly unidentifiable in
# combination (link lengths), or numerous enough to mimic other effects (keypoint biases).
FORWARD_EFFECTS = ("link_length", "lens_distortion", "keypoint_bias")
# Groups that enter only after another one (a lens's k2 refines its k1 as in the usual lens
# calibration order; alone, the r^4 term of a strong k2 mimics the r^2 term of a weak k1)
AFTER_GROUP = {"k2": "k1"}


def try_effect(effect: str, current: Evaluation, problem: Problem, mask: np.ndarray,
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
    """Forward selection of `effect`'s parameter groups: add the group that lowers the BIC
    most (the cost, each parameter priced) while its p-value stays below `group_alpha`; a
    group of `AFTER_GROUP` only once its predecessor is in. Used where combinations of groups
    are (nearly) unidentifiable, e.g. link lengths: stretching every link in proportion scales
    the robot, which a camera farther away absorbs exactly; the sparsest explanation is kept."""
    groups = list(dict.fromkeys(p.group for p in params))
    chosen: list[str] = []
    best_fit: FitResult | None = None
    while len(chosen) < len(groups):
        trials = []
        for g in groups:
            before = AFTER_GROUP.get(g)
            if g in chosen or (before is not None and before not in chosen):
                continue
            kept = [p for c in chosen for p in params if p.group == c]
            added = [p for p in params if p.group == g]
            model = Model(problem, base.model.params + tuple(kept + added), base.model.T0,
                          base.model.change_index)
            start = base.x if best_fit is None else best_fit.x
            x0 = np.concatenate([start, np.zeros(len(added))])
            trials.append((g, fit_model(model, mask, scale_px, x0=x0)))
        if not trials:
            break
        # the lowest BIC: a group of more parameters must lower the cost by more
        g, fit = min(trials, key=lambda t: t[1].bic(mask, scale_px))
        if group_p_values(fit, effect)[g] > settings.group_alpha:
            break
        chosen.append(g)
        best_fit = fit
    if best_fit is None:
        return "no parameter group differs significantly from zero"
    return best_fit


def prune_accepted(current: Evaluation, accepted: list[str], mask: np.ndarray, scale_px: float,
                   settings: DiagnoseSettings) -> tuple[Evaluation, list[tuple[str, str]]]:
    """`current` without the parameter groups of its `accepted` effects (the one just accepted
    included) that no longer differ from zero, dropped one at a time (the least significant
    first), each effect keeping at least one group; e.g. the wrist joint offsets that stood in
    for a hand keypoint's bias until the bias itself was accepted. A drop after which an
    accepted effect would be fitted beyond its plausible size is not taken (that group stays).
    Returns (the refitted and cross-validated model, or `current` itself when nothing is
    dropped; the dropped groups as (effect, group))."""
    fit = current.fit
    dropped: list[tuple[str, str]] = []
    refused: set[tuple[str, str]] = set()
    while True:
        found = _least_significant(fit, accepted, settings.group_alpha, refused)
        if found is None:
            break
        effect, group = found
        keep = [i for i, p in enumerate(fit.model.params)
                if not (p.effect == effect and p.group == group)]
        params = tuple(fit.model.params[i] for i in keep)
        model = Model(fit.model.problem, params, fit.model.T0, fit.model.change_index)
        smaller = fit_model(model, mask, scale_px,
                            x0=np.concatenate([fit.x[:6], fit.x[6:][keep]]))
        if first_implausible(smaller, tuple(accepted), settings.plausible) is not None:
            refused.add(found)
            continue
        fit = smaller
        dropped.append(found)
    if not dropped:
        return current, dropped
    cost, sq, n = cross_validate(fit, mask, scale_px, settings,
                                 rescan_change=fit.model.change_index is not None)
    return Evaluation(current.name, fit, cost, sq, n, current.identifiability,
                      current.pruned), dropped


def redundant_effects(fit: FitResult, accepted: list[str], group_alpha: float) -> list[str]:
    """The `accepted` effects left with one parameter group that no longer differs from zero
    (p > `group_alpha`): `prune_accepted` keeps it, since removing an effect is the held-out
    test's verdict, but the report says so."""
    out = []
    for effect in accepted:
        p_values = group_p_values(fit, effect)
        if len(p_values) == 1 and next(iter(p_values.values())) > group_alpha:
            out.append(effect)
    return out


def _least_significant(fit: FitResult, effects: list[str], group_alpha: float,
                       refused: set[tuple[str, str]]) -> tuple[str, str] | None:
    """(effect, group) of the droppable group with the largest p-value above `group_alpha`:
    not an effect's last group, nor a group that another kept group enters after
    (`AFTER_GROUP`), nor one in `refused`; None when there is none, or when the fit's
    covariance is not finite (its p-values say nothing)."""
    if not np.all(np.isfinite(fit.covariance)):
        return None
    worst: tuple[float, str, str] | None = None
    for effect in effects:
        p_values = group_p_values(fit, effect)
        if len(p_values) < 2:
            continue
        for group, p in p_values.items():
            needed = any(AFTER_GROUP.get(g) == group for g in p_values)
            if (p > group_alpha and not needed and (effect, group) not in refused
                    and (worst is None or p > worst[0])):
                worst = (p, effect, group)
    return None if worst is None else worst[1:]
