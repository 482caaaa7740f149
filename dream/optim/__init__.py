"""Numerical optimisation shared by the solvers: robust losses and Levenberg-Marquardt."""

from dream.optim.lm import LMOutcome, LMProblem, LMSettings, levenberg_marquardt, solve_damped
from dream.optim.robust import RobustLoss, huber_rho, huber_weight

__all__ = ["LMOutcome", "LMProblem", "LMSettings", "RobustLoss", "huber_rho", "huber_weight",
           "levenberg_marquardt", "solve_damped"]
