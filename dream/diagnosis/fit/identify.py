"""Which parameters the data can determine, and which differ significantly from zero.

`identifiable_params` drops parameters the data cannot tell apart from the extrinsic (or from
each other); `group_p_values` tests each parameter group against zero (the selection prunes the
groups that do not differ from it); `undetermined_covariance` is what a dropped parameter's
unknown value adds to the uncertainty of the ones kept.

A dropped parameter is held at zero, but the data cannot say that it is zero: where its image
motion is nearly that of kept parameters (a camera that moved sideways looks like one that
turned), the kept ones absorb its true value. Their stated sigma must include that, or a
sideways move is reported as a turn several sigmas from the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from dream.diagnosis.fit.model import FitResult, Model
from dream.diagnosis.fit.problem import Param, Problem
from dream.optim.robust import huber_weight


@dataclass(frozen=True)
class Identifiability:
    """Which candidate parameters the data can determine, and why the others cannot be.

    Attributes:
        kept: identifiable parameters.
        dropped: parameter name -> reason.
        effect_px: parameter name -> RMS pixel change at its typical magnitude.
        undetermined: the dropped parameters that move the keypoints (their image motion is
            absorbed by the others): unknown, of about their typical magnitude.
    """

    kept: tuple[Param, ...]
    dropped: dict[str, str]
    effect_px: dict[str, float]
    undetermined: tuple[Param, ...] = ()


def identifiable_params(problem: Problem, base: FitResult, candidates: list[Param],
                        mask: np.ndarray, min_effect_px: float, collinearity_tol: float,
                        against_each_other: bool = True) -> Identifiability:
    """Greedy column selection on the Jacobian at the current solution.

    A candidate is dropped when moving it by its typical magnitude changes the prediction by
    less than `min_effect_px` RMS ("moves no observed keypoint"), or when less than
    `collinearity_tol` of that change remains after the extrinsic and the parameters already
    kept can absorb it ("absorbed by the extrinsic" / "confounded with ...").
    """
    change = base.model.change_index
    if change is None and any(p.effect == "camera_moved" for p in candidates):
        change = problem.num_frames // 2  # a provisional move for the test of its parameters
    model = Model(problem, base.model.params + tuple(candidates), base.model.T0, change)
    x = np.concatenate([base.x, np.zeros(len(candidates))])
    J = model.jacobian(x, mask & problem.observed)
    n_points = max(int((mask & problem.observed).sum()), 1)
    n_fixed = base.model.size
    scales = np.array([p.typical for p in candidates])
    fixed = J[:, :n_fixed] * np.concatenate([np.full(6, 0.01), [p.typical for p in
                                                               base.model.params]])
    kept: list[Param] = []
    undetermined: list[Param] = []
    kept_cols: list[np.ndarray] = []
    dropped: dict[str, str] = {}
    effect: dict[str, float] = {}
    for j, p in enumerate(candidates):
        col = J[:, n_fixed + j] * scales[j]
        size = float(np.linalg.norm(col) / np.sqrt(n_points))
        effect[p.name] = size
        if size < min_effect_px:
            dropped[p.name] = (f"moves no observed keypoint ({size:.2g} px RMS at "
                               f"{p.typical:g})")
            continue
        extrinsic_only = _orthogonal_fraction(col, J[:, :6])
        basis = np.column_stack([fixed] + kept_cols) if kept_cols and against_each_other \
            else fixed
        remaining = _orthogonal_fraction(col, basis)
        if remaining < collinearity_tol:
            undetermined.append(p)
            if extrinsic_only < collinearity_tol:
                dropped[p.name] = "absorbed by the extrinsic (same image motion as a camera move)"
            else:
                others = [q.name for q in base.model.params] + [q.name for q in kept]
                dropped[p.name] = "confounded with " + ", ".join(others[-4:])
            continue
        kept.append(p)
        kept_cols.append(col[:, None])
    return Identifiability(tuple(kept), dropped, effect, tuple(undetermined))


def undetermined_covariance(fit: FitResult, undetermined: tuple[Param, ...], mask: np.ndarray,
                            scale_px: float) -> np.ndarray:
    """(6 + P, 6 + P) covariance that parameters held at zero add to `fit`'s estimates (module
    doc), each of them unknown with its typical magnitude as standard deviation: B diag(typical^2)
    B^T, where B = d x / d u is the linear response of the weighted least-squares estimate to
    their values u. Zero without such parameters; NaN where the normal equations are singular.
    """
    n = fit.model.size
    if not undetermined:
        return np.zeros((n, n))
    model = Model(fit.model.problem, fit.model.params + tuple(undetermined), fit.model.T0,
                  fit.model.change_index)
    use = np.asarray(mask, bool) & fit.model.problem.observed
    J = model.jacobian(np.concatenate([fit.x, np.zeros(len(undetermined))]), use)
    w = huber_weight(fit.residual[use].ravel(), scale_px)
    J_fit, J_held = J[:, :n], J[:, n:]
    try:
        B = np.linalg.solve(J_fit.T @ (w[:, None] * J_fit), J_fit.T @ (w[:, None] * J_held))
    except np.linalg.LinAlgError:
        return np.full((n, n), np.nan)
    typical = np.array([p.typical for p in undetermined])
    return (B * typical ** 2) @ B.T


def _orthogonal_fraction(col: np.ndarray, basis: np.ndarray) -> float:
    """|col - projection of col on span(basis)| / |col|."""
    norm = np.linalg.norm(col)
    if norm == 0:
        return 0.0
    coef, *_ = np.linalg.lstsq(basis, col, rcond=None)
    return float(np.linalg.norm(col - basis @ coef) / norm)


def group_p_values(fit: FitResult, effect: str) -> dict[str, float]:
    """p-value of "all parameters of the group are zero" for each group of `effect`."""
    out = {}
    params = fit.model.params
    groups: dict[str, list[int]] = {}
    for i, p in enumerate(params):
        if p.effect == effect:
            groups.setdefault(p.group, []).append(6 + i)
    for g, idx in groups.items():
        theta = fit.x[idx]
        cov = fit.covariance[np.ix_(idx, idx)]
        try:
            chi2 = float(theta @ np.linalg.solve(cov, theta))
        except np.linalg.LinAlgError:
            chi2 = 0.0
        out[g] = float(stats.chi2.sf(chi2, len(idx))) if np.isfinite(chi2) else 1.0
    return out
