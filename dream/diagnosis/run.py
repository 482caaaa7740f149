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
from dream.diagnosis.document import diagnosis_document, json_safe, model_steps
from dream.diagnosis.fit import FitResult, Problem
from dream.diagnosis.held import (
    corrected_problem,
    fold_sampling_phase,
    held_entry,
    held_readings_in,
    sampling_phase_range,
)
from dream.diagnosis.select import DiagnoseSettings, Diagnosis, diagnose
from dream.errors import InputError
from dream.extended import extended_camera, extended_robot, interpolated_frames
from dream.extension import HeldReadings, ModelExtension, extension_yaml
from dream.io.atomic import check_output_folder, dumps, staged_directory, write_bytes_atomic
from dream.pipeline import joints_in_robot_order
from dream.robot import Robot
from dream.sequence import Sequence

log = logging.getLogger(__name__)

DIAGNOSIS_FILE = "diagnosis.json"
EXTENSION_FILE = "extended_model.yaml"
MAX_SILHOUETTE_PANELS = 4   # frames with masks drawn in the report


def frame_times(sequence: Sequence) -> np.ndarray | None:
    """(F,) timestamps when every frame has one and they increase strictly; else None."""
    stamps = sequence.timestamps
    if stamps is None or len(sequence) < 2:
        return stamps
    t = sequence.increasing_timestamps
    if t is None:
        log.warning("frame timestamps do not increase strictly: time effects are not tested")
    return t


def problem_from(sequence: Sequence, robot: Robot, obs: Observations) -> Problem:
    """The diagnosis problem of observed keypoints (labels or detections)."""
    return Problem(robot, sequence.camera, joints_in_robot_order(sequence, robot),
                   frame_times(sequence), obs.uv_found, tuple(f.name for f in sequence.frames))


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
        group_alpha = (settings or DiagnoseSettings()).group_alpha
        phase_range = sampling_phase_range(logged, interval, group_alpha)
        folded = fold_sampling_phase(doc, held, phase_range, group_alpha)
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
    steps = model_steps(diagnosis)
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
