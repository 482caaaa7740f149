"""The library's front door: the steps of a calibration as functions on the core's types.

A recording (`Sequence`: images, joint readings, intrinsics) and a robot (`Robot`: URDF
kinematics and keypoints) give `Observations` (2D keypoints of every frame, from a keypoint
model or from the data's labels); `calibrate` solves `T_cam_base` from them with its
uncertainty; `polish_result` aligns the robot's silhouette with the data's masks; `evaluate`
scores a result against ground truth; `diagnose` explains what the simulated robot and camera
get wrong.

    >>> import dream
    >>> robot = dream.load_robot("panda")
    >>> robot.keypoint_names[:2]
    ('panda_link0', 'panda_link2')
"""

from __future__ import annotations

import logging
from collections.abc import Sequence as SequenceOf
from pathlib import Path
from typing import Any

from dream.calibration import CalibrationResult, Observations
from dream.detection import DEFAULT_BATCH_SIZE, KeypointModel, detect_keypoints
from dream.errors import InputError
from dream.pipeline import calibrate as _calibrate_sequence
from dream.pipeline import evaluate as _evaluate_result
from dream.pipeline import observations_from_labels, robot_for
from dream.pnp import SolverSettings
from dream.robot import Robot
from dream.robot import load_robot as _load_named_robot
from dream.sequence import Sequence

log = logging.getLogger(__name__)


def load_robot(source: Sequence | str | Path,
               keypoints: SequenceOf[str] | None = None) -> Robot:
    """The robot of a recording, or a built-in robot by name, or a URDF file by path.

    Args:
        source: a `Sequence` (its data names the robot), a built-in name (`dream robots`
            lists them) or the path of a .urdf file.
        keypoints: link names to use as keypoints (default: the robot's own).
    """
    names = tuple(keypoints) if keypoints else None
    if isinstance(source, Sequence):
        return robot_for(source, None, names)
    return _load_named_robot(str(source), list(names) if names else None)


def detect(sequence: Sequence, robot: Robot, model: KeypointModel,
           batch_size: int = DEFAULT_BATCH_SIZE) -> Observations:
    """The keypoints a model finds in every frame (the robot takes the model's keypoints).

    `model`: `dream.load_keypoint_model("model.onnx")`, e.g. `dream.BUNDLED_MODEL`.
    """
    return detect_keypoints(sequence, robot, model, batch_size=batch_size)


def labels(sequence: Sequence, robot: Robot) -> Observations:
    """The data's own 2D keypoint labels as observations (`dream calibrate --use-labels`)."""
    return observations_from_labels(sequence, robot)


def calibrate(sequence: Sequence, observations: Observations, mode: str = "all",
              settings: SolverSettings | None = None) -> CalibrationResult:
    """`T_cam_base` from the observations, with its covariance.

    Args:
        mode: "all" (one camera fixed for every frame: one pose from all of them, with the
            keypoint jackknife in its uncertainty) or "each" (every frame's own pose).
        settings: the solver's constants (default `SolverSettings()`).
    """
    return _calibrate_sequence(sequence, observations, mode, settings)


def polish_result(sequence: Sequence, robot: Robot, result: CalibrationResult,
                  observations: Observations, link_geometry: tuple = ()) -> Any:
    """The result aligned with the data's robot masks (`dream calibrate --polish`).

    Returns a `PolishResult` ("all" mode) or one per frame ("each" mode; None for a frame
    that was not polished); a polish is kept where it raises the silhouette IoU on the frames
    that agree (its `kept` attribute; a frame alone: without spoiling its keypoint fit), and a
    kept pose's 1-sigma is its `jackknife` (`dream.refined_uncertainty`). `link_geometry` (a
    `dream.extension.ModelExtension`'s) corrects the rendered links: a tool the URDF lacks.
    """
    from dream.polish import check_polish_input, polish_calibration, polish_frames

    check_polish_input(sequence, result.mode)
    if result.mode == "all":
        return polish_calibration(sequence, robot, result, observations,
                                  link_geometry=link_geometry)
    return polish_frames(sequence, robot, result, observations, link_geometry=link_geometry)


def refine_edges(sequence: Sequence, robot: Robot, result: CalibrationResult,
                 observations: Observations, exclude_links: SequenceOf[str] = (),
                 link_geometry: tuple = ()) -> Any:
    """The result aligned with the images' edges, no masks needed (`dream calibrate --refine
    edges`). All frames: an `EdgeResult` (`dream.edges`): `T_after` is the extrinsic to use,
    the aligned one when `kept`; `mismatched_links` names links whose outline disagrees with
    the images. Each frame (mode "each"): a tuple of `FrameEdgeResult` (`dream.edges.frames`),
    None for frames without a pose or an image. `exclude_links` leaves links out;
    `link_geometry` (a `dream.extension.ModelExtension`'s) corrects links' geometry.
    """
    from dream.edges import refine_with_edges
    from dream.edges.frames import refine_frames_with_edges

    if result.mode == "each":
        return refine_frames_with_edges(sequence, robot, result, observations,
                                        exclude_links=exclude_links,
                                        link_geometry=link_geometry)
    return refine_with_edges(sequence, robot, result.T_cam_base, observations,
                             exclude_links=exclude_links, link_geometry=link_geometry)


def result_document(result: CalibrationResult, observations: Observations,
                    robot: Robot) -> dict[str, Any]:
    """The RESULT.json document of a calibration (docs/data_format.md)."""
    from dream.result import result_to_dict

    return result_to_dict(result, observations, robot=robot.name)


def evaluate(sequence: Sequence, robot: Robot, result: CalibrationResult | dict[str, Any],
             observations: Observations | None = None) -> dict[str, Any]:
    """Errors of a result against the data's ground truth (`dream eval`'s METRICS.json).

    `result`: a `CalibrationResult` with the `observations` it was solved from, or a
    RESULT.json document (`dream.read_result`).
    """
    if isinstance(result, CalibrationResult):
        if observations is None:
            raise InputError("evaluate needs the observations a CalibrationResult was solved "
                             "from", fix="pass observations=, or a RESULT.json document")
        result = result_document(result, observations, robot)
    return _evaluate_result(sequence, robot, result)


def diagnose(sequence: Sequence, robot: Robot, observations: Observations,
             report_dir: str | Path | None = None) -> dict[str, Any]:
    """The sim-to-real diagnosis (`dream diagnose`): its diagnosis.json document.

    With `report_dir`, also writes the report folder (diagnosis.json, extended_model.yaml,
    report.md and plots).
    """
    from dream.diagnosis.run import diagnose_sequence, run_diagnosis

    if report_dir is not None:
        return run_diagnosis(sequence, robot, observations, report_dir)
    return diagnose_sequence(sequence, robot, observations)[0]
