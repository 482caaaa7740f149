"""`dream calibrate`: observations from the labels or a keypoint network -> RESULT.json, plus
RESULT.ros.txt and RESULT.T_base_cam.txt for robot software (`dream.ros`)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from typing import Any, TextIO

from dream.cli.calibrate_report import add_quality, measure_steadiness
from dream.cli.calibrate_write import check_outputs, finish
from dream.cli.intrinsics_records import with_keypoint_intrinsics
from dream.cli.keypoint_pass import PassInputs, keypoint_calibration
from dream.cli.observe import observe
from dream.cli.options import (
    AUTO,
    EDGES,
    INTERPOLATE,
    JOINT_READINGS,
    NONE,
    POLISH,
    REFINE_CHOICES,
    DataOptions,
    add_command,
    add_data_args,
    add_model_source,
    check_seed,
    frames_in_range,
    joint_readings,
    read_data,
    request_from,
)
from dream.cli.require import add_require_arg, required_exit
from dream.errors import InputError
from dream.pnp import RobustLoss, SolverSettings
from dream.ros import CAMERA_OPTICAL_FRAME


@dataclass(frozen=True)
class CalibrateRequest(DataOptions):
    """What `dream calibrate` does: the options of its command line (`loaded_model`: the
    network of `model` already loaded, as `dream demo` does before rendering)."""

    data: str
    out: str
    model: str | None = None
    use_labels: bool = False
    frames: str = "all"
    overlays: str | None = None
    polish: bool = False
    mask_head: bool = False
    motion_masks: bool = False
    loss: str = "huber"
    loss_scale_px: float = RobustLoss().scale_px
    seed: int = 0
    threads: int | None = None
    batch: int | None = None
    model_extension: str | None = None
    joint_readings: str = INTERPOLATE
    refine: str = AUTO
    exclude_links: str | None = None
    base_frame: str | None = None
    camera_frame: str = CAMERA_OPTICAL_FRAME
    camera_guess: str | None = None
    look_at: str | None = None
    guess_sigma: str | None = None
    mark: str | None = None
    mark_link: str | None = None
    mark_offset: str | None = None
    fixed_focal: bool = False
    fixed_principal: bool = False
    fixed_distortion: bool = False
    stamped_timing: bool = False
    frame_range: str | None = None
    loaded_model: Any = None

    def __post_init__(self) -> None:
        _check_mask_head(self.mask_head, self.polish, self.model is not None, self.frames)
        _check_motion_masks(self.motion_masks, self.mask_head, self.polish, self.frames)
        if self.joint_readings not in JOINT_READINGS:
            raise InputError(f"unknown --joint-readings {self.joint_readings!r}",
                             fix=f"use one of {', '.join(JOINT_READINGS)}")
        self.solver_settings()  # checks --seed, --loss and --loss-scale-px
        _check_refine(self.refine, self.frames, self.polish, self.exclude_links)
        _check_frames(self.base_frame, self.camera_frame)
        if self.searches:
            from dream.cli.calibrate_start import camera_guess, check_frames, check_mark_options

            check_frames(self)
            check_mark_options(self)
            camera_guess(self.camera_guess, self.look_at, self.guess_sigma)

    @property
    def keypoints_given(self) -> bool:
        """Whether keypoints come from a network or the labels."""
        return self.model is not None or self.use_labels or self.loaded_model is not None

    @property
    def searches(self) -> bool:
        """Whether the camera pose is searched from the robot's silhouettes: without keypoints,
        or with them and a camera guess or a mark (the keypoint pose then is one more
        hypothesis)."""
        return not self.keypoints_given or bool(self.camera_guess or self.look_at
                                                or self.guess_sigma or self.mark)

    def solver_settings(self) -> SolverSettings:
        """The solver's settings of `--loss`, `--loss-scale-px` and `--seed`."""
        check_seed(self.seed)
        return SolverSettings(loss=RobustLoss(self.loss, self.loss_scale_px), seed=self.seed)


def _check_frames(base_frame: str | None, camera_frame: str) -> None:
    """`--base-frame` and `--camera-frame` are tf frame names (before any reading)."""
    from dream.ros import check_frame_name

    fix = "give a frame name as tf uses it, e.g. camera_color_optical_frame"
    if base_frame is not None:
        check_frame_name(base_frame, "--base-frame", fix)
    check_frame_name(camera_frame, "--camera-frame", fix)


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


