"""Score a diagnosis against the effects hidden in generated data (tests, benchmarks).

An effect counts as identified when the verdict names it and each of its hidden parameters is
recovered within `relative_tol` of its size or within `sigmas` stated standard deviations. When
the data cannot tell two effects apart (e.g. a bias of the base keypoint along the first joint's
axis and a stretch of that joint), the diagnosis names one and reports the other as an equally
good alternative: `EffectScore.equivalent` marks that case.
Parameters the truth does not set must be within `sigmas` of zero (or absent).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from dream.camera import CameraIntrinsics
from dream.extension import ModelExtension

RELATIVE_TOL = 0.10   # identified: a parameter within 10 % of the truth
SIGMAS = 3.0          # ... or within 3 of its stated standard deviations
CHANGE_FRAME_TOL = 1  # camera_moved: frames between the true and the found move


@dataclass(frozen=True)
class EffectScore:
    """How one hidden effect was diagnosed."""

    name: str
    named: bool
    recovered: bool
    detail: str
    equivalent: bool = False   # not in the verdict, but reported as an equally good alternative
    z: tuple[float, ...] = ()  # (estimate - truth) / stated sigma of each parameter with one


def _close(est: float, true: float, sigma: float, size: float, relative_tol: float,
           sigmas: float) -> bool:
    return abs(est - true) <= max(relative_tol * abs(size), sigmas * sigma)


def _sigmas(values) -> np.ndarray:
    """Stated sigmas as floats; unknown ones (None, NaN) count as 0 (no allowance)."""
    s = np.array([np.nan if v is None else float(v) for v in values])
    return np.where(np.isfinite(s), s, 0.0)


def _vector_close(est: np.ndarray, true: np.ndarray, sigma: np.ndarray, relative_tol: float,
                  sigmas: float) -> bool:
    """Every component within `relative_tol` of the true vector's size or `sigmas` sigmas."""
    return bool(np.all(np.abs(est - true) <= np.maximum(relative_tol * np.linalg.norm(true),
                                                        sigmas * sigma)))


def _effect_of(doc: dict[str, Any], name: str) -> dict[str, Any] | None:
    for e in doc.get("effects", []):
        if e["name"] == name:
            return e
    return None


def standardised(est, true, sigma) -> tuple[float, ...]:
    """(estimate - truth) / sigma of the components whose stated sigma is known and positive:
    over many trials about normal with unit spread where the stated sigmas are honest.

        >>> standardised([1.0, 2.0, 5.0], [0.0, 2.0, 1.0], [0.5, None, 2.0])
        (2.0, 2.0)
    """
    e, t = np.atleast_1d(np.asarray(est, float)), np.atleast_1d(np.asarray(true, float))
    s = _sigmas(np.atleast_1d(np.asarray(sigma, dtype=object)))
    known = s > 0
    return tuple(float(v) for v in (e[known] - t[known]) / s[known])


def _compare_scalars(true: dict[str, float], est: dict[str, Any], sigma: dict[str, Any],
                     relative_tol: float, sigmas: float) -> tuple[bool, str, tuple[float, ...]]:
    size = max((abs(v) for v in true.values()), default=0.0)
    ok, parts, z = True, [], ()
    for key in sorted(set(true) | set(est)):
        t, e = float(true.get(key, 0.0)), float(est.get(key, 0.0))
        s = float(sigma.get(key) or 0.0)
        good = _close(e, t, s, size if key in true else 0.0, relative_tol, sigmas)
        ok &= good
        z += standardised(e, t, s)
        parts.append(f"{key}: {e:.5g} vs {t:.5g} (sigma {s:.2g}){'' if good else ' MISS'}")
    return ok, "; ".join(parts), z


