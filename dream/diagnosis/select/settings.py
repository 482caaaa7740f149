"""The constants of a diagnosis (`DiagnoseSettings`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from dream.diagnosis.select.plausible import PLAUSIBLE
from dream.errors import InputError
from dream.extension import EFFECT_NAMES


@dataclass(frozen=True)
class DiagnoseSettings:
    """Every constant of the diagnosis.

    Attributes:
        effects: catalog effects to test.
        folds: cross-validation folds (frames interleaved: frame i in fold i mod folds).
        alpha: one-sided p-value threshold of the paired held-out test.
        bic_margin: the BIC must fall by more than this.
        min_relative_gain: the held-out RMSE must fall by at least this fraction.
        group_alpha: a parameter group (a joint, a keypoint, k1...) is kept only when its
            chi-square test against zero has a p-value below this.
        huber_scale_sigmas: Huber scale = this x the robust residual sigma of the baseline.
        min_huber_scale_px: lower bound of the Huber scale.
        gross_outlier_fraction: observations farther than this fraction of the image diagonal
            from the current model's prediction are left out (wrong detections).
        min_effect_px: identifiability: a parameter at its typical magnitude must move the
            prediction by at least this RMS.
        collinearity_tol: identifiability: fraction of that motion the extrinsic and the other
            parameters must leave unexplained.
        min_segment_frames: camera_moved: frames on each side of the move.
        clear_null_p: groups with a p-value above this are pruned together before the
            one-at-a-time backward elimination of the rest.
        min_motion_rad_s: time_offset is tested only when the joints move at least this fast
            (median over the distinct joint readings of the fastest joint).
        max_rounds: at most this many effects are accepted.
        equivalence_tol: significant effects whose held-out RMSE is within this fraction of
            the accepted one's are reported as equivalent alternatives.
        plausible: largest physically plausible magnitude per parameter kind (rad, m, s, or a
            fraction): an effect fitted beyond it is not accepted (its "gain" is the fit
            absorbing wrong detections, not a property of the robot or camera).
    """

    effects: tuple[str, ...] = EFFECT_NAMES   # held_readings: found from the data first
    folds: int = 5
    alpha: float = 0.01
    bic_margin: float = 10.0
    min_relative_gain: float = 0.002
    group_alpha: float = 1e-3
    huber_scale_sigmas: float = 2.0
    min_huber_scale_px: float = 0.5
    gross_outlier_fraction: float = 0.08
    min_effect_px: float = 0.02
    collinearity_tol: float = 0.05
    min_segment_frames: int = 5
    clear_null_p: float = 0.2
    min_motion_rad_s: float = 0.05
    max_rounds: int = 4
    equivalence_tol: float = 0.01
    plausible: dict = field(default_factory=lambda: dict(PLAUSIBLE))

    def __post_init__(self) -> None:
        unknown = [e for e in self.effects if e not in EFFECT_NAMES]
        if unknown:
            raise InputError(f"unknown effects {unknown}", fix=f"use {', '.join(EFFECT_NAMES)}")
        if self.folds < 2:
            raise InputError(f"folds must be >= 2, got {self.folds}")
        for name in ("alpha", "group_alpha"):
            if not 0 < getattr(self, name) < 1:
                raise InputError(f"{name} must be in (0, 1)")
        for name in ("bic_margin", "min_relative_gain", "huber_scale_sigmas",
                     "min_huber_scale_px", "gross_outlier_fraction", "min_effect_px",
                     "collinearity_tol"):
            if not getattr(self, name) >= 0:
                raise InputError(f"{name} must be >= 0")
