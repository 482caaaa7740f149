"""Residual analysis against the joint angles: a `joint_offset` leaves residuals that vary
with its joint's angle."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import stats

from dream.arrays import finite_or_none
from dream.diagnosis.residuals.regression import ALPHA, MIN_REGRESSION_OBS, corr
from dream.diagnosis.residuals.residual_set import (
    ResidualSet,
    used_residuals,
)

MIN_JOINT_RANGE = 1e-6       # rad (or m): a joint that moves less than this is treated as fixed
COMPONENTS = ("u", "v")


def _standardised(columns: list[np.ndarray]) -> np.ndarray:
    """(n, m) design of centred, unit-variance columns; columns without variance dropped."""
    keep = []
    for c in columns:
        c = c - c.mean()
        s = float(np.sqrt(np.mean(c ** 2)))
        if s > 0 and s > 1e-12 * max(1.0, float(np.max(np.abs(c)))):
            keep.append(c / s)
    return np.stack(keep, -1) if keep else np.zeros((len(columns[0]), 0))


def _harmonic_fit(q: np.ndarray, y: np.ndarray) -> tuple[float | None, float | None]:
    """R^2 and F-test p-value of y ~ 1 + sin(q - q0) + cos(q - q0) against y ~ 1."""
    n = len(q)
    if n < MIN_REGRESSION_OBS + 1:
        return None, None
    qc = q - q.mean()
    X = _standardised([np.sin(qc), 1.0 - np.cos(qc)])
    m = X.shape[1]
    yc = y - y.mean()
    tss = float(yc @ yc)
    if m == 0 or tss <= 0:
        return None, None
    coef, *_ = np.linalg.lstsq(X, yc, rcond=None)
    rss = float(np.sum((yc - X @ coef) ** 2))
    r2 = max(0.0, 1.0 - rss / tss)
    dof = n - 1 - m
    if rss <= 0:
        return r2, 0.0
    f_stat = (r2 / m) / ((1.0 - r2) / dof)
    return r2, float(stats.f.sf(f_stat, m, dof))


def _joint_stats(res: ResidualSet, j: int, r: np.ndarray, f: np.ndarray,
                 k: np.ndarray) -> dict:
    q_all = res.joints[:, j]
    out: dict[str, Any] = {"range": finite_or_none(np.ptp(q_all)), "max_abs_corr": None,
                           "corr": None, "keypoint": None, "component": None,
                           "corr_p_value": None, "harmonic_r2": None,
                           "harmonic_keypoint": None, "harmonic_component": None,
                           "harmonic_p_value": None, "significant": False}
    if np.ptp(q_all) < MIN_JOINT_RANGE:
        return out
    K = len(res.keypoint_names)
    num_tests = 4 * K   # correlation and harmonic fit, of u and v, of every keypoint
    best_corr = (-1.0, None, None, None, 0)   # |corr|, corr, keypoint, component, n
    best_harm = (-1.0, None, None, None)   # r2, p, keypoint, component
    for ki in range(K):
        sel = k == ki
        q = q_all[f[sel]]
        if len(q) < MIN_REGRESSION_OBS or np.ptp(q) < MIN_JOINT_RANGE:
            continue
        for c in range(2):
            y = r[sel, c]
            rho = corr(q, y)
            if rho is not None and abs(rho) > best_corr[0]:
                best_corr = (abs(rho), rho, ki, c, len(q))
            r2, p = _harmonic_fit(q, y)
            if r2 is not None and r2 > best_harm[0]:
                best_harm = (r2, p, ki, c)
    if best_corr[2] is not None:
        rho, n = best_corr[1], best_corr[4]
        if abs(rho) >= 1.0:
            p_corr = 0.0
        else:
            t = rho * math.sqrt((n - 2) / (1.0 - rho * rho))
            p_corr = float(2 * stats.t.sf(abs(t), n - 2))
        out.update(max_abs_corr=abs(rho), corr=rho, keypoint=res.keypoint_names[best_corr[2]],
                   component=COMPONENTS[best_corr[3]],
                   corr_p_value=min(1.0, p_corr * num_tests))
    if best_harm[2] is not None:
        p_h = None if best_harm[1] is None else min(1.0, best_harm[1] * num_tests)
        out.update(harmonic_r2=best_harm[0], harmonic_keypoint=res.keypoint_names[best_harm[2]],
                   harmonic_component=COMPONENTS[best_harm[3]], harmonic_p_value=p_h)
    out["significant"] = bool(
        (out["corr_p_value"] is not None and out["corr_p_value"] < ALPHA)
        or (out["harmonic_p_value"] is not None and out["harmonic_p_value"] < ALPHA))
    return out


def analyse_joints(res: ResidualSet) -> dict:
    """Per joint: how much the residuals depend on that joint's angle.

    For every keypoint and component (u, v): the Pearson correlation of the residual with the
    joint angle, and the R^2 of a harmonic fit residual ~ 1 + sin(q) + cos(q) (a joint offset
    d moves a keypoint by about d * d(uv)/dq, which turns with the joint: a first harmonic of
    q). Reported: the strongest of each (`max_abs_corr`, `corr`, `keypoint`, `component`;
    `harmonic_r2`, `harmonic_keypoint`, `harmonic_component`) with p-values Bonferroni-corrected
    over the 4K tests of the joint; `significant` when either is below ALPHA. `range` is the
    joint's range over the sequence; a joint that does not move gives None (no evidence).
    """
    r, f, k = used_residuals(res)
    return {name: _joint_stats(res, j, r, f, k) for j, name in enumerate(res.joint_names)}
