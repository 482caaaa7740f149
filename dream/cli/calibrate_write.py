"""What `dream calibrate` writes and how it ends, shared by the keypoint path
(`dream.cli.calibrate`) and the search without keypoints (`dream.cli.calibrate_start`): the
output locations checked before the work, RESULT.json with its files for robot software and the
--overlays folder written all or none, the summary printed; and the rule of `--refine auto`
when a refinement cannot run."""

from __future__ import annotations

from pathlib import Path
from typing import TextIO

import numpy as np

from dream.cli.calibrate_report import print_summary, print_truth_errors
from dream.cli.options import AUTO
from dream.errors import CannotRefine, InputError
from dream.refinement_document import pose_refined_by


def refined_or_kept(request, refine, doc: dict, out: TextIO) -> dict:
    """`refine()`'s document; under `--refine auto`, an edge alignment that cannot run
    (`CannotRefine`: no image edges near the outline...) leaves `doc` as it was, with the
    reason in `doc["edges"]` and on the console, instead of failing the command."""
    if request.refine != AUTO:
        return refine()
    try:
        return refine()
    except CannotRefine as exc:
        reason = f"the edge alignment did not run: {exc.problem}"
        print(f"{reason}; the pose before it is kept (--refine edges makes this an error)",
              file=out)
        return {**doc, "edges": {"mode": request.frames, "ran": False, "kept": False,
                                 "reason": reason}}


def result_document(request, seq, result, obs, data_doc: dict,
                    readings_doc: dict | None) -> dict:
    """RESULT.json's document of `result` (`dream.result.result_to_dict`) with the data's
    record, the request's settings and, where the joint log was interpolated, how."""
    from dream.result import result_to_dict

    doc = result_to_dict(result, obs, robot=request.robot or seq.robot)
    doc["data"] = data_doc
    doc["settings"] = {k: v for k, v in vars(request).items() if k != "loaded_model"}
    if readings_doc is not None:
        doc["joint_readings"] = readings_doc
    return doc


def finish(request, seq, robot, obs, result, doc: dict, paths, out: TextIO) -> None:
    """Write the files, print the summary and, where the data has them, the truth errors."""
    from dream.pipeline import truth_poses

    base_frame = request.base_frame or robot.base_link
    _write_calibration(request, seq, robot, obs, result, doc, paths, base_frame)
    print_summary(doc, out)
    reference_only = seq.T_cam_base_reference is not None and all(
        f.T_cam_base_true is None for f in seq.frames)
    print_truth_errors(doc, truth_poses(seq), out,
                       "the reference" if reference_only else "ground truth")
    ros_path, matrix_path, urdf_path, launch_path, handeye_path = paths
    print(f"wrote {request.out}, {ros_path} (ROS static_transform_publisher: x y z qx qy qz qw "
          f"{base_frame} {request.camera_frame}), {matrix_path} (T_base_cam), {urdf_path} (URDF "
          f"joint), {launch_path} (ROS 2 launch) and {handeye_path} (easy_handeye YAML)",
          file=out)


def check_outputs(request) -> tuple[Path, ...]:
    """Before any work: RESULT.json and the files written next to it (`dream.ros`) can be
    written and the --overlays folder can be made; returns the paths of those files."""
    from dream.io import check_output_file, check_output_folder
    from dream.ros import output_paths, snippet_paths

    check_output_file(request.out)
    paths = output_paths(request.out) + snippet_paths(request.out)
    for path in paths:
        try:
            check_output_file(path)
        except InputError as exc:
            raise InputError(f"{exc.problem} (dream calibrate --out {request.out} writes it)",
                             exc.path, "remove it, or choose another --out") from None
    if request.overlays:
        check_output_folder(request.overlays)
    return paths


def _write_calibration(request, seq, robot, obs, result, doc: dict,
                       paths: tuple[Path, ...], base_frame: str) -> None:
    """RESULT.json, its two text files and the --overlays folder, all or none: the files are
    written, then the overlays drawn (`write_calibration_overlays` stages them in a temporary folder
    and moves them into place); on a failure of either (an unreadable image...) the files are
    put back as they were before the command."""
    from dream.io import replacing_files
    from dream.io.atomic import dumps
    from dream.ros import handeye_text, launch_text, matrix_text, ros_text, urdf_text

    T, camera = np.asarray(doc["T_cam_base"]), request.camera_frame
    ros_path, matrix_path, urdf_path, launch_path, handeye_path = paths
    texts = {Path(request.out): dumps(doc),
             ros_path: ros_text(T, base_frame, camera, file_name=ros_path.name),
             matrix_path: matrix_text(T, base_frame),
             urdf_path: urdf_text(T, base_frame, camera),
             launch_path: launch_text(T, base_frame, camera),
             handeye_path: handeye_text(T, base_frame, camera)}
    files = {path: text.encode("utf-8") for path, text in texts.items()}
    with replacing_files(files):  # a failure puts the files back
        if request.overlays:
            from dream.overlay_search import write_calibration_overlays

            write_calibration_overlays(seq, robot, obs, result, Path(request.overlays), doc,
                                       pose_refined_by(doc))
