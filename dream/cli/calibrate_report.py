"""What `dream calibrate` adds to its result and prints: the edge alignment of `--refine
edges`, the silhouette polish of `--polish`, the verdict, the summary of the extrinsic and its
uncertainty, and its errors against the data's ground truth."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, TextIO

import numpy as np

from dream.refinement_document import with_refinement, written_quality

if TYPE_CHECKING:
    from dream.coarse.crosscheck import Crosscheck


def add_polish(seq, robot, result, obs, model, doc: dict, out: TextIO, *, frames: str,
               mask_head: bool, motion_masks: bool = False, link_geometry: tuple = ()) -> dict:
    """`--polish`: the silhouette polish of the one extrinsic (`frames` "all") or of every
    frame's own pose ("each"), rendering the model extension's `link_geometry`; returns
    RESULT.json's document with it."""
    from dream.polish import has_masks, polish_calibration

    if frames != "all":
        return _polish_frames(seq, robot, result, obs, doc, out, link_geometry)
    predict, leave_out = None, ()
    if has_masks(seq):
        if mask_head or motion_masks:
            print("the data has masks: the polish uses them, not "
                  f"{'the mask head' if mask_head else 'motion masks'}", file=out)
    elif motion_masks:
        predict, leave_out = _motion_masks(seq, robot, out)
    else:  # --mask-head (checked)
        from dream.detection import predict_masks

        predict = lambda idx: predict_masks(seq, model, idx)  # noqa: E731
        print("no masks in the data: the polish uses the network's mask head (--mask-head)",
              file=out)
    report = polish_calibration(seq, robot, result, obs, predict_masks=predict,
                                leave_out_links=leave_out, link_geometry=link_geometry)
    print(f"silhouette polish ({len(report.frames)} frames with masks, "
          f"{report.seconds:.1f} s): {report.reason}", file=out)
    agreement = report.agreement
    if agreement is not None and len(agreement.left_out):
        print("  frames left out (do their joint readings match their images?): " + "; ".join(
            f"{report.frames[i]} ({agreement.reasons[i]}: IoU {agreement.iou_common[i]:.2f}, "
            f"{agreement.iou_own[i]:.2f} alone)" for i in agreement.left_out), file=out)
    return with_refinement(doc, report, seq, result, obs)


def _motion_masks(seq, robot, out: TextIO):
    """`--motion-masks`: the polish's mask source (frame indices -> motion masks) and the links
    left out of its silhouettes (those that never move stay in the background model)."""
    from dream.edges.motion import MotionSettings, sequence_motion_masks, sequence_motion_model
    from dream.pipeline import joints_in_robot_order
    from dream.silhouette import load_robot_meshes, static_links

    background, settings = sequence_motion_model(seq, MotionSettings())
    static = static_links(load_robot_meshes(robot), joints_in_robot_order(seq, robot),
                          settings.static_link_m)
    print(f"no masks in the data: the polish uses motion masks (--motion-masks), without the "
          f"links that never move ({', '.join(static) or 'none'})", file=out)
    return (lambda idx: sequence_motion_masks(seq, np.asarray(idx), settings, background)), \
        static


def _polish_frames(seq, robot, result, obs, doc: dict, out: TextIO,
                   link_geometry: tuple = ()) -> dict:
    """`--polish --frames each`: every solved frame's own pose polished."""
    from dream.detection import PROGRESS_EVERY_FRAMES
    from dream.polish import polish_frames

    def progress(done: int, total: int) -> None:
        print(f"polished {done}/{total} frames", file=sys.stderr)

    reports = polish_frames(seq, robot, result, obs,
                            progress=progress if len(seq) > PROGRESS_EVERY_FRAMES else None,
                            link_geometry=link_geometry)
    doc = with_refinement(doc, reports, seq, result, obs, kind="polish")
    p = doc["polish"]
    if p["frames_polished"]:
        print(f"silhouette polish of each frame ({p['frames_polished']} frames with masks, "
              f"{p['seconds']:.1f} s): kept in {p['frames_kept']}; mean IoU "
              f"{p['iou_before']:.4f} -> {p['iou_kept']:.4f} ({p['iou_after']:.4f} at every "
              "polished pose)", file=out)
    else:
        print("silhouette polish of each frame: no solved frame has a non-empty mask", file=out)
    reported = result.reported_frame
    if reported is not None and reports[reported] is not None:
        print(f"  reported frame {doc['reported_frame']}: {reports[reported].reason}", file=out)
    return doc


