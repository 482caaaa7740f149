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
import os
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

IMAGE_MARGIN_PX = 1.0         # a keypoint this far beyond the image's last pixel lies outside
MAX_OUTSIDE_FRACTION = 0.5    # observations mostly beyond the images are of another camera


def read_sequence(path: str | Path, **options: Any) -> Sequence:
    """A recording in any supported layout (docs/data_format.md), its cameras and timestamps
    checked as `dream calibrate` checks them: a principal point of another resolution, a focal
    length in millimetres or timestamps that are not seconds raise `InputError`.

    `options`: those of `dream.io.read_sequence` (`fmt`, `joint_names`, `intrinsics` (a
    `CameraIntrinsics` or fx, fy, cx, cy in pixels), `robot`, `topics`).
    """
    from dream.io.read import read_sequence as read_unchecked
    from dream.plausibility import check_sequence_cameras, check_sequence_times

    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"read_sequence needs the recording's path, not {type(path).__name__}",
                         fix="pass the dataset folder or file as a str or pathlib.Path")
    sequence = read_unchecked(path, **options)
    check_sequence_cameras(sequence)
    check_sequence_times(sequence)
    return sequence


def load_robot(source: Sequence | str | Path,
               keypoints: SequenceOf[str] | None = None) -> Robot:
    """The robot of a recording, or a built-in robot by name, or a URDF file by path.

    Args:
        source: a `Sequence` (its data names the robot), a built-in name (`dream robots`
            lists them) or the path of a .urdf file.
        keypoints: link names to use as keypoints (default: the robot's own), a list.
    """
    if isinstance(keypoints, str):
        raise InputError(f"keypoints={keypoints!r} is one string",
                         fix='pass a list of link names, e.g. keypoints=["link0", "link2"]')
    names = tuple(keypoints) if keypoints else None
    if isinstance(source, Sequence):
        return robot_for(source, None, names)
    return _load_named_robot(str(source), list(names) if names else None)


def _check_recording(sequence: Any, robot: Any) -> None:
    """The arguments are a `Sequence` and a `Robot`, and the readings fit the robot (radians
    within its joint limits: `dream.plausibility`)."""
    from dream.plausibility import check_robot_readings

    _check_type(sequence, Sequence, "sequence", "dream.read_sequence(path)")
    _check_type(robot, Robot, "robot", "dream.load_robot(sequence)")
    check_robot_readings(sequence, robot)


def _check_type(value: Any, kind: type, name: str, make: str) -> None:
    if not isinstance(value, kind):
        raise InputError(f"{name} is a {type(value).__name__}, not a {kind.__name__}",
                         fix=f"pass the {kind.__name__} that {make} returns")


def detect(sequence: Sequence, robot: Robot, model: KeypointModel | str | Path,
           batch_size: int = DEFAULT_BATCH_SIZE) -> Observations:
    """The keypoints a model finds in every frame (the robot takes the model's keypoints).

    `model`: a network loaded by `dream.load_keypoint_model("model.onnx")`, or the path of
    its ONNX file (e.g. `dream.BUNDLED_MODEL`). Joint readings outside the robot's limits
    (degrees given for radians) raise `InputError`.
    """
    from dream.detection import load_keypoint_model

    _check_recording(sequence, robot)
    if isinstance(model, (str, Path)):
        model = load_keypoint_model(model)
    return detect_keypoints(sequence, robot, model, batch_size=batch_size)


def labels(sequence: Sequence, robot: Robot) -> Observations:
    """The data's own 2D keypoint labels as observations (`dream calibrate --use-labels`)."""
    _check_recording(sequence, robot)
    return observations_from_labels(sequence, robot)


def _check_observations(sequence: Sequence, observations: Any) -> None:
    """The observations are of `sequence`'s frames, in its images."""
    _check_type(sequence, Sequence, "sequence", "dream.read_sequence(path)")
    _check_type(observations, Observations, "observations", "dream.detect or dream.labels")
    names = tuple(frame.name for frame in sequence.frames)
    if tuple(observations.frame_names) != names:
        raise InputError(f"the observations are of {len(observations.frame_names)} frames "
                         f"({_span(observations.frame_names)}), the sequence has {len(names)} "
                         f"({_span(names)})",
                         fix="pass the observations that dream.detect or dream.labels made of "
                             "this sequence (subset both alike)")
    uv = observations.uv[observations.found]
    camera = sequence.camera
    outside = ((uv[:, 0] > camera.width - 0.5 + IMAGE_MARGIN_PX)
               | (uv[:, 1] > camera.height - 0.5 + IMAGE_MARGIN_PX)).mean() if len(uv) else 0.0
    if outside > MAX_OUTSIDE_FRACTION:
        raise InputError(f"{outside:.0%} of the observed keypoints lie beyond the sequence's "
                         f"{camera.width}x{camera.height} images",
                         fix="pass the observations made of this sequence's images (or its "
                             "intrinsics of another resolution?)")


def _span(names: SequenceOf[str]) -> str:
    return f"{names[0]} .. {names[-1]}" if names else "none"