def _check_motion_masks(motion_masks: bool, mask_head: bool, polish: bool, frames: str) -> None:
    """`--motion-masks` goes with `--polish` and all frames, not with `--mask-head`."""
    if not motion_masks:
        return
    if not polish:
        raise InputError("--motion-masks chooses the masks of the silhouette polish, and "
                         "--polish was not given", fix="add --polish or drop --motion-masks")
    if mask_head:
        raise InputError("--motion-masks and --mask-head both choose the polish's masks",
                         fix="choose one")
    if frames != "all":
        raise InputError("--motion-masks come from a background model of a fixed camera, for "
                         "the one extrinsic of all frames", fix="use --frames all, or drop "
                         "--motion-masks")


def _check_refine(refine: str, frames: str, polish: bool, exclude_links: str | None) -> None:
    """`--refine` and `--exclude-links` against the other options (before any reading)."""
    if refine not in REFINE_CHOICES:
        raise InputError(f"unknown --refine {refine!r}", fix=f"use one of "
                         f"{', '.join(REFINE_CHOICES)}")
    if refine != EDGES:
        if exclude_links and refine == NONE:
            raise InputError("--exclude-links chooses the links of the edge alignment, and "
                             "--refine none turns it off", fix="drop one of them")
        return
    if polish:
        raise InputError("--refine edges and --polish both refine the extrinsic",
                         fix="choose one: --polish with masks, --refine edges without")


def refine_mode(request: CalibrateRequest, seq) -> str:
    """What `--refine` does with this data: with --polish, the polish; `auto` polishes the
    silhouettes against the data's masks when it has them (as --polish), and aligns edges (the
    one extrinsic of all frames, or each frame's own pose) when every frame has an image and
    none a mask."""
    if request.polish:
        return POLISH
    if request.refine != AUTO:
        return request.refine
    from dream.polish import has_masks

    if has_masks(seq):
        return POLISH
    images = all(f.image_path is not None for f in seq.frames)
    return EDGES if images else NONE


def run_calibrate(request: CalibrateRequest, out: TextIO | None = None) -> dict:
    """`dream calibrate`: observations from the labels (`--use-labels`) or from a keypoint
    network (`--model MODEL.onnx`, run by the `dream.model_loaders` entry point: onnxruntime,
    no torch) -> RESULT.json, plus RESULT.ros.txt and RESULT.T_base_cam.txt for robot
    software (`dream.ros`). Every output location is checked before the work, and the files
    and the --overlays folder appear together or not at all."""
    from dream.io.recording_files import check_spares_recording
    from dream.provenance import data_record

    out = out or sys.stdout
    settings = request.solver_settings()
    paths = check_outputs(request)
    extension = _read_extension(request)
    seq = read_data(request)
    check_spares_recording([request.out, *paths], seq, request.data)
    seq = frames_in_range(seq, request.frame_range)
    data_doc = data_record(seq, request.data)
    seq, readings_doc = joint_readings(seq, request.joint_readings == INTERPOLATE, out)
    refine = refine_mode(request, seq)
    motion = measure_steadiness(seq, request.frames, out)
    if request.searches:
        from dream.cli.calibrate_start import run_search

        return run_search(request, seq, data_doc, readings_doc, refine, paths, out, motion)
    if request.exclude_links and refine != EDGES:
        raise InputError("--exclude-links chooses the links of the edge alignment, and it does "
                         "not run here (--refine auto runs it on data with images and no "
                         "masks, without --polish)", request.data,
                         "add --refine edges, or drop --exclude-links")
    if refine == POLISH and not request.polish:
        print("the data has robot masks: --refine auto polishes the silhouettes against them "
              "(--refine none keeps the keypoint pose)", file=out)
    if refine == POLISH:
        from dream.polish import check_polish_input

        check_polish_input(seq, request.frames,
                           network_masks=request.mask_head or request.motion_masks)
    robot, obs, model = observe(seq, request.robot, request.model, request.use_labels, out,
                                threads=request.threads, batch=request.batch,
                                loaded_model=request.loaded_model, keypoints=request.keypoint_links)
    if extension is not None:
        seq, robot, obs = _apply_extension(request, extension, seq, robot, obs, out)
    inputs = PassInputs(request, robot, obs, extension, refine, settings, data_doc,
                        readings_doc, motion, model)
    kp = keypoint_calibration(inputs, seq, out)
    seq, result, doc = kp.seq, kp.result, kp.doc
    doc, open_intrinsics = with_keypoint_intrinsics(doc, seq.camera)
    doc["quality"] = add_quality(result, obs, doc, out, [*kp.checked, *open_intrinsics],
                                 leading=(kp.readings,))
    finish(request, seq, robot, obs, result, doc, paths, out)
    return doc