def add_edges(seq, robot, result, obs, doc: dict, out: TextIO,
              exclude_links: str | None, link_geometry: tuple = ()) -> dict:
    """`--refine edges`: the one extrinsic aligned with the images' edges; returns RESULT.json's
    document with it."""
    from dream.edges import refine_with_edges

    res = refine_with_edges(seq, robot, result.fit.T_cam_base, obs,
                            exclude_links=_links(exclude_links), link_geometry=link_geometry)
    moved_m, moved_rad = res.correction
    print(f"edge alignment ({len(res.frames)} frames, {res.seconds:.1f} s"
          f"{', background model' if res.background else ''}): {res.reason}; the aligned pose "
          f"is {moved_m * 1e3:.1f} mm and {np.rad2deg(moved_rad):.2f} deg from the pose "
          "before it", file=out)
    if res.mismatched_links:
        print(f"  links whose outline disagrees with the images (a tool or gripper the URDF "
              f"lacks? --exclude-links): {', '.join(res.mismatched_links)}", file=out)
    return with_refinement(doc, res, seq, result, obs)


def add_frame_edges(seq, robot, result, obs, doc: dict, out: TextIO,
                    exclude_links: str | None, link_geometry: tuple = ()) -> dict:
    """`--refine edges --frames each`: every solved frame's own pose aligned with its image's
    edges; returns RESULT.json's document with them."""
    from dream.detection import PROGRESS_EVERY_FRAMES
    from dream.edges.frames import refine_frames_with_edges

    def progress(done: int, total: int) -> None:
        print(f"aligned {done}/{total} frames with the image edges", file=sys.stderr)

    results = refine_frames_with_edges(
        seq, robot, result, obs, exclude_links=_links(exclude_links),
        progress=progress if len(seq) > PROGRESS_EVERY_FRAMES else None,
        link_geometry=link_geometry)
    doc = with_refinement(doc, results, seq, result, obs, kind="edges")
    e = doc["edges"]
    print(f"edge alignment of each frame ({e['frames_aligned']} frames, {e['seconds']:.1f} s"
          f"{', background model' if e['background_model'] else ''}): kept in "
          f"{e['frames_kept']}", file=out)
    reported = result.reported_frame
    if reported is not None and results[reported] is not None:
        print(f"  reported frame {doc['reported_frame']}: {results[reported].reason}", file=out)
    return doc


def _links(exclude_links: str | None) -> tuple[str, ...]:
    """The link names of `--exclude-links A,B`."""
    return tuple(n.strip() for n in (exclude_links or "").split(",") if n.strip())


