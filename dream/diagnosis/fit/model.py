"""The model of a diagnosis fit, its Jacobian, and the robust fit of its parameters.

The model predicts every observed keypoint of every frame:

    uv[f, k] = project(camera(theta), T_f(xi, theta) @ P_base[f, k](theta))

with `xi` the extrinsic's increment on a starting pose (the same convention as `dream.pnp`) and
`theta` the parameters of the effects (`dream.extension`). `fit_model` minimises a Huber cost
of the pixel residuals by Levenberg-Marquardt (`dream.optim.levenberg_marquardt`) with
finite-difference Jacobians (the keypoint positions are recomputed only for kinematic
parameters), and returns the parameters, their covariance and the residuals.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dream.camera import project
from dream.diagnosis.fit.problem import POINT_EFFECTS, Param, Problem, build_extension
from dream.errors import InputError
from dream.extended import extended_camera, extended_points
from dream.extension import ModelExtension
from dream.optim.lm import LMSettings, levenberg_marquardt
from dream.optim.robust import huber_rho, huber_weight
from dream.pnp import apply_increment
from dream.transforms import transform_points

_FD_STEP_FRACTION = 1e-3    # finite-difference step = this x the parameter's typical magnitude
_MIN_DEPTH_M = 1e-3         # points closer to the camera plane are clamped (keeps FD finite)


@dataclass
class Model:
    """A parametrised prediction of the observations: starting pose `T0`, parameters `params`
    (after the 6 extrinsic increments) and, with `camera_moved`, the first frame after the move.
    Caches the keypoint positions of the last kinematic parameter values."""

    problem: Problem
    params: tuple[Param, ...]
    T0: np.ndarray
    change_index: int | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.params = tuple(self.params)
        self.point_columns = np.array([p.effect in POINT_EFFECTS for p in self.params], bool)
        if any(p.effect == "camera_moved" for p in self.params) and self.change_index is None:
            raise InputError("a camera_moved model needs its change frame")

    @property
    def size(self) -> int:
        return 6 + len(self.params)

    def extension(self, x: np.ndarray) -> ModelExtension:
        return build_extension(self.params, np.asarray(x[6:], dtype=float), self.problem,
                               self.change_index)

    def points(self, x: np.ndarray) -> np.ndarray:
        """(F, K, 3) keypoints in the base frame for the kinematic part of x."""
        key = tuple(np.asarray(x[6:], dtype=float)[self.point_columns])
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            point_params = tuple(p for p in self.params if p.effect in POINT_EFFECTS)
            ext = build_extension(point_params, np.array(key), self.problem, None)
            self._cache[key] = extended_points(self.problem.robot, self.problem.joints,
                                               self.problem.times_s, ext)
        return self._cache[key]

    def poses(self, x: np.ndarray) -> np.ndarray:
        """(F, 4, 4) T_cam_base of every frame."""
        T = apply_increment(self.T0, np.asarray(x[:6], dtype=float))
        out = np.broadcast_to(T, (self.problem.num_frames, 4, 4)).copy()
        if self.change_index is not None:
            move = self.extension(x).camera_moved
            if move is not None:
                out[self.change_index:] = move.T_after_before @ T
        return out

    def predict(self, x: np.ndarray) -> np.ndarray:
        """(F, K, 2) predicted pixels."""
        P_cam = transform_points(self.poses(x)[:, None], self.points(x))
        P_cam[..., 2] = np.maximum(P_cam[..., 2], _MIN_DEPTH_M)
        camera = extended_camera(self.problem.camera, self.extension(x))
        F, K = P_cam.shape[:2]
        return project(camera, P_cam.reshape(-1, 3)).reshape(F, K, 2)

    def jacobian(self, x: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """d residual / dx over the `mask` (F, K) points: (2 M, n) by forward differences."""
        base = self.predict(x)[mask].ravel()
        steps = np.concatenate([np.full(3, 1e-6), np.full(3, 1e-6),
                                [_FD_STEP_FRACTION * p.typical for p in self.params]])
        J = np.empty((base.size, self.size))
        for j in range(self.size):
            xp = np.array(x, dtype=float)
            xp[j] += steps[j]
            J[:, j] = (self.predict(xp)[mask].ravel() - base) / steps[j]
        return J


@dataclass(frozen=True)
class FitResult:
    """A fitted model.

    Attributes:
        x: (6 + P,) extrinsic increment and parameter values.
        covariance: (6 + P, 6 + P), NaN when singular.
        residual: (F, K, 2) observed - predicted, px (every frame, NaN where not observed).
        cost: Huber cost over the fitted points.
        num_points: fitted keypoint observations.
    """

    model: Model
    x: np.ndarray
    covariance: np.ndarray
    residual: np.ndarray
    cost: float
    num_points: int

    @property
    def sigma(self) -> np.ndarray:
        """1-sigma of x; NaN where the covariance is singular or not positive."""
        return self.sigma_with(None)

    def sigma_with(self, added: np.ndarray | None) -> np.ndarray:
        """1-sigma of x with the covariance `added` ((6 + P, 6 + P) or None) on top of the
        fit's; NaN where the sum is singular or not positive."""
        d = np.diag(self.covariance) + (0.0 if added is None else np.diag(added))
        return np.where(np.isfinite(d) & (d > 0), np.sqrt(np.abs(d)), np.nan)

    @property
    def T_cam_base(self) -> np.ndarray:
        """The extrinsic of the first frame (before any camera move)."""
        return self.model.poses(self.x)[0]

    def bic(self, mask: np.ndarray, scale: float) -> float:
        """Bayesian information criterion over `mask`, Gaussian-equivalent Huber cost."""
        r = self.residual[mask].ravel()
        n = r.size
        rss = 2.0 * float(huber_rho(r, scale).sum())
        k = self.model.size + (1 if self.model.change_index is not None else 0)
        return n * np.log(max(rss, 1e-12) / n) + k * np.log(n)


