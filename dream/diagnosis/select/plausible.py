"""Physical plausibility of fitted effect parameters.

A significant effect whose parameters are beyond any realistic size (a joint offset of tens of
degrees, a lens distortion that folds the image) is the fit absorbing wrong detections, not a
property of the robot or camera: the selection does not accept it.
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceOf

import numpy as np

from dream.diagnosis.fit.model import FitResult
from dream.extension_limits import PLAUSIBLE  # noqa: F401  (the selection's limits)


def implausible_effect(fit: FitResult, effects: SequenceOf[str],
                       limits: dict) -> tuple[str, str] | None:
    """The first of `effects` whose fitted parameters are implausible (`implausible`), and why."""
    for effect in effects:
        why = implausible(fit, effect, limits)
        if why is not None:
            return effect, why
    return None


def first_implausible(fit: FitResult, effects: tuple[str, ...], limits: dict) -> str | None:
    """`implausible` of the first of `effects` that is (its name prefixed after the first)."""
    found = implausible_effect(fit, effects, limits)
    if found is None:
        return None
    effect, why = found
    return why if effect == effects[0] else f"{effect}: {why}"


def implausible(fit: FitResult, effect: str, limits: dict) -> str | None:
    """Why the fitted parameters of `effect` are beyond physical plausibility (None: fine)."""
    params = [(p, fit.x[6 + i]) for i, p in enumerate(fit.model.params) if p.effect == effect]
    groups: dict[str, list[float]] = {}
    for p, v in params:
        if effect == "lens_distortion":
            kind = "lens_distortion.k" if p.name in ("k1", "k2") else "lens_distortion.p"
        elif effect == "intrinsics_error":
            kind = "intrinsics_error.f" if p.name in ("fx", "fy") else "intrinsics_error.c"
        elif effect == "camera_moved":
            kind = "camera_moved.r" if p.name[-2] == "r" else "camera_moved.t"
        else:
            kind = effect
        key = (kind, p.group) if effect in ("keypoint_bias", "camera_moved") else (kind, p.name)
        groups.setdefault(key, []).append(float(v))
    for (kind, name), values in groups.items():
        size = float(np.linalg.norm(values))
        if kind in limits and size > limits[kind]:
            return (f"implausible magnitude: {name} = {size:.3g} > {limits[kind]:.3g} "
                    f"({kind}); the misfit looks like wrong detections, not a model effect")
    return None
