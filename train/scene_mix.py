"""Renders of the robot in the user's own scene, for `dream adapt` to mix into its teaching.

A calibrated fixed camera fixes everything a network sees but the arm: its intrinsics, its pose
in the base frame and what lies behind the robot. Rendered from that camera (the calibrated
extrinsic, the recording's intrinsics) with the recording's own background behind it (the
plate: each pixel's median over the frames where the robot, rendered at the calibrated
extrinsic and widened by `PLATE_MARGIN_PX`, leaves it free; inpainted where none does), the
robot in random joint configurations under the recipe's randomised lights, appearance and
occluders shows the network poses the recording never showed, against the scene it will see
them in. The real frames teach
the arm's real appearance; these renders teach the rest of its joint space in that scene.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path

import cv2
import numpy as np

from dream.errors import InputError
from dream.sequence import Sequence

log = logging.getLogger(__name__)

PLATE_MARGIN_PX = 3     # the robot's rendered silhouette widened by this before a pixel is
                        # free: the calibration's error and the meshes' decimation
INPAINT_RADIUS_PX = 5   # the neighbourhood a pixel no frame saw free is inpainted from
PLATE_FRAMES = 60       # at most this many evenly spaced frames make the plate
SCENE_WORKERS = 2       # render processes


def scene_plate(images: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """The scene behind the robot (H, W, 3) uint8: each pixel's median over the frames of
    `images` (F, H, W, 3) uint8 where `covered` (F, H, W) bool leaves it free; where every frame
    covers it (no frame saw what lies behind the robot there), inpainted from the free pixels
    around it (OpenCV's Telea method within `INPAINT_RADIUS_PX`).

    >>> images = np.stack([np.full((1, 2, 3), v, np.uint8) for v in (10, 200, 30)])
    >>> covered = np.zeros((3, 1, 2), bool); covered[1] = True; covered[0, 0, 1] = True
    >>> scene_plate(images, covered)[0, :, 0].tolist()
    [20, 30]
    """
    images = np.asarray(images)
    covered = np.asarray(covered, dtype=bool)
    if images.ndim != 4 or images.shape[3] != 3 or images.dtype != np.uint8 or \
            covered.shape != images.shape[:3]:
        raise InputError(f"images {images.shape} {images.dtype} and covered {covered.shape} "
                         "must be (F, H, W, 3) uint8 and (F, H, W)")
    if len(images) == 0:
        raise InputError("a plate needs at least one frame")
    stack = images.astype(np.float32)
    stack[covered] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # pixels covered in every frame
        free = np.nanmedian(stack, axis=0)
    unseen = np.isnan(free[..., 0])
    plate = np.round(np.nan_to_num(free)).astype(np.uint8)
    if unseen.all():
        raise InputError("the robot covers every pixel in every frame: no background to show",
                         fix="record frames where the arm leaves part of the view free")
    if unseen.any():
        plate = cv2.inpaint(plate, unseen.astype(np.uint8), INPAINT_RADIUS_PX,
                            cv2.INPAINT_TELEA)
    return plate


def robot_coverage(sequence: Sequence, robot, T_cam_base: np.ndarray, frames: np.ndarray,
                   margin_px: float = PLATE_MARGIN_PX) -> np.ndarray:
    """(F, H, W) bool: the robot's silhouette in each of `frames` at `T_cam_base`, from its
    joint readings, widened by `margin_px`."""
    from dream.edges.motion import disk
    from dream.pipeline import joints_in_robot_order
    from dream.silhouette import load_robot_meshes, render_frames, vertices_in_base

    camera = sequence.fixed_camera("render the robot's silhouettes at one extrinsic")
    meshes = load_robot_meshes(robot)
    joints = joints_in_robot_order(sequence, robot)[np.asarray(frames, int)]
    rendered = render_frames(vertices_in_base(meshes, joints), meshes.faces, T_cam_base, camera)
    kernel = disk(margin_px)
    if kernel is None:
        return rendered
    return np.stack([cv2.dilate(m.astype(np.uint8), kernel) > 0 for m in rendered])


def plate_frames(frames: np.ndarray, most: int = PLATE_FRAMES) -> np.ndarray:
    """At most `most` of `frames`, evenly spaced.

    >>> plate_frames(np.arange(10), 4).tolist()
    [0, 3, 6, 9]
    """
    frames = np.asarray(frames, int)
    if len(frames) <= most:
        return frames
    return frames[np.round(np.linspace(0, len(frames) - 1, most)).astype(int)]


def recording_plate(sequence: Sequence, robot, T_cam_base: np.ndarray, frames: np.ndarray
                    ) -> np.ndarray:
    """The plate (H, W, 3) uint8 RGB of the recording's `frames` (`scene_plate`)."""
    from dream.io import load_image

    chosen = plate_frames(frames)
    images = np.stack([load_image(sequence.frames[int(i)], sequence.camera) for i in chosen])
    return scene_plate(images, robot_coverage(sequence, robot, T_cam_base, chosen))


def scene_recipe(sequence: Sequence, T_cam_base: np.ndarray, plate_path: Path) -> dict:
    """The synth recipe (over the defaults) of renders from the recording's camera at
    `T_cam_base` with the plate behind the robot: no shell, no close-ups, no floor."""
    from dream.provenance import camera_record

    camera = sequence.fixed_camera("render the recording's own scene")
    return {
        "camera": {"T_cam_base": np.asarray(T_cam_base, float).tolist(), "closeup_prob": 0.0},
        "intrinsics": camera_record(camera),
        "background": {"plate": str(plate_path), "floor_prob": 0.0},
    }


def render_scene_mix(sequence: Sequence, robot, robot_name: str, T_cam_base: np.ndarray,
                     frames: np.ndarray, count: int, out: Path, seed: int) -> Path:
    """`count` renders of the robot in the recording's scene (module doc), its keypoints named
    as `robot`'s, written to `out` in the DREAM layout; the plate made from `frames` is kept
    beside them (`out`/../scene_plate.png)."""
    from synth.config import config_from_dict
    from synth.generate import SynthJob, generate

    out = Path(out)
    plate_path = out.parent / "scene_plate.png"
    plate = recording_plate(sequence, robot, T_cam_base, frames)
    plate_path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(plate_path), cv2.cvtColor(plate, cv2.COLOR_RGB2BGR)):
        raise InputError("cannot write the scene's plate", plate_path,
                         "choose a writable location for the adapted model")
    config = config_from_dict(scene_recipe(sequence, T_cam_base, plate_path))
    generate(SynthJob(robot=robot_name, out_dir=out, num_frames=count, config=config, seed=seed,
                      keypoints=tuple(robot.keypoint_names), workers=SCENE_WORKERS),
             on_progress=lambda done: None)
    log.info("rendered %d frames of the robot in the recording's scene", count)
    return out
