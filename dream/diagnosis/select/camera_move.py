"""Where the camera moved: the change frame of a `camera_moved` model that fits best."""

from __future__ import annotations

import numpy as np

from dream.diagnosis.fit.model import FitResult, Model
from dream.diagnosis.fit.problem import Problem, candidate_params
from dream.diagnosis.select.settings import DiagnoseSettings
from dream.errors import InputError
from dream.optim.robust import huber_weight


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
    w = huber_weight(r, scale_px)
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
