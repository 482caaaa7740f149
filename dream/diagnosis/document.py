"""diagnosis.json: a `Diagnosis` as the document `dream diagnose` writes
(docs/data_format.md).

    diagnosis_document(sequence, diagnosis, extension_path) -> dict

Each effect tested is one entry: its evidence, its parameters with their 1-sigma (which include
what the parameters the data could not determine may be,
`dream.diagnosis.fit.undetermined_covariance`), its identifiability; then the baseline and the
extended fit, the gain on held-out frames, what remains unexplained, and with ground truth or
a reference extrinsic the error before, after and at each accepted effect.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dream.diagnosis.fit import FitResult, undetermined_covariance
from dream.diagnosis.remaining import remaining_misfit
from dream.diagnosis.select import Diagnosis, Verdict
from dream.metrics import add_per_frame, pose_errors
from dream.pipeline import truth_poses
from dream.sequence import Sequence


def _params_with_sigma(fit: FitResult, effect: str, undetermined: np.ndarray | None = None
                       ) -> tuple[dict, dict]:
    """(params, sigma) of one effect of a fit, in the extended_model.yaml vocabulary; the sigma
    includes the `undetermined` covariance (`dream.diagnosis.fit.undetermined_covariance`)."""
    ext = fit.model.extension(fit.x)
    params = ext.effect_params(effect)
    sd = fit.sigma_with(undetermined)
    sigma: dict[str, Any] = {}
    for i, p in enumerate(fit.model.params):
        if p.effect != effect:
            continue
        s = float(sd[6 + i])
        if effect == "keypoint_bias":
            sigma.setdefault(p.group, [0.0, 0.0, 0.0])["xyz".index(p.name[-1])] = s
        elif effect == "intrinsics_error":  # relative parameters -> pixels
            cam = fit.model.problem.camera
            sigma[p.name] = s * (cam.fx if p.name in ("fx", "cx") else cam.fy)
        elif effect == "camera_moved":
            sigma[p.name.split(".")[1]] = s
        elif effect == "time_offset":
            sigma["seconds"] = s
        else:
            sigma[p.name] = s
    return params, sigma


def _undetermined(evaluations, fit: FitResult, diagnosis: Diagnosis) -> np.ndarray:
    """The covariance that the parameters the `evaluations` could not determine add to `fit`."""
    held = tuple(p for ev in evaluations if ev is not None and ev.identifiability is not None
                 for p in ev.identifiability.undetermined)
    return undetermined_covariance(fit, held, diagnosis.mask, diagnosis.scale_px)


def _effect_entry(verdict: Verdict, final: FitResult, accepted: list[str],
                  final_undetermined: np.ndarray, diagnosis: Diagnosis) -> dict[str, Any]:
    entry: dict[str, Any] = {"name": verdict.name, "significant": verdict.significant,
                             "evidence": verdict.evidence, "round": verdict.round}
    ev = verdict.evaluation
    if ev is None:  # not testable, or nothing identifiable / significant to fit
        entry.update(params={}, heldout_rmse_px=None)
        return entry
    if verdict.name in accepted:
        fit, undetermined = final, final_undetermined
    else:
        fit, undetermined = ev.fit, _undetermined([ev], ev.fit, diagnosis)
    params, sigma = _params_with_sigma(fit, verdict.name, undetermined)
    entry.update(params=params, sigma=sigma, heldout_rmse_px=ev.heldout_rmse_px,
                 p_value=verdict.p_value, bic_delta=verdict.bic_delta)
    if ev.identifiability is not None:
        entry["identifiability"] = {
            "identifiable": [p.name for p in ev.identifiability.kept],
            "not_identifiable": ev.identifiability.dropped,
            "in_sigma": [p.name for p in ev.identifiability.undetermined],
            "pruned_as_zero": list(ev.pruned) + diagnosis.dropped_later.get(verdict.name, [])}
    return entry


def _last_verdicts(tested: list[Verdict], accepted: list[str]) -> list[Verdict]:
    """One verdict per effect: for an accepted effect the accepting one, for the others the
    latest (tested against the final model)."""
    out: dict[str, Verdict] = {}
    for v in tested:
        if v.name in accepted:
            if v.significant and accepted.index(v.name) + 1 == v.round:
                out[v.name] = v
        else:
            out[v.name] = v
    return list(out.values())


def _alternative_fits(tested: list[Verdict], alternatives: dict[str, list[str]]
                      ) -> dict[str, Verdict]:
    """The significant verdicts of the effects reported as equivalent alternatives."""
    names = {n for alts in alternatives.values() for n in alts}
    out: dict[str, Verdict] = {}
    for v in tested:
        if v.name in names and v.significant and v.evaluation is not None:
            out.setdefault(v.name, v)
    return out


def _truth(sequence: Sequence, diagnosis: Diagnosis) -> dict[str, Any] | None:
    """Extrinsic error and ADD of the baseline and extended fits against the data's truth, and
    the extrinsic error after each accepted effect (`steps`)."""
    T_true = truth_poses(sequence)
    has = np.all(np.isfinite(T_true.reshape(len(sequence), -1)), axis=1)
    if not has.any():
        return None
    out: dict[str, Any] = {"frames_with_truth": int(has.sum())}
    before = diagnosis.baseline_as_logged or diagnosis.baseline
    for label, fit in (("before", before.fit), ("after", diagnosis.final.fit)):
        T_est = fit.model.poses(fit.x)
        t_err, r_err = pose_errors(T_est[has], T_true[has])
        P = fit.model.points(fit.x)[has]
        add = add_per_frame(P, T_est[has], T_true[has])
        out[label] = {"translation_error_m": float(np.median(t_err)),
                      "rotation_error_rad": float(np.median(r_err)),
                      "add_mean_m": float(np.mean(add))}
    out["steps"] = []   # after each accepted effect, in order
    for label, fit in model_steps(diagnosis):
        t_err, r_err = pose_errors(fit.model.poses(fit.x)[has], T_true[has])
        out["steps"].append({"model": label, "translation_error_m": float(np.median(t_err)),
                             "rotation_error_rad": float(np.median(r_err))})
    return out


def diagnosis_document(sequence: Sequence, diagnosis: Diagnosis,
                       extension_path: Path) -> dict[str, Any]:
    """diagnosis.json (docs/data_format.md): the required keys, and sigma, identifiability,
    truth and notes."""
    mask = diagnosis.mask
    base, final = diagnosis.baseline, diagnosis.final
    before = diagnosis.baseline_as_logged or base   # with held readings: as logged

    def fit_rmse(fit: FitResult) -> float:
        r = fit.residual[mask]
        return float(np.sqrt(np.mean(np.sum(r * r, axis=-1)))) if r.size else float("nan")

    verdicts = _last_verdicts(diagnosis.tested, diagnosis.accepted)
    final_undetermined = _undetermined([v.evaluation for v in verdicts
                                        if v.name in diagnosis.accepted], final.fit, diagnosis)
    effects = [_effect_entry(v, final.fit, diagnosis.accepted, final_undetermined, diagnosis)
               for v in verdicts]
    alternative = _alternative_fits(diagnosis.tested, diagnosis.alternatives)
    for entry in effects:
        v = alternative.get(entry["name"])
        if v is not None:  # equally good as an accepted effect: its own fit, for the record
            fit = v.evaluation.fit
            params, sigma = _params_with_sigma(fit, v.name,
                                               _undetermined([v.evaluation], fit, diagnosis))
            entry["alternative"] = {"params": params, "sigma": sigma,
                                    "heldout_rmse_px": v.evaluation.heldout_rmse_px,
                                    "evidence": v.evidence, "round": v.round}
    order = {n: i for i, n in enumerate(diagnosis.accepted)}
    effects.sort(key=lambda e: (order.get(e["name"], len(order)), e["name"]))
    doc: dict[str, Any] = {
        "data": str(sequence.source) if sequence.source else None,
        "robot": final.fit.model.problem.robot.name,
        "frames": len(sequence),
        "keypoints_used": int(mask.sum()),
        "huber_scale_px": diagnosis.scale_px,
        "baseline": {"rmse_px": fit_rmse(base.fit), "heldout_rmse_px": before.heldout_rmse_px,
                     "T_cam_base": base.fit.T_cam_base.tolist()},
        "effects": effects,
        "verdict": list(diagnosis.accepted),
        "alternatives": dict(diagnosis.alternatives),
        "extended_model": str(extension_path),
        "extended": {"rmse_px": fit_rmse(final.fit), "T_cam_base": final.fit.T_cam_base.tolist()},
        "gain": {"heldout_rmse_px_before": before.heldout_rmse_px,
                 "heldout_rmse_px_after": final.heldout_rmse_px},
        "seconds": diagnosis.seconds,
        "notes": list(diagnosis.notes),
    }
    if before is not base:
        doc["baseline"]["heldout_rmse_px_interpolated"] = base.heldout_rmse_px
    doc["remaining"] = remaining_misfit(final.fit.residual, mask & final.fit.model.problem.observed,
                                        final.fit.model.problem.robot.keypoint_names,
                                        before.heldout_rmse_px, final.heldout_rmse_px)
    truth = _truth(sequence, diagnosis)
    if truth is not None:
        doc["truth"] = truth
    return doc


def model_steps(diagnosis: Diagnosis) -> list[tuple[str, FitResult]]:
    """(label, fit) of the baseline and of the model after each accepted effect, in order."""
    steps = []
    if diagnosis.baseline_as_logged is not None:
        steps.append(("baseline", diagnosis.baseline_as_logged.fit))
        steps.append(("held_readings", diagnosis.baseline.fit))
    else:
        steps.append(("baseline", diagnosis.baseline.fit))
    steps.extend(zip(diagnosis.accepted, diagnosis.step_fits, strict=True))
    return steps


def json_safe(value: Any) -> Any:
    """`value` with non-finite floats (unknown sigmas, undefined statistics) as None (numpy
    values are left to `dream.io.atomic.dumps`)."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value