def calibrate(sequence: Sequence, observations: Observations, mode: str = "all",
              settings: SolverSettings | None = None) -> CalibrationResult:
    """`T_cam_base` from the observations, with its covariance.

    Args:
        mode: "all" (one camera fixed for every frame: one pose from all of them, with the
            keypoint jackknife in its uncertainty) or "each" (every frame's own pose).
        settings: the solver's constants (default `SolverSettings()`).
    """
    _check_observations(sequence, observations)
    if settings is not None:
        _check_type(settings, SolverSettings, "settings", "dream.SolverSettings(...)")
    return _calibrate_sequence(sequence, observations, mode, settings)


def polish_result(sequence: Sequence, robot: Robot, result: CalibrationResult,
                  observations: Observations, link_geometry: tuple = ()) -> Any:
    """The result aligned with the data's robot masks (`dream calibrate --polish`).

    Returns a `PolishResult` ("all" mode) or one per frame ("each" mode; None for a frame
    that was not polished); a polish is kept where it raises the silhouette IoU on the frames
    that agree (its `kept` attribute; a frame alone: without spoiling its keypoint fit), and a
    kept pose's 1-sigma is its `jackknife` (`dream.refined_uncertainty`). `link_geometry` (a
    `dream.extension.ModelExtension`'s) corrects the rendered links: a tool the URDF lacks.
    The silhouettes draw each joint the data logs at its reading, also those off `robot`'s
    keypoints (`dream.outline_robot.with_logged_joints`).
    """
    from dream.outline_robot import with_logged_joints
    from dream.polish import check_polish_input, polish_calibration, polish_frames

    check_polish_input(sequence, result.mode)
    robot = with_logged_joints(sequence, robot)
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
    `link_geometry` (a `dream.extension.ModelExtension`'s) corrects links' geometry. The
    outline draws each joint the data logs at its reading (`dream.outline_robot`).
    """
    from dream.edges import refine_with_edges
    from dream.edges.frames import refine_frames_with_edges
    from dream.outline_robot import with_logged_joints

    robot = with_logged_joints(sequence, robot)
    if result.mode == "each":
        return refine_frames_with_edges(sequence, robot, result, observations,
                                        exclude_links=exclude_links,
                                        link_geometry=link_geometry)
    return refine_with_edges(sequence, robot, result.T_cam_base, observations,
                             exclude_links=exclude_links, link_geometry=link_geometry)


def result_document(result: CalibrationResult, observations: Observations, robot: Robot,
                    sequence: Sequence | None = None, refined: Any = None) -> dict[str, Any]:
    """The RESULT.json document (docs/data_format.md) of the keypoints' calibration with its
    `quality` verdict; with `sequence` (the data it was solved from) also its `data` record,
    by which `dream eval` and `dream.evaluate` refuse other data.

    `refined`: what `refine_edges` or `polish_result` returned for this result (needs
    `sequence`). Its object is written in, and where it was kept its pose, `rmse_px`, 1-sigma
    and verdict are the refined pose's, as `dream calibrate` writes them; without it the
    document holds the keypoint pose. (The command's silhouette cross-check of an edge
    alignment is not run here.)
    """
    from dream.provenance import data_record
    from dream.refinement_document import with_refinement, written_quality
    from dream.result import result_to_dict

    if refined is not None and sequence is None:
        raise InputError("a refined result needs the sequence it was refined on",
                         fix="pass sequence= as well as refined=")
    document = result_to_dict(result, observations, robot=robot.name)
    if sequence is not None:
        _check_observations(sequence, observations)
        document["data"] = data_record(sequence, str(sequence.source))
    if refined is not None:
        document = with_refinement(document, refined, sequence, result, observations)
    document["quality"] = written_quality(result, observations, document).to_dict()
    return document


def evaluate(sequence: Sequence, robot: Robot, result: CalibrationResult | dict[str, Any],
             observations: Observations | None = None) -> dict[str, Any]:
    """Errors of a result against the data's ground truth (`dream eval`'s METRICS.json).

    `result`: a `CalibrationResult` with the `observations` it was solved from, or a
    RESULT.json document (`dream.read_result`). A document made from other data than
    `sequence` raises `InputError`; where `dream calibrate` interpolated a held joint log,
    the sequence's readings are interpolated alike (`dream.readings.solved_readings`).
    """
    from dream.provenance import check_same_data
    from dream.readings import solved_readings

    if isinstance(result, CalibrationResult):
        if observations is None:
            raise InputError("evaluate needs the observations a CalibrationResult was solved "
                             "from", fix="pass observations=, or a RESULT.json document")
        _check_observations(sequence, observations)
        result = result_document(result, observations, robot)
    elif not isinstance(result, dict):
        raise InputError(f"result is a {type(result).__name__}",
                         fix="pass a CalibrationResult or dream.read_result(path)")
    else:
        check_same_data(result, sequence, str(sequence.source), "the result document",
                        given_as="the sequence")
        sequence = solved_readings(sequence, result)
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
