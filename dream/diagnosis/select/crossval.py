"""Cross-validation by frames: a model fitted on all frames, then on each fold's training
frames, scored on the frames held out (interleaved folds: frame i in fold i mod folds)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.diagnosis.fit.identify import Identifiability
from dream.diagnosis.fit.model import FitResult, Model, fit_model
from dream.diagnosis.select.camera_move import best_change
from dream.diagnosis.select.settings import DiagnoseSettings
from dream.optim.robust import huber_rho

_CV_MAX_EVALUATIONS = 20   # residual evaluations of each fold's refit (from the full fit)


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
        sub = fit_model(model, train, scale_px, x0=fit.x, max_evaluations=_CV_MAX_EVALUATIONS)
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
    """`model` fitted on the `mask` observations (from x0) and cross-validated."""
    fit = fit_model(model, mask, scale_px, x0=x0)
    rescan = model.change_index is not None
    cost, sq, n = cross_validate(fit, mask, scale_px, settings, rescan)
    return Evaluation(name, fit, cost, sq, n, identifiability, pruned)