def add_silhouette_check(seq, robot, result, doc: dict, out: TextIO,
                         doc_keypoints: dict | None = None) -> tuple[dict, list]:
    """The silhouettes' cross-check of the pose written by `--refine edges` (or `auto`) for all
    frames, the alignment's or, where it was not kept or could not run, the keypoints' (or
    that of the silhouette polish on the data's masks: `doc_keypoints` None)
    (`dream.coarse.crosscheck`): RESULT.json's `silhouette_check`, the covariance gains the
    disagreement of the two cues (`with_cue_term`), and the verdict's findings on it. Where no
    masks can be made it does not run, and says why. Where the silhouettes side with the
    keypoint pose against a kept alignment (`dream.coarse.crosscheck.undoes_alignment`),
    `doc_keypoints` (the document before the alignment) is written instead, its `edges`
    object saying why."""
    from dream.coarse.crosscheck import silhouette_crosscheck
    from dream.coarse.settings import SearchSettings
    from dream.coarse.verdict import crosscheck_findings
    from dream.errors import InputError
    from dream.refined_uncertainty import with_cue_term
    from dream.refinement_document import pose_refined_by

    try:
        check = silhouette_crosscheck(seq, robot, np.asarray(doc["T_cam_base"]),
                                      result.fit.T_cam_base, progress=lambda line: print(
                                          f"  silhouette check: {line}", file=sys.stderr))
    except InputError as exc:
        print(f"silhouette cross-check did not run: {exc.problem}", file=out)
        return {**doc, "silhouette_check": {"ran": False, "reason": exc.problem}}, []
    o = check.outcome
    if doc_keypoints is not None:
        doc, check = _keypoints_or_aligned(doc, doc_keypoints, check, result.fit.T_cam_base,
                                           out)
    print(f"silhouette cross-check ({check.source} of {check.frames} frames, "
          f"{o.seconds:.1f} s): their optimum lies {check.distance_m * 1e3:.1f} mm and "
          f"{np.rad2deg(check.angle_rad):.2f} deg from the pose written (IoU "
          f"{check.iou_written:.3f} there, {o.best.iou:.3f} at the optimum)", file=out)
    doc, _ = with_cue_term({**doc, "silhouette_check": {"ran": True, **check.to_dict()}},
                           o.best.T_cam_base)
    findings = crosscheck_findings(check.iou_written, o.best.iou, check.distance_m,
                                   check.angle_rad, o.basin_returned, o.basin_starts,
                                   check.source, SearchSettings(), o.basin_m,
                                   doc["silhouette_check"]["away"],
                                   pose_refined_by(doc) or "the keypoint fit")
    doc, intrinsics = _with_intrinsics(doc, check, out)
    return doc, findings + intrinsics


def _with_intrinsics(doc: dict, check, out: TextIO) -> tuple[dict, list]:
    """The document whose covariance holds what the intrinsics the outlines ask for at the
    silhouettes' optimum move the pose by (`Crosscheck.intrinsics_covariance`), and their
    findings (none where the robot was not found there: no fits)."""
    from dream.coarse.distortion import crosscheck_distortion_finding
    from dream.coarse.verdict import crosscheck_focal_finding, principal_finding
    from dream.refined_uncertainty import set_covariance

    record = doc["silhouette_check"]
    if record["focal"] is None:
        return doc, []
    print(f"intrinsics on the outlines: {check.distortion.reason}; {check.focal.reason}; "
          f"{check.principal.reason}", file=out)
    added = check.intrinsics_covariance
    if np.any(added):
        set_covariance(doc, np.asarray(doc["covariance_xi"]) + added)
        doc["uncertainty"]["method"] += " + the move through the intrinsics the outlines ask for"
    findings = (crosscheck_distortion_finding(record.get("distortion")),
                crosscheck_focal_finding(record["focal"]), principal_finding(record["principal"]))
    return doc, [f for f in findings if f is not None]


def _keypoints_or_aligned(doc: dict, doc_keypoints: dict, check: Crosscheck,
                          T_keypoints: np.ndarray, out: TextIO) -> tuple[dict, Crosscheck]:
    """The document and cross-check of the pose the silhouettes side with: the kept
    alignment's, or the keypoint pose's (the alignment undone, its `edges` object saying
    why)."""
    from dream.coarse.crosscheck import undoes_alignment
    from dream.coarse.settings import SearchSettings

    edges = doc.get("edges") or {}
    if not edges.get("kept") or "T_cam_base_aligned" not in edges:
        return doc, check
    undo, to_keypoints, to_aligned = undoes_alignment(
        check, T_keypoints, np.asarray(edges["T_cam_base_aligned"]), SearchSettings())
    if not undo:
        return doc, check
    reason = (f"undone: the silhouettes' optimum ({check.source}) lies "
              f"{to_keypoints * 1e3:.1f} mm from the keypoint pose and {to_aligned * 1e3:.1f} mm "
              "from the aligned one (the alignment slid along what the edges hardly "
              "constrain); the keypoint pose is written")
    print(f"edge alignment {reason}", file=out)
    undone = {**edges, "kept": False, "reason": f"{edges['reason']}; {reason}",
              "undone_by_silhouettes": True}
    return {**doc_keypoints, "edges": undone}, check.at_keypoints(T_keypoints)