def score_effect(name: str, truth: ModelExtension, camera: CameraIntrinsics,
                 frame_names: tuple[str, ...], doc: dict[str, Any],
                 relative_tol: float = RELATIVE_TOL, sigmas: float = SIGMAS) -> EffectScore:
    """Compare the hidden effect `name` of `truth` with the diagnosis document `doc`."""
    named = name in doc.get("verdict", [])
    equivalent = not named and any(name in alts for alts in
                                   doc.get("alternatives", {}).values())
    entry = _effect_of(doc, name)
    if not (named or equivalent) or entry is None:
        return EffectScore(name, False, False, "not in the verdict")
    source = entry.get("alternative", entry) if equivalent else entry
    est, sigma = source.get("params", {}), source.get("sigma", {}) or {}
    true = truth.effect_params(name)
    if name in ("joint_offset", "link_length", "time_offset"):
        ok, detail, z = _compare_scalars(true, est, sigma, relative_tol, sigmas)
    elif name == "lens_distortion":
        ok, detail, z = _compare_scalars({k: v for k, v in true.items() if v != 0.0},
                                         {k: v for k, v in est.items() if v != 0.0}, sigma,
                                         relative_tol, sigmas)
    elif name == "intrinsics_error":  # compare the corrections, pixels
        nominal = {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy}
        dtrue = {k: true[k] - nominal[k] for k in nominal if abs(true[k] - nominal[k]) > 1e-9}
        dest = {k: float(est[k]) - nominal[k] for k in nominal
                if k in est and abs(float(est[k]) - nominal[k]) > 1e-9}
        ok, detail, z = _compare_scalars(dtrue, dest, sigma, relative_tol, sigmas)
    elif name == "keypoint_bias":
        ok, parts, z = True, [], ()
        for k in sorted(set(true) | set(est)):
            t = np.asarray(true.get(k, (0.0, 0.0, 0.0)), float)
            e = np.asarray(est.get(k, (0.0, 0.0, 0.0)), float)
            s = _sigmas(sigma.get(k, (0.0, 0.0, 0.0)))
            good = _vector_close(e, t, s, relative_tol, sigmas)
            ok &= good
            z += standardised(e, t, s)
            parts.append(f"{k}: {np.round(e, 4).tolist()} vs {np.round(t, 4).tolist()}"
                         f"{'' if good else ' MISS'}")
        detail = "; ".join(parts)
    elif name == "camera_moved":
        t_frame = frame_names.index(true["frame"])
        e_frame = frame_names.index(est["frame"]) if est.get("frame") in frame_names else -99
        ok = abs(t_frame - e_frame) <= CHANGE_FRAME_TOL
        parts, z = [f"frame {est.get('frame')} vs {true['frame']}"], ()
        for key, comps in (("rotation_rad", ("rx", "ry", "rz")),
                           ("translation_m", ("tx", "ty", "tz"))):
            t = np.asarray(true[key], float)
            e = np.asarray(est.get(key, (0.0, 0.0, 0.0)), float)
            s = _sigmas([sigma.get(c) for c in comps])
            good = _vector_close(e, t, s, relative_tol, sigmas)
            ok &= good
            z += standardised(e, t, s)
            parts.append(f"{key}: {np.round(e, 5).tolist()} vs {np.round(t, 5).tolist()}"
                         f"{'' if good else ' MISS'}")
        detail = "; ".join(parts)
    elif name == "held_readings":  # the period, read from frames: within one frame interval
        interval = float(doc.get("frame_interval_s") or 0.0)
        t, e = float(true["period_s"]), float(est.get("period_s", np.nan))
        ok, z = bool(abs(e - t) <= max(relative_tol * t, interval + 1e-9)), ()
        detail = f"period_s: {e:.4g} vs {t:.4g}{'' if ok else ' MISS'}"
    else:
        return EffectScore(name, named, False, f"unknown effect {name}")
    if equivalent:
        detail = f"reported as an equivalent alternative to {doc['verdict']}; {detail}"
    return EffectScore(name, named, bool(ok), detail, equivalent, z)


def score_diagnosis(truth: ModelExtension, camera: CameraIntrinsics,
                    frame_names: tuple[str, ...], doc: dict[str, Any]) -> dict[str, Any]:
    """Every hidden effect scored, plus the effects found that were not hidden."""
    scores = [score_effect(n, truth, camera, frame_names, doc) for n in truth.effects]
    extra = [n for n in doc.get("verdict", []) if n not in truth.effects]
    return {"scores": scores, "extra": extra,
            "exact": all(s.recovered for s in scores) and not extra}
