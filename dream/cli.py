"""`dream` command line: thin wrappers around the library. Every failure is one line on stderr."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np

from dream import __version__
from dream.camera import CameraIntrinsics
from dream.errors import DreamError, InputError
from dream.pnp import RobustLoss, SolverSettings

log = logging.getLogger("dream")

ENTRY_POINT_GROUP = "dream.commands"
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141          # 128 + SIGPIPE, what a shell reports for a writer cut off


FIX_INTRINSICS = "give --intrinsics fx,fy,cx,cy or fx,fy,cx,cy,width,height (pixels)"


def _parse_intrinsics(text: str | None) -> CameraIntrinsics | tuple[float, ...] | None:
    """'fx,fy,cx,cy' (size from the images) or 'fx,fy,cx,cy,width,height'; a bad value is an
    `InputError` naming the option (not the data's camera file)."""
    if text is None:
        return None
    from dream.io import parse_intrinsics_text

    parts = text.split(",")
    if len(parts) != 6:
        return parse_intrinsics_text(text, "--intrinsics")
    try:
        w, h = int(parts[4]), int(parts[5])
    except ValueError:
        raise InputError(f"--intrinsics '{text}': width and height must be integers",
                         fix=FIX_INTRINSICS) from None
    fx_fy_cx_cy = parse_intrinsics_text(",".join(parts[:4]), "--intrinsics")
    try:
        return CameraIntrinsics(*fx_fy_cx_cy, w, h)
    except InputError as exc:
        raise InputError(f"--intrinsics '{text}': {exc.problem}", fix=FIX_INTRINSICS) from None


def _check_positive(value: int | None, option: str, fix: str) -> None:
    """A whole-number option that must be >= 1 when given (None: its default)."""
    if value is not None and value < 1:
        raise InputError(f"{option} must be 1 or more, got {value}", fix=fix)


def _check_seed(seed: int | None) -> None:
    if seed is not None and seed < 0:
        raise InputError(f"--seed must be a whole number >= 0, got {seed}",
                         fix="give --seed 0 or a positive integer")


def _read(args: argparse.Namespace):
    from dream.io import read_sequence

    return read_sequence(args.data, intrinsics=_parse_intrinsics(getattr(args, "intrinsics", None)),
                         robot=getattr(args, "robot", None))


def cmd_robots(args: argparse.Namespace) -> int:
    from dream.robot import builtin_robots

    for entry in builtin_robots():
        print(f"{entry.name}: {entry.description}")
        print(f"  keypoints: {', '.join(entry.keypoints)}")
        print(f"  why: {entry.rationale}")
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    seq = _read(args)
    cam = seq.camera
    print(f"data:      {args.data} ({len(seq)} frames)")
    print(f"robot:     {seq.robot}")
    dist = "none" if cam.distortion is None else ", ".join(f"{c:.4g}" for c in cam.distortion)
    print(f"camera:    {cam.width}x{cam.height} fx={cam.fx:.2f} fy={cam.fy:.2f} cx={cam.cx:.2f} "
          f"cy={cam.cy:.2f} distortion: {dist}")
    if seq.has_frame_cameras:
        fx = [seq.frame_camera(i).fx for i in range(len(seq))]
        print(f"           frames carry their own intrinsics: fx {min(fx):.2f} to {max(fx):.2f} "
              "(solve them with --frames each)")
    frames = seq.frames
    print(f"images:    {sum(f.image_path is not None for f in frames)}   masks: "
          f"{sum(f.mask_path is not None for f in frames)}   timestamps: "
          f"{sum(f.timestamp is not None for f in frames)}")
    labelled = sum(f.uv_labels is not None for f in frames)
    print(f"labels:    {labelled} frames with 2D keypoint labels "
          f"({', '.join(seq.keypoint_names) or 'none'})")
    truth = sum(f.T_cam_base_true is not None for f in frames)
    print(f"truth:     {truth} frames with ground-truth pose; reference extrinsic: "
          f"{'yes' if seq.T_cam_base_reference is not None else 'no'}")
    if frames[0].timestamp is not None and len(frames) > 1:
        t = np.array([f.timestamp for f in frames if f.timestamp is not None])
        print(f"time:      {t[-1] - t[0]:.3f} s, median period {np.median(np.diff(t)):.4f} s")
    q = seq.joints
    print("joints (min .. max):")
    for name, lo, hi in zip(seq.joint_names, q.min(0), q.max(0), strict=True):
        print(f"  {name:24s} {lo:+.4f} .. {hi:+.4f}")
    return 0


def cmd_overlay(args: argparse.Namespace) -> int:
    from dream.io import check_output_folder
    from dream.overlay import check_limit, write_skeleton_overlays
    from dream.pipeline import robot_for
    from dream.result import read_result

    check_limit(args.limit)
    check_output_folder(args.out)  # before any reading or drawing
    seq = _read(args)
    robot = robot_for(seq, args.robot)
    if args.extrinsic is not None:
        T = read_result(args.extrinsic)["T_cam_base"]
        poses = np.broadcast_to(T, (len(seq), 4, 4))
    else:
        from dream.pipeline import truth_poses

        if not seq.has_ground_truth:
            raise InputError("the data has no reference extrinsic", args.data,
                             "pass --extrinsic RESULT.json")
        poses = truth_poses(seq)
    n = write_skeleton_overlays(seq, robot, poses, Path(args.out), limit=args.limit)
    print(f"wrote {n} overlay images to {args.out}")
    return 0


def _settings(args: argparse.Namespace) -> SolverSettings:
    _check_seed(args.seed)
    return SolverSettings(loss=RobustLoss(args.loss, args.loss_scale_px), seed=args.seed)


def _detect(args: argparse.Namespace, seq, out):
    """Robot, observations and the loaded network of `--model` (onnxruntime, no torch),
    with a progress line on stderr every `PROGRESS_EVERY_FRAMES` frames."""
    from dream.detect import (
        DEFAULT_BATCH_SIZE,
        PROGRESS_EVERY_FRAMES,
        check_images,
        detect_keypoints,
        load_keypoint_model,
        load_model_robot,
    )

    batch = getattr(args, "batch", None)
    _check_positive(batch, "--batch", "give --batch 1 or more images per network call "
                    f"(default {DEFAULT_BATCH_SIZE})")
    batch = DEFAULT_BATCH_SIZE if batch is None else batch
    check_images(seq)
    model = getattr(args, "loaded_model", None)  # `dream demo` loads it before rendering
    if model is None:
        model = load_keypoint_model(args.model, threads=getattr(args, "threads", None))
    robot = load_model_robot(seq, model, args.robot)
    trained_on = getattr(model, "robot", None)
    if trained_on is not None and trained_on != robot.name:
        log.warning("the model was trained on robot '%s', the data is of '%s'", trained_on,
                    robot.name)
    every = PROGRESS_EVERY_FRAMES

    def progress(done: int, total: int) -> None:  # a line each time `every` is crossed
        if done == total or done // every > (done - batch) // every:
            print(f"detected keypoints in {done}/{total} frames", file=sys.stderr)

    obs = detect_keypoints(seq, robot, model, batch_size=batch,
                           peak_params=getattr(model, "peak_params", None),
                           progress=progress if len(seq) > every else None)
    print(f"{args.model}: found {int(obs.found.sum())} of {obs.found.size} keypoints in "
          f"{len(seq)} frames", file=out)
    return robot, obs, model


def _check_mask_head(mask_head: bool, polish: bool, model: bool, frames: str) -> None:
    """`--mask-head` goes with `--polish`, `--model` and all frames (checked before any
    reading)."""
    if not mask_head:
        return
    if not polish:
        raise InputError("--mask-head chooses the masks of the silhouette polish, and --polish "
                         "was not given", fix="add --polish or drop --mask-head")
    if not model:
        raise InputError("--mask-head takes the masks from the --model's mask head, and no "
                         "--model was given", fix="add --model MODEL.onnx or drop --mask-head")
    if frames != "all":
        raise InputError("--mask-head polishes the one extrinsic of all frames; the mask head "
                         "is too coarse to polish a frame alone",
                         fix="use --frames all, or drop --mask-head")


def run_calibrate(args: argparse.Namespace, out=None) -> dict:
    """`dream calibrate`: observations from the labels (`--use-labels`) or from a keypoint
    network (`--model MODEL.onnx`, run by the `dream.model_loaders` entry point: onnxruntime,
    no torch) -> RESULT.json, plus RESULT.ros.txt and RESULT.T_base_cam.txt for robot
    software (`dream.ros`). Every output location is checked before the work, and the files
    and the --overlays folder appear together or not at all."""
    from dream.pipeline import calibrate, observations_from_labels, robot_for, truth_poses
    from dream.result import result_to_dict

    out = out or sys.stdout
    polish = getattr(args, "polish", False)
    mask_head = getattr(args, "mask_head", False)
    _check_mask_head(mask_head, polish, getattr(args, "model", None) is not None, args.frames)
    settings = _settings(args)
    ros_path, matrix_path = _check_calibrate_outputs(args)
    extension = None
    if getattr(args, "model_extension", None):
        from dream.extension import read_extension

        if polish:
            raise InputError("--polish renders the nominal robot and cannot use a model "
                             "extension", args.model_extension,
                             "drop --polish or --model-extension")
        extension = read_extension(args.model_extension)
    seq = _read(args)
    if polish:
        from dream.polish import check_polish_input

        check_polish_input(seq, args.frames, network_masks=mask_head)
    model = None
    if getattr(args, "model", None) is not None:
        robot, obs, model = _detect(args, seq, out)
    else:
        keypoints = seq.keypoint_names if args.use_labels else None
        robot = robot_for(seq, args.robot, keypoints, keypoints_from=seq.source)
        obs = observations_from_labels(seq, robot)
    if extension is not None:
        from dream.diagnose.run import apply_extension_to_observations

        try:
            seq, obs = apply_extension_to_observations(seq, robot, obs, extension)
        except InputError as exc:
            if exc.path is not None:
                raise
            raise InputError(exc.problem, args.model_extension, exc.fix) from None
        print(f"model extension {args.model_extension}: "
              f"{', '.join(extension.effects) or 'no effect'}", file=out)
    result = calibrate(seq, obs, args.frames, settings)
    doc = result_to_dict(result, obs, robot=args.robot or seq.robot)
    if extension is not None:
        doc["model_extension"] = {"file": str(args.model_extension),
                                  "effects": extension.to_dict()["effects"],
                                  "camera": {"fx": seq.camera.fx, "fy": seq.camera.fy,
                                             "cx": seq.camera.cx, "cy": seq.camera.cy,
                                             "distortion": seq.camera.distortion}}
    if polish:
        doc = _polish(args, seq, robot, result, obs, model, doc, out)
    _write_calibration(args, seq, robot, obs, result, doc, ros_path, matrix_path)
    _print_summary(doc, out)
    T_true = truth_poses(seq)
    if args.frames == "all" and np.all(np.isfinite(T_true[0])):
        from dream.metrics import pose_errors

        t_err, r_err = pose_errors(np.asarray(doc["T_cam_base"]), T_true[0])
        print(f"error vs ground truth: camera position {t_err * 1000:.2f} mm, rotation "
              f"{np.rad2deg(r_err):.3f} deg", file=out)
    print(f"wrote {args.out}, {ros_path} (ROS static_transform_publisher: x y z qx qy qz qw "
          f"{robot.base_link} camera_optical_frame) and {matrix_path} (T_base_cam)", file=out)
    return doc


def _check_calibrate_outputs(args: argparse.Namespace) -> tuple[Path, Path]:
    """Before any work: RESULT.json, RESULT.ros.txt and RESULT.T_base_cam.txt can be written
    and the --overlays folder can be made; returns the paths of the two text files."""
    from dream.io import check_output_file, check_output_folder
    from dream.ros import output_paths

    check_output_file(args.out)
    ros_path, matrix_path = output_paths(args.out)
    for path in (ros_path, matrix_path):
        try:
            check_output_file(path)
        except InputError as exc:
            raise InputError(f"{exc.problem} (dream calibrate --out {args.out} writes it)",
                             exc.path, "remove it, or choose another --out") from None
    if getattr(args, "overlays", None):
        check_output_folder(args.overlays)
    return ros_path, matrix_path


def _write_calibration(args: argparse.Namespace, seq, robot, obs, result, doc: dict,
                       ros_path: Path, matrix_path: Path) -> None:
    """RESULT.json, its two text files and the --overlays folder, all or none: the files are
    written, then the overlays drawn (`write_result_overlays` stages them in a temporary folder
    and moves them into place); on a failure of either (an unreadable image...) the files are
    put back as they were before the command."""
    from dream.io import replacing_files
    from dream.io.atomic import dumps
    from dream.ros import matrix_text, ros_text

    T = np.asarray(doc["T_cam_base"])
    files = {Path(args.out): dumps(doc).encode("utf-8"),
             ros_path: ros_text(T, robot.base_link, file_name=ros_path.name).encode("utf-8"),
             matrix_path: matrix_text(T, robot.base_link).encode("utf-8")}
    with replacing_files(files):  # a failure puts the files back
        if args.overlays:
            from dream.overlay import write_result_overlays

            write_result_overlays(seq, robot, obs, result, Path(args.overlays))


def _polish(args: argparse.Namespace, seq, robot, result, obs, model, doc: dict, out) -> dict:
    """`--polish`: the silhouette polish of the one extrinsic (all frames) or of every frame's
    own pose (`--frames each`); returns RESULT.json's document with it."""
    from dream.detect import PROGRESS_EVERY_FRAMES
    from dream.polish import (
        has_masks,
        polish_calibration,
        polish_frames,
        result_doc_with_frame_polishes,
        result_doc_with_polish,
    )

    if args.frames == "all":
        predict = None
        if not has_masks(seq):  # --mask-head (checked)
            from dream.detect import predict_masks

            predict = lambda idx: predict_masks(seq, model, idx)  # noqa: E731
            print("no masks in the data: the polish uses the network's mask head (--mask-head)",
                  file=out)
        elif getattr(args, "mask_head", False):
            print("the data has masks: the polish uses them, not the mask head", file=out)
        report = polish_calibration(seq, robot, result, obs, predict_masks=predict)
        print(f"silhouette polish ({len(report.frames)} frames with masks, "
              f"{report.seconds:.1f} s): {report.reason}", file=out)
        return result_doc_with_polish(doc, report)

    def progress(done: int, total: int) -> None:
        print(f"polished {done}/{total} frames", file=sys.stderr)

    reports = polish_frames(seq, robot, result, obs,
                            progress=progress if len(seq) > PROGRESS_EVERY_FRAMES else None)
    doc = result_doc_with_frame_polishes(doc, reports)
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


def cmd_diagnose(args: argparse.Namespace) -> int:
    """`dream diagnose`: residual analysis, effect catalog, cross-validated model selection."""
    from dream.diagnose.run import run_diagnosis
    from dream.diagnose.select import DiagnoseSettings
    from dream.io import check_output_folder
    from dream.pipeline import observations_from_labels, robot_for

    check_output_folder(args.out)  # before the analysis, which takes a while
    seq = _read(args)
    if args.model is not None:
        robot, obs, _ = _detect(args, seq, sys.stdout)
    else:
        robot = robot_for(seq, args.robot, seq.keypoint_names, keypoints_from=seq.source)
        obs = observations_from_labels(seq, robot)
    effects = tuple(e.strip() for e in args.effects.split(",")) if args.effects else None
    settings = DiagnoseSettings(**({"effects": effects} if effects else {}),
                                folds=args.folds)
    doc = run_diagnosis(seq, robot, obs, args.out, settings,
                        progress=lambda message: print(message, file=sys.stderr))
    gain = doc["gain"]
    print(f"baseline: held-out RMSE {gain['heldout_rmse_px_before']:.3f} px")
    print(f"verdict: {', '.join(doc['verdict']) or 'no significant effect'}")
    for effect in doc["effects"]:
        if effect["name"] in doc["verdict"]:
            print(f"  {effect['name']}: {effect['params']}")
    print(f"extended model: held-out RMSE {gain['heldout_rmse_px_after']:.3f} px")
    truth = doc.get("truth")
    if truth:
        for label in ("before", "after"):
            t = truth[label]
            print(f"vs ground truth {label}: camera position {1000 * t['translation_error_m']:.2f}"
                  f" mm, rotation {np.rad2deg(t['rotation_error_rad']):.3f} deg, ADD "
                  f"{1000 * t['add_mean_m']:.2f} mm")
    print(f"wrote {Path(args.out) / 'diagnosis.json'}, {doc['extended_model']} and "
          f"{Path(args.out) / 'report.md'} ({doc['seconds']:.1f} s)")
    return 0


def _print_summary(doc: dict, out) -> None:
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
    if uncertainty.get("covariance_xi_keypoint_jackknife") is not None:
        from dream.result import camera_position_covariance

        fit_c = camera_position_covariance(np.asarray(doc["T_cam_base"]),
                                           np.asarray(uncertainty["covariance_xi_fit"]))
        left_out = len(uncertainty["keypoint_jackknife_left_out"])
        spread = (f"{left_out} solutions with one keypoint left out of every frame, for errors "
                  "a keypoint repeats across frames" if doc["frames_mode"] == "all" else
                  f"{left_out} solutions of the frame with one keypoint left out, for a "
                  "misplaced keypoint")
        print(f"  (1-sigma = the fit's, {np.sqrt(np.trace(fit_c)) * 1e3:.2f} mm in position, "
              f"for independent detection errors, plus the spread over {spread})", file=out)
    print(f"reprojection RMSE {doc['rmse_px']:.3f} px over {doc['keypoints_used']} keypoints "
          f"in {doc['frames_used']} frames ({doc['frames_mode']} mode)", file=out)


def cmd_calibrate(args: argparse.Namespace) -> int:
    run_calibrate(args)
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from dream.io import check_output_file, write_json_atomic
    from dream.pipeline import evaluate, robot_for
    from dream.result import read_result

    check_output_file(args.out)
    doc = read_result(args.result)
    seq = _read(args)
    names = [k["name"] for f in doc["per_frame"][:1] for k in f.get("keypoints") or []]
    robot = robot_for(seq, args.robot or doc.get("robot"), tuple(names) or None,
                      robot_from=args.result if not args.robot and doc.get("robot") else None,
                      keypoints_from=args.result)
    metrics = evaluate(seq, robot, doc)
    write_json_atomic(args.out, metrics)
    add, t, r = metrics["add_m"], metrics["translation_error_m"], metrics["rotation_error_rad"]
    fmt = lambda v, s=1.0: "n/a" if v is None else f"{v * s:.3f}"  # noqa: E731
    print(f"ADD mean {fmt(add['mean'], 1e3)} mm, median {fmt(add['median'], 1e3)} mm, "
          f"ADD AUC {metrics['add_auc']:.4f} (0-{metrics['add_auc_threshold_m']} m, "
          f"{metrics['frames_in_add_auc']} frames)")
    kp = metrics["keypoint_l2_px"]
    print(f"keypoint L2 mean {fmt(kp['mean'])} px, median {fmt(kp['median'])} px, PCK AUC "
          f"{metrics['pck_auc']:.4f} (0-{metrics['pck_auc_threshold_px']:g} px)")
    print(f"camera position error median {fmt(t['median'], 1e3)} mm, rotation error median "
          f"{fmt(r['median'], np.rad2deg(1))} deg")
    print(f"wrote {args.out}")
    return 0


def cmd_sample(args: argparse.Namespace) -> int:
    from dream.io import write_dream
    from dream.sample import SampleSpec, make_sample

    _check_seed(args.seed)
    _check_positive(args.num, "--num", "give --num 1 or more frames")
    if not np.isfinite(args.noise_px) or args.noise_px < 0:
        raise InputError(f"--noise-px must be a finite number of pixels >= 0, got "
                         f"{args.noise_px}", fix="give e.g. --noise-px 1.0 (0: exact labels)")
    if not np.isfinite(args.outliers) or not 0 <= args.outliers <= 1:
        raise InputError(f"--outliers must be a fraction between 0 and 1, got {args.outliers}",
                         fix="give e.g. --outliers 0.1 (0: no outlier labels)")
    spec = SampleSpec(robot=args.robot, num_frames=args.num, pixel_noise_px=args.noise_px,
                      outlier_fraction=args.outliers, seed=args.seed)
    write_dream(make_sample(spec), Path(args.out), overwrite=args.overwrite)
    print(f"wrote {spec.num_frames} keypoint-only frames of {spec.robot} to {args.out}")
    return 0


BUNDLED_MODEL = Path(__file__).resolve().parent / "models" / "panda_cpu.onnx"


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job on the embedded default scene: render -> detect (bundled model) ->
    calibrate -> print the extrinsic, its uncertainty and its error -> overlays.
    `--keypoints-only`: the keypoint-only sample calibrated from its labels (no rendering)."""
    import importlib

    from dream.io import check_output_folder

    _check_seed(args.seed)
    if args.out:
        check_output_folder(args.out)
    work = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="dream-demo-"))
    if args.keypoints_only:
        from dream.io import write_dream
        from dream.sample import SampleSpec, make_sample

        data = work / "sample"
        spec = SampleSpec(seed=0 if args.seed is None else args.seed, outlier_fraction=0.1)
        print(f"built-in synthetic sample: {spec.num_frames} frames of {spec.robot}, "
              f"{spec.pixel_noise_px:g} px noise, {spec.outlier_fraction:.0%} outlier labels "
              f"-> {data}")
        write_dream(make_sample(spec), data, overwrite=True)
        ns = argparse.Namespace(data=str(data), use_labels=True, robot=None, frames="all",
                                out=str(work / "result.json"), overlays=None, loss="huber",
                                loss_scale_px=3.0, seed=0, intrinsics=None)
        run_calibrate(ns)
        print(f"same as: dream calibrate --data {data} --use-labels --out "
              f"{work / 'result.json'}")
        return 0
    model = Path(args.model) if args.model else BUNDLED_MODEL
    if not model.is_file():
        raise InputError("the keypoint model is missing", model,
                         "reinstall the project (the bundled model ships in dream/models/), "
                         "give --model MODEL.onnx, or run dream demo --keypoints-only")
    from dream.detect import load_keypoint_model, robot_for_model
    from dream.robot import load_robot

    loaded = load_keypoint_model(model)  # a bad model fails here, before the rendering
    demo = importlib.import_module("synth.demo")  # the renderer (MuJoCo), loaded only here
    robot_for_model(load_robot(demo.DEMO_ROBOT), loaded)
    seed = demo.DEMO_SEED if args.seed is None else args.seed
    data = work / "scene"
    print(f"rendering the demo scene: {demo.DEMO_FRAMES} frames of {demo.DEMO_ROBOT}, one fixed "
          f"camera, seed {seed} -> {data}")
    demo.render_demo_scene(data, seed=seed)
    ns = argparse.Namespace(data=str(data), model=str(model), use_labels=False, robot=None,
                            frames="all", out=str(work / "result.json"),
                            overlays=str(work / "overlays"), polish=False, loss="huber",
                            loss_scale_px=RobustLoss().scale_px, seed=0, intrinsics=None,
                            threads=None, batch=None, model_extension=None,
                            loaded_model=loaded)
    run_calibrate(ns)
    print(f"overlays in {work / 'overlays'}; same as: dream calibrate --data {data} --model "
          f"{model} --overlays {work / 'overlays'} --out {work / 'result.json'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dream", description=__doc__)
    parser.add_argument("--version", action="version", version=f"dream {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    def add(name: str, fn: Callable[[argparse.Namespace], int], help_: str):
        p = sub.add_parser(name, help=help_, description=help_)
        p.set_defaults(func=fn)
        return p

    def data_args(p, required=True):
        p.add_argument("--data", required=required, help="dataset folder (DREAM layout, "
                       "panda_teleop, franka_offline) or ManiUniCon .npz")
        p.add_argument("--robot", help="built-in robot name or URDF path (default: the data's)")
        p.add_argument("--intrinsics", help="fx,fy,cx,cy[,width,height] for data without them")

    add("robots", cmd_robots, "list built-in robots and their default keypoints")
    p = add("info", cmd_info, "summarise a dataset: frames, robot, camera, labels, truth")
    p.add_argument("data", help="dataset folder or .npz")
    p.add_argument("--intrinsics", help="fx,fy,cx,cy[,width,height] for data without them")
    p.add_argument("--robot", help=argparse.SUPPRESS)

    p = add("overlay", cmd_overlay, "draw projected keypoints and skeleton on the images")
    p.add_argument("data", help="dataset folder or .npz")
    p.add_argument("--out", required=True, help="folder for the overlay PNGs")
    p.add_argument("--extrinsic", help="RESULT.json to draw with (default: the data's reference)")
    p.add_argument("--robot", help="built-in robot name or URDF path (default: the data's)")
    p.add_argument("--intrinsics", help="fx,fy,cx,cy[,width,height] for data without them")
    p.add_argument("--limit", type=int, default=None, help="draw at most this many frames")

    p = add("calibrate", cmd_calibrate, "solve T_cam_base from keypoints of many frames")
    data_args(p)
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--model", metavar="MODEL.onnx",
                        help="detect the keypoints with this network (dream export; runs with "
                             "onnxruntime, no torch)")
    source.add_argument("--use-labels", action="store_true",
                        help="take 2D observations from the labels (projected_location)")
    p.add_argument("--out", required=True, help="RESULT.json to write")
    p.add_argument("--frames", choices=("all", "each"), default="all",
                   help="all: one extrinsic from every frame (fixed camera); each: per frame")
    p.add_argument("--overlays", help="folder for per-frame overlays and a summary image")
    p.add_argument("--polish", action="store_true",
                   help="refine the extrinsic (with --frames each: every frame's own pose) by "
                        "aligning the robot's rendered silhouette with the data's masks (or, "
                        "all frames with --mask-head, the --model's mask head); kept only when "
                        "the IoU improves without spoiling the keypoint fit")
    p.add_argument("--mask-head", action="store_true",
                   help="--polish, all frames, data without masks: align with the --model's "
                        "mask head (opt-in: the bundled model's is too coarse and made "
                        "rendered scenes worse, see README)")
    p.add_argument("--loss", choices=("huber", "cauchy", "l2"), default="huber")
    p.add_argument("--loss-scale-px", type=float, default=RobustLoss().scale_px)
    p.add_argument("--seed", type=int, default=0, help="seed of the RANSAC sampling")
    p.add_argument("--threads", type=int, default=None,
                   help="--model: onnxruntime threads (default: every core)")
    p.add_argument("--batch", type=int, default=None,
                   help="--model: images per network call (default 8)")

    p.add_argument("--model-extension", metavar="FILE",
                   help="extended model (extended_model.yaml of dream diagnose): corrected "
                        "camera, joint offsets, link lengths, keypoint bias, time offset; with "
                        "a camera move only the frames after it are used")

    p = add("diagnose", cmd_diagnose, "find what the robot-and-camera model gets wrong on "
            "measured data, extend it and measure the gain")
    data_args(p)
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--model", metavar="MODEL.onnx",
                        help="detect the keypoints with this network (onnxruntime, no torch)")
    source.add_argument("--use-labels", action="store_true",
                        help="take 2D observations from the labels (projected_location)")
    p.add_argument("--out", required=True, metavar="REPORT_DIR",
                   help="folder for diagnosis.json, extended_model.yaml, report.md and plots")
    p.add_argument("--effects", help="comma-separated effects to test (default: all of "
                   "joint_offset, lens_distortion, intrinsics_error, time_offset, link_length, "
                   "camera_moved, keypoint_bias)")
    p.add_argument("--folds", type=int, default=5, help="cross-validation folds over frames")
    p.add_argument("--threads", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--batch", type=int, default=None, help=argparse.SUPPRESS)

    p = add("eval", cmd_eval, "score a RESULT.json against the data's ground truth")
    data_args(p)
    p.add_argument("--result", required=True, help="RESULT.json of dream calibrate")
    p.add_argument("--out", required=True, help="METRICS.json to write")

    p = add("sample", cmd_sample, "write the built-in keypoint-only synthetic sample")
    p.add_argument("--out", required=True)
    p.add_argument("--robot", default="panda")
    p.add_argument("--num", type=int, default=20, help="frames")
    p.add_argument("--noise-px", type=float, default=1.0)
    p.add_argument("--outliers", type=float, default=0.0, help="fraction of random labels")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--overwrite", action="store_true")

    p = add("demo", cmd_demo, "the main job on the embedded default scene: render a Panda "
            "sequence, detect its keypoints with the bundled model, calibrate, compare with "
            "the truth, draw overlays")
    p.add_argument("--out", help="working folder (default: a new temporary folder)")
    p.add_argument("--seed", type=int, default=None, help="scene seed (default: the fixed one)")
    p.add_argument("--model", metavar="MODEL.onnx", help="another model than the bundled one")
    p.add_argument("--keypoints-only", action="store_true",
                   help="calibrate the keypoint-only sample from its labels instead (no "
                        "rendering, no network)")
    _add_stage_commands(sub)
    return parser


def _add_stage_commands(sub: argparse._SubParsersAction) -> None:
    """Commands of the other stages (synth, train, export), found through the `dream.commands`
    entry points so that the core imports none of them. Each entry point is a function
    `register(subparsers)` that adds its parser and sets `func`; it must import nothing heavy."""
    for entry in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        try:
            register = entry.load()
        except ImportError as exc:
            log.warning("command '%s' is unavailable (%s)", entry.name, exc)
            continue
        register(sub)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        code = args.func(args)
        sys.stdout.flush()  # a closed reader shows up here, not at interpreter exit
        return code
    except BrokenPipeError:
        # the reader of the output went away (`dream info DATA | head`): stop quietly, as
        # command-line tools do, without a second error when Python flushes stdout at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except DreamError as exc:
        print(f"dream {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"dream {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