def add_quality(result, obs, doc: dict, out: TextIO, extra: list | tuple = (),
                leading: list | tuple = ()) -> dict:
    """The quality verdict (`dream.quality`) on the pose written, with the `extra` findings
    (the `leading` ones first): printed, with its reasons; RESULT.json's `quality` object."""
    quality = written_quality(result, obs, doc, extra, leading)
    print(f"quality: {quality.verdict}", file=out)
    for warning in quality.warnings:
        print(f"  - {warning}", file=out)
    return quality.to_dict()


def print_summary(doc: dict, out: TextIO) -> None:
    """The extrinsic, the camera position, their 1-sigma and the reprojection error."""
    T = np.asarray(doc["T_cam_base"])
    with np.printoptions(precision=5, suppress=True):
        print("T_cam_base (maps base-frame points into the camera frame):", file=out)
        print(T, file=out)
    c = np.asarray(doc["T_base_cam"])[:3, 3]
    sc = np.asarray(doc["sigma_camera_position_base_m"])
    st = np.asarray(doc["sigma_translation_m"])
    sr = np.rad2deg(np.asarray(doc["sigma_rotation_rad"]))
    print(f"camera position in base frame: [{c[0]:+.4f}, {c[1]:+.4f}, {c[2]:+.4f}] m  "
          f"(1-sigma {sc[0] * 1e3:.2f}, {sc[1] * 1e3:.2f}, {sc[2] * 1e3:.2f} mm)", file=out)
    print(f"1-sigma translation (camera axes): {st[0] * 1e3:.2f}, {st[1] * 1e3:.2f}, "
          f"{st[2] * 1e3:.2f} mm; rotation: {sr[0]:.3f}, {sr[1]:.3f}, {sr[2]:.3f} deg", file=out)
    uncertainty = doc.get("uncertainty") or {}
    if uncertainty.get("jackknife_left_out"):
        groups = uncertainty["jackknife_left_out"]
        frames = sum(g.startswith("frames ") for g in groups)
        print(f"  (1-sigma of the pose written: the spread of {uncertainty['refined_by']} "
              f"repeated with each of {len(groups) - frames} links"
              f"{f' and {frames} frame groups' if frames else ''} left out in turn)", file=out)
    elif uncertainty.get("covariance_xi_keypoint_pose") is not None:
        print("  (1-sigma of the keypoint pose: the refined pose had too few links and frames "
              "for its own)", file=out)
    elif uncertainty.get("covariance_xi_keypoint_jackknife") is not None:
        from dream.transforms import camera_position_covariance

        fit_c = camera_position_covariance(np.asarray(doc["T_cam_base"]),
                                           np.asarray(uncertainty["covariance_xi_fit"]))
        left_out = len(uncertainty["keypoint_jackknife_left_out"])
        spread = (f"{left_out} solutions with one keypoint left out of every frame, for errors "
                  "a keypoint repeats across frames" if doc["frames_mode"] == "all" else
                  f"{left_out} solutions of the frame with one keypoint left out, for a "
                  "misplaced keypoint")
        print(f"  (1-sigma = the fit's, {np.sqrt(np.trace(fit_c)) * 1e3:.2f} mm in position, "
              f"for independent detection errors, plus the spread over {spread})", file=out)
    if uncertainty.get("cue_disagreement_xi") is not None:
        print("  (with the disagreement of the pose written and the silhouettes' optimum "
              "added)", file=out)
    if uncertainty.get("keypoint_intrinsics_added"):
        names = " and ".join(uncertainty["keypoint_intrinsics_added"])
        print(f"  (with the move through the {names} the keypoints ask for added: nothing "
              "else checked the given ones)", file=out)
    if doc.get("start") is not None:
        print(f"no keypoints: the pose rests on the robot's silhouettes in "
              f"{len(doc['start']['frames'])} frames ({doc['start']['evidence']})", file=out)
        return
    print(f"reprojection RMSE {doc['rmse_px']:.3f} px over {doc['keypoints_used']} keypoints "
          f"in {doc['frames_used']} frames ({doc['frames_mode']} mode)", file=out)


