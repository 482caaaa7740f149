"""Robust losses of pixel residuals: the cost rho(r) and the IRLS weight rho'(r) / r.

One implementation of the Huber and Cauchy losses for every solver (pose, silhouette polish,
diagnosis). `r` may be a signed residual or a distance >= 0; the functions use |r|.

    >>> import numpy as np
    >>> huber_rho(np.array([1.0, 4.0]), 2.0)
    array([0.5, 6. ])
    >>> huber_weight(np.array([1.0, 4.0]), 2.0)
    array([1. , 0.5])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.errors import InputError

TINY = 1e-300   # keeps a division or a damping positive at exactly zero
LOSS_KINDS = ("huber", "cauchy", "l2")


def huber_rho(r: np.ndarray, scale: float) -> np.ndarray:
    """Huber cost: r^2 / 2 up to `scale`, then linear, scale (|r| - scale / 2)."""
    a = np.abs(r)
    return np.where(a <= scale, 0.5 * a * a, scale * (a - 0.5 * scale))


def huber_weight(r: np.ndarray, scale: float) -> np.ndarray:
    """Huber IRLS weight: 1 up to `scale`, then scale / |r|."""
    a = np.abs(r)
    return np.where(a <= scale, 1.0, scale / np.maximum(a, TINY))


def cauchy_rho(r: np.ndarray, scale: float) -> np.ndarray:
    """Cauchy cost: scale^2 / 2 log(1 + (r / scale)^2)."""
    return 0.5 * scale * scale * np.log1p((r / scale) ** 2)


def cauchy_weight(r: np.ndarray, scale: float) -> np.ndarray:
    """Cauchy IRLS weight: 1 / (1 + (r / scale)^2)."""
    return 1.0 / (1.0 + (r / scale) ** 2)


@dataclass(frozen=True)
class RobustLoss:
    """A robust loss of pixel residuals.

    Attributes:
        kind: "huber" (quadratic up to `scale_px`, then linear), "cauchy" or "l2".
        scale_px: where the loss stops being quadratic, px.

    >>> RobustLoss("huber", 3.0).weight(np.array([6.0]))
    array([0.5])
    """

    kind: str = "huber"
    scale_px: float = 3.0

    def __post_init__(self) -> None:
        if self.kind not in LOSS_KINDS:
            raise InputError(f"unknown robust loss '{self.kind}'", fix="use huber, cauchy or l2")
        if not (np.isfinite(self.scale_px) and self.scale_px > 0):
            raise InputError(f"robust loss scale must be a positive number of pixels, got "
                             f"{self.scale_px}")

    def rho(self, r: np.ndarray) -> np.ndarray:
        """Cost of residuals r (equals r^2 / 2 near zero)."""
        if self.kind == "l2":
            return 0.5 * r * r
        if self.kind == "huber":
            return huber_rho(r, self.scale_px)
        return cauchy_rho(r, self.scale_px)

    def weight(self, r: np.ndarray) -> np.ndarray:
        """IRLS weight rho'(r) / r."""
        if self.kind == "l2":
            return np.ones_like(r)
        if self.kind == "huber":
            return huber_weight(r, self.scale_px)
        return cauchy_weight(r, self.scale_px)