def _read_extension(request: CalibrateRequest):
    """The `--model-extension` (None without one)."""
    if not request.model_extension:
        return None
    from dream.extension import read_extension

    return read_extension(request.model_extension)


def _apply_extension(request: CalibrateRequest, extension, seq, robot, obs, out: TextIO):
    """The data, robot (its link lengths) and observations corrected by the model extension (a
    problem without a file of its own names the extension's)."""
    from dream.diagnosis.run import apply_extension_to_observations
    from dream.extended import extended_robot
    from dream.plausibility import check_camera

    frames = len(seq)
    try:
        seq, obs = apply_extension_to_observations(seq, robot, obs, extension)
        robot = extended_robot(robot, extension)
        check_camera(seq.camera)        # its intrinsics for these images (not another size)
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(exc.problem, request.model_extension, exc.fix) from None
    left = (f" ({frames - len(seq)} of {frames} frames left out: before the camera move or "
            "outside the joint log's span)" if len(seq) < frames else "")
    print(f"model extension {request.model_extension}: "
          f"{', '.join(extension.effects) or 'no effect'}{left}", file=out)
    return seq, robot, obs


def cmd_calibrate(args: argparse.Namespace) -> int:
    request = request_from(CalibrateRequest, args)
    doc = run_calibrate(request)
    return required_exit(doc["quality"]["verdict"], args.require, request.out)


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream calibrate` parser."""
    p = add_command(sub, "calibrate", cmd_calibrate,
                    "solve T_cam_base from keypoints of many frames")
    add_data_args(p)
    p.add_argument("--out", required=True, help="RESULT.json to write")
    p.add_argument("--overlays", help="folder for per-frame overlays and a summary image")
    add_require_arg(p, "exit with status 3 where the verdict falls below this (the result is "
                       "written all the same): for scripts that must not go on with a "
                       "calibration to be checked or an unreliable one")
    add_calibrate_args(p)


def add_calibrate_args(p: argparse.ArgumentParser) -> None:
    """The options of `dream calibrate` besides `--data`, `--out` and `--overlays` (which
    `dream batch calibrate` gives other meanings)."""
    add_model_source(p, "detect the keypoints with this network (dream export; runs with "
                        "onnxruntime, no torch). Without --model and --use-labels the camera "
                        "pose is searched from the robot's silhouettes (fixed camera, the arm "
                        "moving, or the data's robot masks)", required=False)
    p.add_argument("--frames", choices=("all", "each"), default="all",
                   help="all: one extrinsic from every frame (fixed camera); each: per frame "
                        "(default: %(default)s)")
    p.add_argument("--polish", action="store_true",
                   help="refine the extrinsic (with --frames each: every frame's own pose) by "
                        "aligning the robot's rendered silhouette with the data's masks (or, "
                        "all frames with --mask-head or --motion-masks, masks made here); kept "
                        "when the IoU improves on the frames that agree (masks made here: and "
                        "the keypoint detections do not contradict it). --refine auto does "
                        "this on data with masks")
    p.add_argument("--refine", choices=REFINE_CHOICES, default=AUTO,
                   help="edges: align the robot's outline (URDF meshes) with the images' edges "
                        "from the keypoint extrinsic, coarse to fine over all frames of the "
                        "fixed camera (with --frames each: each frame's own pose), no masks "
                        "needed; kept only when more of the outline "
                        "lies on edges and the keypoint detections do not contradict it. "
                        "auto (default): the silhouette polish (as --polish) when the data "
                        "has robot masks, edges when it has images and no masks. none: the "
                        "keypoint pose")
    p.add_argument("--exclude-links", metavar="LINK[,LINK...]",
                   help="--refine edges: links left out of the alignment (a tool or gripper "
                        "the URDF lacks; RESULT.json's edges.mismatched_links names suspects)")
    p.add_argument("--mask-head", action="store_true",
                   help="--polish, all frames, data without masks: align with the --model's "
                        "mask head (opt-in: the bundled model's is too coarse and made "
                        "rendered scenes worse: docs/benchmarks.md)")
    p.add_argument("--motion-masks", action="store_true",
                   help="--polish, all frames, data without masks: align with motion masks (the "
                        "pixels that differ from a background model of the fixed camera; "
                        "links that never move left out; dream masks writes them)")
    p.add_argument("--base-frame", metavar="NAME",
                   help="the robot base's tf frame in the written snippets (default: the URDF's "
                        "base link)")
    p.add_argument("--camera-frame", metavar="NAME", default=CAMERA_OPTICAL_FRAME,
                   help="the camera's optical tf frame (x right, y down, z forward) in the "
                        "written snippets (default: %(default)s)")
    p.add_argument("--camera-guess", metavar="X,Y,Z|RESULT.json",
                   help="without keypoints: a rough camera position (metres, base frame; with "
                        "--look-at) or a RESULT.json whose extrinsic is searched around "
                        "(--guess-sigma); without it the search covers a shell around the robot")
    p.add_argument("--look-at", metavar="X,Y,Z",
                   help="with --camera-guess X,Y,Z: a point on the robot the camera looks at "
                        "(metres, base frame)")
    p.add_argument("--guess-sigma", metavar="METRES,DEGREES",
                   help="how rough --camera-guess is, 1-sigma per axis (default 0.3,20)")
    p.add_argument("--mark", metavar="MARKS.csv",
                   help="without keypoints: one point on the end effector clicked in some "
                        "frames (frame,u,v rows; dream mark writes them), tracked through the "
                        "recording; its pose over time is the centre of the search")
    p.add_argument("--mark-link", metavar="LINK",
                   help="with --mark: the URDF link the marked point is fixed to")
    p.add_argument("--mark-offset", metavar="X,Y,Z",
                   help="with --mark: the point in --mark-link's frame, metres (default 0,0,0)")
    p.add_argument("--fixed-focal", action="store_true",
                   help="keep the data's fx, fy as given (by default, on images without "
                        "masks, the scale the robot's outlines determine and their overlap "
                        "agrees with is fitted, the calibration made through it, and reported)")
    p.add_argument("--fixed-principal", action="store_true",
                   help="keep the data's cx, cy as given (by default a principal point "
                        "the robot's outlines ask for, turning the camera by more than 1.5 "
                        "deg beyond their noise, is adopted and the calibration made again "
                        "through it; kept, it is reported and its move enters the 1-sigma)")
    p.add_argument("--fixed-distortion", action="store_true",
                   help="keep the data's distortion as given (by default "
                        "a radial distortion the robot's outlines ask for and their overlap "
                        "agrees with, as of raw images given with a rectified camera, is "
                        "adopted and the calibration made again through it)")
    p.add_argument("--stamped-timing", action="store_true",
                   help="without keypoints: take the joint readings at their timestamps (by "
                        "default the search reads a lag of the joint log behind the images off "
                        "the moving arm's silhouettes, shifts the readings by it where it is "
                        "clear, and reports it)")
    p.add_argument("--frame-range", metavar="START:STOP",
                   help="calibrate only these frames (indices in time order, STOP excluded): "
                        "one still stretch of a recording whose camera moved")
    p.add_argument("--loss", choices=("huber", "cauchy", "l2"), default="huber",
                   help="robust loss of the keypoint fit (default: %(default)s)")
    p.add_argument("--loss-scale-px", type=float, default=RobustLoss().scale_px,
                   help="where the robust loss turns from quadratic, pixels (default: "
                        "%(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the RANSAC sampling (default: %(default)s)")
    p.add_argument("--threads", type=int, default=None,
                   help="--model: onnxruntime threads (default: every core)")
    p.add_argument("--batch", type=int, default=None,
                   help="--model: images per network call (default 8)")
    p.add_argument("--joint-readings", choices=JOINT_READINGS, default=INTERPOLATE,
                   help="a joint log that updates slower than the images (runs of identical "
                        "readings, with timestamps): interpolate the readings in time between "
                        "their updates, or keep them as logged (default: %(default)s)")
    p.add_argument("--model-extension", metavar="FILE",
                   help="extended model (extended_model.yaml of dream diagnose): corrected "
                        "camera, joint offsets, link lengths, keypoint bias, time offset; with "
                        "a camera move only the frames after it are used")
