"""`dream synth --model-extension FILE`: render the world a model extension describes.

The extension (`dream.extension`, the `dream diagnose` vocabulary) changes the true robot and
camera; the written data is what a user would log from that world:

- `joint_offset`: the arm is rendered (and labelled) at reading + offset; the reading is written.
- `link_length`: the scene is built from `Robot.with_link_length_changes` (the stretched joint
  origins place the MuJoCo bodies); labels are the stretched robot's link origins.
- `lens_distortion`, `intrinsics_error`: rendered and labelled through the true camera
  (`extended_camera`, via the lens remap of `synth.lens`); `_camera_settings.json` keeps the
  recipe's (nominal) camera.
- `keypoint_bias`: labels (and keypoint locations) are the biased points of the links.
- `time_offset` (sequence mode `trajectory`): frame i shows the arm at its image time
  t = i / fps; the written reading is the trajectory at t - seconds (readings lag). Before
  t = 0 the arm rests at the trajectory's start.
- `camera_moved` (sequence modes `fixed_camera`, `trajectory`): from the named frame on, the
  true extrinsic is dT @ T_cam_base; the written ground truth is the true per-frame pose.
- `link_geometry`: boxes are rendered attached to their links and scaled links scaled; they are
  part of the robot in the masks and occlude keypoints in the labels. `exclude` (an unknown
  outline) cannot be rendered and is refused.

Other modes refuse the last two (`dream.inject` makes keypoint-only data with them).
"""

from __future__ import annotations

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError, RobotError
from dream.extended import extended_camera, extended_robot, joint_offset_vector, keypoint_points
from dream.extension import ModelExtension
from dream.io.common import FRAME_DIGITS, frame_name
from dream.readings import held_update_times
from dream.robot import Robot
from dream.robot.link_geometry import check_links, check_renderable
from dream.transforms import transform_points
from synth.config import SynthConfig
from synth.nominal import nominal_camera

KEYPOINT_ONLY_HINT = "use dream.inject (keypoint-only sequences) for this effect"


def normalised(extension: ModelExtension | None) -> ModelExtension | None:
    """None for no extension or an empty one (the default path)."""
    if extension is None:
        return None
    if not isinstance(extension, ModelExtension):
        raise InputError("the model extension must be a dream.extension.ModelExtension",
                         fix="read it with dream.extension.read_extension")
    return None if extension.is_empty else extension


def move_index(extension: ModelExtension) -> int | None:
    """Index of the first frame after the camera move, or None without one."""
    move = extension.camera_moved
    if move is None:
        return None
    name = move.frame
    if len(name) != FRAME_DIGITS or not name.isdigit():
        raise InputError(f"camera_moved.frame '{name}' is not a synth frame name",
                         fix=f"name the first frame after the move by its index, "
                             f"{FRAME_DIGITS} digits (e.g. \"000120\")")
    return int(name)


def check_extension(extension: ModelExtension, robot: Robot, config: SynthConfig,
                    num_frames: int) -> None:
    """Refuse, before anything is written, an extension this recipe cannot render.

    Raises:
        InputError: another robot, unknown joints or keypoints, zero-length offsets, a camera
            the lens cannot render, or effects the sequence mode cannot show.
    """
    from dream.plausibility import check_camera
    from synth.lens import plan_lens

    mode = config.sequence.mode
    try:
        true_robot = extended_robot(robot, extension)
    except RobotError as exc:
        raise InputError(f"the model extension does not fit robot '{robot.name}': {exc}") \
            from None
    joint_offset_vector(robot, extension.joint_offset_rad)
    check_links(extension.link_geometry, robot.link_names)
    check_renderable(extension.link_geometry)
    keypoint_points(true_robot, robot.rest_joints[None], None, extension.keypoint_bias_m)
    if extension.intrinsics is not None and not config.intrinsics.fixed:
        raise InputError("intrinsics_error gives absolute intrinsics, but the recipe draws a "
                         "random field of view per frame",
                         fix="give intrinsics.fx, fy, cx, cy in the recipe (the nominal camera)")
    if extension.distortion is not None or extension.intrinsics is not None:
        camera = true_camera(nominal_camera(config), extension)
        try:
            check_camera(camera)        # its intrinsics for the recipe's images
        except InputError as exc:
            raise InputError(f"the model extension's camera on the recipe's {camera.width}x"
                             f"{camera.height} images: {exc.problem}", fix="use the extension "
                             "of a camera of this resolution, or set intrinsics.width and "
                             "height to its images'") from None
        plan_lens(camera)
    if extension.time_offset_s and mode != "trajectory":
        raise InputError(f"time_offset needs sequence.mode trajectory, not '{mode}'",
                         fix=f"set sequence.mode=trajectory, or {KEYPOINT_ONLY_HINT}")
    if extension.held_readings is not None:
        if mode != "trajectory":
            raise InputError(f"held_readings needs sequence.mode trajectory, not '{mode}'",
                             fix=f"set sequence.mode=trajectory, or {KEYPOINT_ONLY_HINT}")
        extension.held_readings.columns(robot.joint_names)
    index = move_index(extension)
    if index is not None:
        if mode == "random":
            raise InputError("camera_moved needs a fixed camera (sequence.mode fixed_camera or "
                             "trajectory), not 'random'",
                             fix=f"set sequence.mode, or {KEYPOINT_ONLY_HINT}")
        if not 0 < index < num_frames:
            raise InputError(f"camera_moved.frame {extension.camera_moved.frame} is not a frame "
                             f"after the first of the {num_frames} frames",
                             fix=f"name a frame between {frame_name(1)} and "
                                 f"{frame_name(num_frames - 1)}")


def true_camera(camera: CameraIntrinsics, extension: ModelExtension | None) -> CameraIntrinsics:
    """The camera the frame is rendered and labelled with (the written one is `camera`)."""
    return camera if extension is None else extended_camera(camera, extension)


def true_pose(T_cam_base: np.ndarray, index: int,
              extension: ModelExtension | None) -> np.ndarray:
    """(4, 4) true extrinsic of frame `index`: dT @ T_cam_base from the camera move on."""
    T = np.asarray(T_cam_base, dtype=float)
    if T.shape != (4, 4):
        raise InputError(f"T_cam_base has shape {T.shape}, expected (4, 4)")
    start = None if extension is None else move_index(extension)
    if start is None or index < start:
        return T
    return extension.camera_moved.T_after_before @ T


def true_keypoints_cam(true_robot: Robot, q_true: np.ndarray, T_cam_base: np.ndarray,
                       extension: ModelExtension | None) -> np.ndarray:
    """(K, 3) labelled points in the camera frame, m: the true robot's link origins at the true
    joints `q_true` (J,), or the biased points of the links."""
    q_true = np.asarray(q_true, dtype=float)
    if q_true.ndim != 1:
        raise InputError(f"q_true must be (J,), got shape {q_true.shape}")
    bias = {} if extension is None else extension.keypoint_bias_m
    return transform_points(T_cam_base, keypoint_points(true_robot, q_true, None, bias))


def held_reading_time(timestamp: float, extension: ModelExtension | None) -> float:
    """When the reading written with the frame at `timestamp` was sampled: the last update of
    the held log at or before it (updates every `period_s` from time 0, shifted by the
    extension's sampling phase); the frame's own time without held readings."""
    held = None if extension is None else extension.held_readings
    if held is None:
        return timestamp
    return float(held_update_times(np.array([0.0, timestamp]), held.period_s, 0.0)[1]
                 - held.phase_s)