# Levenberg-Marquardt constants of the fit (`dream.optim.LMSettings`)
_INITIAL_DAMPING = 1e-3
_DAMPING_UP = 4.0
_DAMPING_DOWN = 3.0
_MIN_DAMPING = 1e-12
_MAX_DAMPING = 1e12
_DIAGONAL_FLOOR = 1e-12
_RELATIVE_COST_TOL = 1e-10


@dataclass(frozen=True)
class _HuberCost:
    """The Huber cost of residuals `fun(x)` as a `dream.optim.LMProblem` over a vector x.

    Attributes:
        fun: x -> (2 M,) residuals, px.
        jac: x -> (2 M, n) their Jacobian.
        scale_px: the Huber scale.
    """

    fun: Callable[[np.ndarray], np.ndarray]
    jac: Callable[[np.ndarray], np.ndarray]
    scale_px: float

    def evaluate(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        r = self.fun(x)
        return float(huber_rho(r, self.scale_px).sum()), r

    def normal_equations(self, x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        J = self.jac(x)
        w = huber_weight(r, self.scale_px)
        return J.T @ (w[:, None] * J), J.T @ (w * r)

    def retract(self, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
        return x + dx


def _lm_settings(max_evaluations: int) -> LMSettings:
    """The fit's iteration: at most `max_evaluations` residual evaluations (each linearisation
    after the first follows a kept step, so the iteration cap never binds before it)."""
    return LMSettings(initial_damping=_INITIAL_DAMPING, damping_up=_DAMPING_UP,
                      damping_down=_DAMPING_DOWN, min_damping=_MIN_DAMPING,
                      max_damping=_MAX_DAMPING, diagonal_floor=_DIAGONAL_FLOOR,
                      max_iterations=max_evaluations,
                      max_evaluations=max_evaluations,
                      relative_cost_tolerance=_RELATIVE_COST_TOL)


def fit_model(model: Model, mask: np.ndarray, scale_px: float, x0: np.ndarray | None = None,
              max_evaluations: int = 60) -> FitResult:
    """Minimise the Huber cost of the `mask` (F, K) residuals over x (from x0 or zeros) by
    IRLS-weighted Levenberg-Marquardt; at most `max_evaluations` residual evaluations."""
    mask = np.asarray(mask, bool) & model.problem.observed
    if mask.sum() * 2 < model.size:
        raise InputError(f"{int(mask.sum())} observations cannot fit {model.size} parameters")
    uv_obs = model.problem.uv[mask].ravel()
    x0 = np.zeros(model.size) if x0 is None else np.array(x0, dtype=float)

    def fun(x: np.ndarray) -> np.ndarray:
        return model.predict(x)[mask].ravel() - uv_obs

    def jac(x: np.ndarray) -> np.ndarray:
        return model.jacobian(x, mask)

    x = levenberg_marquardt(_HuberCost(fun, jac, scale_px), x0,
                            _lm_settings(max_evaluations)).x
    residual = model.problem.uv - model.predict(x)
    r = residual[mask].ravel()
    J = jac(x)
    w = huber_weight(r, scale_px)
    dof = max(r.size - model.size, 1)
    sigma2 = float(np.sum(w * r * r) / dof)
    JtWJ = J.T @ (w[:, None] * J)
    try:
        cov = sigma2 * np.linalg.inv(JtWJ)
    except np.linalg.LinAlgError:
        cov = np.full((model.size, model.size), np.nan)
    return FitResult(model, x, cov, residual, float(huber_rho(r, scale_px).sum()),
                     int(mask.sum()))


def param_table(fit: FitResult) -> list[dict[str, Any]]:
    """Rows (effect, group, name, value, sigma) of a fitted model's effect parameters."""
    rows = []
    sigma = fit.sigma
    for i, p in enumerate(fit.model.params):
        rows.append({"effect": p.effect, "group": p.group, "name": p.name,
                     "value": float(fit.x[6 + i]), "sigma": float(sigma[6 + i])})
    return rows


def params_of(fit: FitResult, effect: str) -> tuple[list[Param], np.ndarray, np.ndarray]:
    """The parameters of `effect` in `fit`, their values and their 1-sigma."""
    idx = [i for i, p in enumerate(fit.model.params) if p.effect == effect]
    return ([fit.model.params[i] for i in idx], fit.x[[6 + i for i in idx]],
            fit.sigma[[6 + i for i in idx]])
