"""`dream diagnose` at the edges: a measured sequence in, `REPORT_DIR` out.

    problem_from(sequence, robot, observations) -> Problem
    run_diagnosis(sequence, robot, observations, report_dir, settings) -> dict (diagnosis.json)

`REPORT_DIR` receives `diagnosis.json` (docs/data_format.md), `extended_model.yaml` (the
accepted effects, read by `dream calibrate --model-extension` and `dream synth
--model-extension`), `report.md` and its plots. Nothing is written when the diagnosis fails.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import numpy as np

from dream.calibration import Observations, calibrate_all
from dream.diagnosis.fit import FitResult, Problem, undetermined_covariance
from dream.diagnosis.held import (
    corrected_problem,
    fold_sampling_phase,
    held_entry,
    held_readings_in,
)
from dream.diagnosis.remaining import remaining_misfit
from dream.diagnosis.select import DiagnoseSettings, Diagnosis, Verdict, diagnose
from dream.errors import InputError
from dream.extended import extended_camera, extended_robot, interpolated_frames
from dream.extension import HeldReadings, ModelExtension, extension_yaml
from dream.io.atomic import check_output_folder, dumps, staged_directory, write_bytes_atomic
from dream.metrics import add_per_frame, pose_errors
from dream.pipeline import joints_in_robot_order, truth_poses
from dream.robot import Robot
from dream.sequence import Sequence

log = logging.getLogger(__name__)

DIAGNOSIS_FILE = "diagnosis.json"
EXTENSION_FILE = "extended_model.yaml"
MAX_SILHOUETTE_PANELS = 4   # frames with masks drawn in the report


def frame_times(sequence: Sequence) -> np.ndarray | None:
    """(F,) timestamps when every frame has one and they increase strictly; else None."""
    times = [f.timestamp for f in sequence.frames]
    if any(t is None for t in times):
        return None
    t = np.asarray(times, dtype=float)
    if np.any(np.diff(t) <= 0):
        log.warning("frame timestamps do not increase strictly: time effects are not tested")
        return None
    return t


def problem_from(sequence: Sequence, robot: Robot, obs: Observations) -> Problem:
    """The diagnosis problem of observed keypoints (labels or detections)."""
    return Problem(robot, sequence.camera, joints_in_robot_order(sequence, robot),
                   frame_times(sequence), obs.uv_found, tuple(f.name for f in sequence.frames))


def _params_with_sigma(fit: FitResult, effect: str, undetermined: np.ndarray | None = None
                       ) -> tuple[dict, dict]:
    """(params, sigma) of one effect of a fit, in the extended_model.yaml vocabulary; the sigma
    includes the `undetermined` covariance (`dream.diagnosis.fit.undetermined_covariance`)."""
    ext = fit.model.extension(fit.x)
    params = ext.effect_params(effect)
    variance = np.diag(fit.covariance) + (0.0 if undetermined is None else np.diag(undetermined))
    sigma: dict[str, Any] = {}
    for i, p in enumerate(fit.model.params):
        if p.effect != effect:
            continue
        s = float(np.sqrt(variance[6 + i])) if variance[6 + i] > 0 else float("nan")
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
            "pruned_as_zero": list(ev.pruned)}
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
    for label, fit in _model_steps(diagnosis):
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


def _residual_set(problem: Problem, fit: FitResult, mask: np.ndarray):
    from dream.diagnosis.residuals import ResidualSet

    return ResidualSet(problem.frame_names, problem.robot.keypoint_names,
                       problem.robot.joint_names, problem.uv, fit.model.predict(fit.x),
                       mask & problem.observed, problem.joints, problem.times_s,
                       problem.camera)


def _silhouette_panels(sequence: Sequence, problem: Problem, diagnosis: Diagnosis) -> list:
    """Observed masks against the rendered robot before and after the extension."""
    from dream.diagnosis.images import fit_joints
    from dream.diagnosis.report import SilhouettePanel
    from dream.io import load_image, load_mask
    from dream.silhouette import load_robot_meshes, render_silhouette, silhouette_iou

    with_mask = [i for i, f in enumerate(sequence.frames) if f.mask_path is not None]
    if not with_mask:
        return []
    chosen = np.unique(np.linspace(0, len(with_mask) - 1, min(MAX_SILHOUETTE_PANELS,
                                                                len(with_mask))).round()
                       .astype(int))
    base, final = diagnosis.baseline.fit, diagnosis.final.fit
    ext = diagnosis.extension
    robot_x = extended_robot(problem.robot, ext)
    meshes, meshes_x = load_robot_meshes(problem.robot), load_robot_meshes(robot_x)
    camera_x = extended_camera(problem.camera, ext)
    joints_base, joints_final = fit_joints(base), fit_joints(final)
    T_base, T_final = base.model.poses(base.x), final.model.poses(final.x)
    panels = []
    for c in chosen:
        i = with_mask[c]
        frame = sequence.frames[i]
        observed = load_mask(frame, sequence.camera) > 0
        image = load_image(frame, sequence.camera)
        before = render_silhouette(meshes, joints_base[i], T_base[i], problem.camera)
        after = None
        if not ext.is_empty:
            after = render_silhouette(meshes_x, joints_final[i], T_final[i], camera_x)
        panels.append(SilhouettePanel(frame.name, image, observed, before, after,
                                      silhouette_iou(observed, before),
                                      None if after is None else silhouette_iou(observed,
                                                                                after)))
    return panels


def diagnose_sequence(sequence: Sequence, robot: Robot, obs: Observations,
                      settings: DiagnoseSettings | None = None, progress=None,
                      extension_path: Path | None = None, judge=None
                      ) -> tuple[dict[str, Any], Diagnosis, Problem]:
    """The diagnosis of a sequence, in memory: (diagnosis.json document, Diagnosis, Problem).
    With a `judge` (`dream.diagnosis.images.OutlineJudge`), an effect the images contradict is
    not accepted."""
    logged = problem_from(sequence, robot, obs)
    return _diagnose_logged(sequence, obs, logged, held_readings_in(logged), settings, progress,
                            extension_path, judge)


def _diagnose_logged(sequence: Sequence, obs: Observations, logged: Problem,
                     held: HeldReadings | None, settings: DiagnoseSettings | None, progress,
                     extension_path: Path | None, judge
                     ) -> tuple[dict[str, Any], Diagnosis, Problem]:
    """`diagnose_sequence` on the problem of the readings as logged and the held readings
    found in them."""
    camera = sequence.fixed_camera("diagnose a sequence recorded by one camera")
    start = calibrate_all(obs, camera)
    problem = logged
    if held is not None:  # found in the data: the search runs on the interpolated readings
        problem = corrected_problem(problem, held)
    diagnosis = diagnose(problem, start.fit.T_cam_base, settings, progress,
                         None if judge is None else judge.veto)
    if held is not None:
        diagnosis = _with_held_readings(diagnosis, logged, held, settings)
    doc = diagnosis_document(sequence, diagnosis, extension_path or Path(EXTENSION_FILE))
    if held is not None:
        as_logged = diagnosis.baseline_as_logged
        interval = float(np.median(np.diff(logged.times_s)))
        doc["frame_interval_s"] = interval
        folded = fold_sampling_phase(doc, held, interval)
        if folded is not held:  # the time offset became the held readings' phase
            ext = dataclasses.replace(diagnosis.extension, time_offset_s=None,
                                      held_readings=folded)
            diagnosis = dataclasses.replace(diagnosis, extension=ext)
            held = folded
        doc["verdict"].insert(0, "held_readings")
        doc["effects"].insert(0, held_entry(logged, held, as_logged.heldout_rmse_px,
                                            diagnosis.baseline.heldout_rmse_px))
    return doc, diagnosis, problem


def _with_held_readings(diagnosis: Diagnosis, logged: Problem, held, settings
                        ) -> Diagnosis:
    """The diagnosis with held readings in its extension, and the baseline of the readings as
    logged (`baseline_as_logged`) for the record."""
    from dream.diagnosis.fit.model import Model
    from dream.diagnosis.select import evaluate

    as_logged = evaluate("baseline as logged",
                         Model(logged, (), diagnosis.baseline.fit.T_cam_base), diagnosis.mask,
                         diagnosis.scale_px, settings or DiagnoseSettings())
    return dataclasses.replace(diagnosis, extension=diagnosis.extension.merged(
                                   ModelExtension(held_readings=held)),
                               baseline_as_logged=as_logged)


def run_diagnosis(sequence: Sequence, robot: Robot, obs: Observations, report_dir: str | Path,
                  settings: DiagnoseSettings | None = None, progress=None) -> dict[str, Any]:
    """Diagnose `sequence` and write REPORT_DIR (diagnosis.json, extended_model.yaml, report)."""
    from dream.diagnosis.images import add_attached_geometry, add_image_evidence, outline_judge
    from dream.diagnosis.report import PLOT_FILES, write_report
    from dream.diagnosis.residuals import analyse

    report_dir = check_output_folder(report_dir)  # before the analysis, not after it
    extension_path = report_dir / EXTENSION_FILE
    logged = problem_from(sequence, robot, obs)
    held = held_readings_in(logged)
    judge = outline_judge(sequence, logged, known=None if held is None else interpolated_frames(
        logged.joints, logged.times_s, None, held, robot.joint_names))
    doc, diagnosis, problem = _diagnose_logged(sequence, obs, logged, held, settings, progress,
                                               extension_path, judge)
    baseline_res = _residual_set(problem, diagnosis.baseline.fit, diagnosis.mask)
    final_res = None if not diagnosis.accepted else _residual_set(problem, diagnosis.final.fit,
                                                                  diagnosis.mask)
    analysis = analyse(baseline_res)
    steps = _model_steps(diagnosis)
    add_image_evidence(doc, judge, steps)
    found = add_attached_geometry(doc, sequence, steps[-1][1], obs,
                                  diagnosis.extension.held_readings)
    if found is not None:
        diagnosis = dataclasses.replace(diagnosis, extension=diagnosis.extension.merged(
            ModelExtension(link_geometry=(found,))))
    panels = _silhouette_panels(sequence, problem, diagnosis)
    if panels:
        doc["silhouette_iou"] = [{"frame": p.frame, "before": p.iou_before, "after": p.iou_after}
                                 for p in panels]
    doc["residual_analysis"] = analysis
    doc = json_safe(doc)
    text = dumps(doc)  # fails here, before any file is written
    with staged_directory(report_dir) as stage:  # all the report's files, or none of them
        write_report(stage, doc, baseline_res, final_res, analysis, panels)
        write_bytes_atomic(stage / EXTENSION_FILE, extension_yaml(diagnosis.extension).encode())
        write_bytes_atomic(stage / DIAGNOSIS_FILE, text.encode())
        made = {path.name for path in stage.iterdir()}
    for name in PLOT_FILES:  # a plot of an earlier run into this folder that this one lacks
        if name not in made:
            (report_dir / name).unlink(missing_ok=True)
    return doc


def _model_steps(diagnosis: Diagnosis) -> list[tuple[str, FitResult]]:
    """(label, fit) of the baseline and of the model after each accepted effect, in order."""
    steps = []
    if diagnosis.baseline_as_logged is not None:
        steps.append(("baseline", diagnosis.baseline_as_logged.fit))
        steps.append(("held_readings", diagnosis.baseline.fit))
    else:
        steps.append(("baseline", diagnosis.baseline.fit))
    for name in diagnosis.accepted:
        fits = [v.evaluation.fit for v in diagnosis.tested
                if v.name == name and v.significant and v.evaluation is not None]
        if fits:
            steps.append((name, fits[-1]))
    if diagnosis.accepted:
        steps[-1] = (steps[-1][0], diagnosis.final.fit)
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


def apply_extension_to_observations(sequence: Sequence, robot: Robot, obs: Observations,
                                    extension: ModelExtension) -> tuple[Sequence, Observations]:
    """`dream calibrate --model-extension`: the sequence with the corrected camera and the
    joints its images show (`dream.extended.image_joints`: timing effects and joint offsets,
    for the image refinements, which render `extended_robot`), and the observations with the
    extended keypoint positions. Frames whose joints the timing effects cannot place between
    two readings (`dream.extended.interpolated_frames`: after a held log's last update) are
    left out, and with a camera move so are the frames before it (the extrinsic reported is
    the camera's latest pose)."""
    from dream.extended import extended_points, frames_after_move, image_joints
    from dream.pipeline import with_robot_joints

    names = tuple(f.name for f in sequence.frames)
    joints, times = joints_in_robot_order(sequence, robot), frame_times(sequence)
    P_base = extended_points(robot, joints, times, extension)
    obs = dataclasses.replace(obs, P_base=P_base)
    sequence = with_robot_joints(sequence, robot, image_joints(robot, joints, times, extension))
    sequence = dataclasses.replace(sequence, camera=extended_camera(sequence.camera, extension))
    keep = interpolated_frames(joints, times, extension.time_offset_s, extension.held_readings,
                               robot.joint_names)
    if not keep.all():
        log.info("%d frames whose joints lie outside the log left out: %s",
                 int((~keep).sum()), ", ".join(n for n, k in zip(names, keep, strict=True)
                                               if not k))
    if extension.camera_moved is not None:
        keep &= frames_after_move(names, extension)
        log.info("camera moved at frame %s: solving from the %d frames after it",
                 extension.camera_moved.frame, int(keep.sum()))
    if keep.sum() < 1:
        raise InputError("no frame is left after the camera move and the joint log's span",
                         fix="check the extension's camera_moved frame and time effects")
    if keep.all():
        return sequence, obs
    sequence = sequence.subset(keep)
    obs = Observations(obs.P_base[keep], obs.uv[keep], obs.confidence[keep],
                       tuple(n for n, k in zip(names, keep, strict=True) if k),
                       obs.keypoint_names)
    return sequence, obs
