"""Levenberg-Marquardt on a robust (IRLS-weighted) least-squares problem.

The one damped Gauss-Newton loop of the pose solver (`dream.pnp`), the silhouette polish
(`dream.polish`) and the diagnosis fit (`dream.diagnosis.fit`). A problem supplies its cost, its
weighted normal equations and how a step moves a parameter (a vector sum, or an SE(3) increment);
the loop damps the normal equations with Marquardt's scaling, lambda diag(H), and raises or
lowers lambda on a refused or kept step. `dream.pnp.solve_pnp_batch` runs the same iteration on
many frames in lockstep with numpy (a fast path, tested equal to this loop frame by frame).

    >>> import numpy as np
    >>> class Line:  # fit y = a x + b to three points
    ...     x, y = np.array([0.0, 1.0, 2.0]), np.array([1.0, 3.0, 5.0])
    ...     def evaluate(self, p):
    ...         r = p[0] * self.x + p[1] - self.y
    ...         return 0.5 * float(r @ r), r
    ...     def normal_equations(self, p, r):
    ...         J = np.stack([self.x, np.ones(3)], axis=1)
    ...         return J.T @ J, J.T @ r
    ...     def retract(self, p, dp):
    ...         return p + dp
    >>> out = levenberg_marquardt(Line(), np.zeros(2), LMSettings(max_iterations=50))
    >>> np.round(out.x, 6)
    array([2., 1.])
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

import cv2
import numpy as np

from dream.errors import InputError
from dream.optim.robust import TINY

X = TypeVar("X")


class LMProblem(Protocol[X]):
    """What `levenberg_marquardt` needs of a problem with parameter type X."""

    def evaluate(self, x: X) -> tuple[float, Any]:
        """(cost, state) at x; cost inf where x is infeasible. The state goes back to
        `normal_equations` once x is kept."""

    def normal_equations(self, x: X, state: Any) -> tuple[np.ndarray, np.ndarray]:
        """(H, g): the IRLS-weighted J^T W J and J^T W r at x."""

    def retract(self, x: X, dx: np.ndarray) -> X:
        """x moved by the step dx."""


@dataclass(frozen=True)
class LMSettings:
    """Constants of the damped iteration.

    Attributes:
        initial_damping: lambda of the first step, relative to diag(H).
        damping_up, damping_down: lambda is multiplied by `damping_up` after a refused step,
            divided by `damping_down` after a kept one.
        min_damping: lambda never falls below this.
        max_damping: no step is tried at a lambda at or above this (the iteration ends).
        diagonal_floor: diag(H) entries below this are raised to it (a zero column still damps).
        max_iterations: linearisations at most.
        max_evaluations: cost evaluations at most (the start's included).
        strict_decrease: keep a step only when it lowers the cost (else: does not raise it).
        step_tolerance: stop after a kept step shorter than this (Euclidean norm of dx).
        relative_cost_tolerance: stop after a kept step that lowers the cost by at most this
            fraction (None: no such test).
        predicted_tolerance: stop before a step whose predicted decrease of the quadratic model,
            -(g dx) - dx H dx / 2, is at most this fraction of the cost (None: no such test).
    """

    initial_damping: float = 1e-3
    damping_up: float = 10.0
    damping_down: float = 10.0
    min_damping: float = 1e-12
    max_damping: float = 1e12
    diagonal_floor: float = TINY
    max_iterations: int = 100
    max_evaluations: float = math.inf
    strict_decrease: bool = False
    step_tolerance: float = 0.0
    relative_cost_tolerance: float | None = None
    predicted_tolerance: float | None = None

    def __post_init__(self) -> None:
        for name in ("initial_damping", "min_damping", "max_damping", "diagonal_floor"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"LMSettings.{name} must be positive and finite, got {value}")
        for name in ("damping_up", "damping_down"):
            if not getattr(self, name) > 1:
                raise InputError(f"LMSettings.{name} must exceed 1, got {getattr(self, name)}")
        if self.max_iterations < 1 or not self.max_evaluations >= 1:
            raise InputError("LMSettings.max_iterations and max_evaluations must be >= 1")
        for name in ("step_tolerance", "relative_cost_tolerance", "predicted_tolerance"):
            if getattr(self, name) is not None and not getattr(self, name) >= 0:
                raise InputError(f"LMSettings.{name} must be >= 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class LMOutcome(Generic[X]):
    """The last kept parameter, its cost and state, and the linearisations run."""

    x: X
    cost: float
    state: Any
    iterations: int


def solve_damped(H: np.ndarray, damping: np.ndarray, g: np.ndarray) -> np.ndarray | None:
    """dx solving (H + diag(damping)) dx = -g; None where the system is singular.

    OpenCV's Cholesky first (positive definite for positive damping; a fraction of numpy's
    per-call cost on small systems), numpy's LU where it refuses.
    """
    A = H.copy()
    A.flat[:: A.shape[0] + 1] += damping
    ok, dx = cv2.solve(A, -g[:, None], flags=cv2.DECOMP_CHOLESKY)
    if ok:
        return dx[:, 0]
    try:
        return np.linalg.solve(A, -g)
    except np.linalg.LinAlgError:
        return None


def levenberg_marquardt(problem: LMProblem[X], x0: X, settings: LMSettings,
                        start: tuple[float, Any] | None = None) -> LMOutcome[X]:
    """Minimise `problem`'s cost from x0.

    Args:
        start: `problem.evaluate(x0)` when the caller has it.
    Returns:
        The last kept x (x0 when no step lowered the cost) with its cost and state.
    """
    s = settings
    cost, state = problem.evaluate(x0) if start is None else start
    x, lam, evaluations, iterations = x0, s.initial_damping, 1, 0
    while iterations < s.max_iterations and evaluations < s.max_evaluations:
        iterations += 1
        H, g = problem.normal_equations(x, state)
        scale = np.maximum(H.diagonal(), s.diagonal_floor)
        kept, stop = False, False
        while lam < s.max_damping and evaluations < s.max_evaluations:
            dx = solve_damped(H, lam * scale, g)
            if dx is None:
                lam *= s.damping_up
                continue
            if s.predicted_tolerance is not None:
                predicted = -(g @ dx) - 0.5 * (dx @ H @ dx)
                if predicted <= s.predicted_tolerance * cost:
                    return LMOutcome(x, cost, state, iterations)
            x_new = problem.retract(x, dx)
            new_cost, new_state = problem.evaluate(x_new)
            evaluations += 1
            if math.isfinite(new_cost) and (
                    new_cost < cost or (not s.strict_decrease and new_cost <= cost)):
                stop = dx @ dx < s.step_tolerance ** 2 or (
                    s.relative_cost_tolerance is not None
                    and cost - new_cost <= s.relative_cost_tolerance * max(cost, TINY))
                x, cost, state = x_new, new_cost, new_state
                lam = max(lam / s.damping_down, s.min_damping)
                kept = True
                break
            lam *= s.damping_up
        if not kept or stop:
            break
    return LMOutcome(x, cost, state, iterations)
