"""The significance level and the small regressions the residual analyses share."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from dream.arrays import finite_or_none

ALPHA = 0.01                 # family-wise significance level of every "significant" flag
MIN_REGRESSION_OBS = 4       # observations needed for a correlation or a regression


def slope_through_origin(x: np.ndarray, y: np.ndarray) -> dict:
    """Least squares y ~ b x (no intercept): b, its standard error, t, two-sided p."""
    n = len(x)
    sxx = float(x @ x)
    if n < MIN_REGRESSION_OBS or sxx <= 0:
        return {"slope": None, "se": None, "t": None, "p_value": None}
    b = float(x @ y) / sxx
    dof = n - 1
    s2 = float(np.sum((y - b * x) ** 2)) / dof
    se = math.sqrt(s2 / sxx) if s2 > 0 else 0.0
    t = b / se if se > 0 else (math.inf if b != 0 else 0.0)
    p = float(2 * stats.t.sf(abs(t), dof)) if math.isfinite(t) else 0.0
    return {"slope": b, "se": se, "t": finite_or_none(t), "p_value": p}


def corr(x: np.ndarray, y: np.ndarray) -> float | None:
    """Pearson correlation, None when undefined (fewer than 3 points or no variance)."""
    if len(x) < 3:
        return None
    xc, yc = x - x.mean(), y - y.mean()
    den = math.sqrt(float(xc @ xc) * float(yc @ yc))
    return None if den <= 0 else float(xc @ yc) / den