def print_truth_errors(doc: dict, T_true: np.ndarray, out: TextIO,
                       against: str = "ground truth") -> None:
    """Where the data has ground truth (or a reference extrinsic: `against` "the reference"):
    the written pose's error against it and, with --frames each, the reported frame's and the
    median over the frames' poses written."""
    from dream.metrics import pose_errors
    from dream.result import written_poses

    if doc["frames_mode"] == "all":
        if np.all(np.isfinite(T_true[0])):
            t_err, r_err = pose_errors(np.asarray(doc["T_cam_base"]), T_true[0])
            print(f"error vs {against}: camera position {t_err * 1000:.2f} mm, rotation "
                  f"{np.rad2deg(r_err):.3f} deg", file=out)
        return
    T_written = written_poses(doc)
    both = np.all(np.isfinite(T_written.reshape(len(T_written), -1)), axis=1) & np.all(
        np.isfinite(T_true.reshape(len(T_true), -1)), axis=1)
    if not both.any():
        return
    t_all, r_all = pose_errors(T_written[both], T_true[both])
    reported = [e["frame"] for e in doc["per_frame"]].index(doc["reported_frame"])
    if np.all(np.isfinite(T_true[reported])):
        t_err, r_err = pose_errors(np.asarray(doc["T_cam_base"]), T_true[reported])
        print(f"error vs {against}: reported frame {doc['reported_frame']}: camera "
              f"position {t_err * 1000:.2f} mm, rotation {np.rad2deg(r_err):.3f} deg", file=out)
    print(f"error vs {against} over the {int(both.sum())} frames with a pose: median camera "
          f"position {np.median(t_all) * 1000:.2f} mm, rotation "
          f"{np.rad2deg(np.median(r_all)):.3f} deg", file=out)


def measure_steadiness(seq, frames: str, out: TextIO):
    """Whether the camera of an all-frames calibration stayed put (`dream.steadiness`): its
    `CameraMotion` over up to `max_frames` frames, read here and shrunk as they are read; None
    for per-frame calibrations, data without images, or one frame."""
    from dream.edges.background import grey
    from dream.io import load_image
    from dream.steadiness import SteadinessSettings, camera_motion, shrunk

    if frames != "all" or len(seq) < 2 or not seq.has_images or seq.has_frame_cameras:
        return None
    settings = SteadinessSettings()
    indices = settings.compared(len(seq))
    images = np.stack([shrunk(grey(load_image(seq.frames[i], seq.camera)), settings)
                       for i in indices])
    motion = camera_motion(images, indices, settings, image_width=seq.camera.width)
    if motion.moved.any():
        print(f"steadiness: the camera moved while it recorded ({motion.largest_px:.1f} px "
              f"at most, {motion.moved.sum()} of {len(indices)} compared frames moved; "
              "the verdict says what to do)", file=out)
    return motion


def steadiness_record(motion, seq, doc: dict):
    """RESULT.json's `steadiness` from `measure_steadiness`'s motion (nothing without one),
    and the verdict's finding on it (None where the camera stayed put)."""
    from dream.steadiness import steadiness_finding

    if motion is None:
        return None
    names = [f.name for f in seq.frames]
    doc["steadiness"] = motion.to_dict(names)
    return steadiness_finding(motion, names)
