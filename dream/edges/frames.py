"""The edge alignment of every frame's own pose (`dream calibrate --frames each`).

Each solved frame with an image is aligned alone, from its keypoint pose (`align_edges` on one
frame). Where the frames share one camera and a background model explains them
(`background_explains`: in the median frame at least `min_static_share` of the pixels lie
within `motion_threshold` of the model, as for a fixed camera; a moving camera fails it), the
model's side test is used and links that never move are left out; otherwise edges are matched
without it. A frame's aligned pose is kept when more of its outline lies on edges and the
median distance of its own inlier keypoints stays within their median at the keypoint pose
divided by `fit_shrinkage(n)`, plus `frame_median_margin_px` (the single-frame polish's guard:
a frame's few keypoints are fitted closely by its own pose, `dream.polish.guard`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, replace

import numpy as np

from dream.calibration import CalibrationResult, Observations
from dream.edges.background import (
    background_indices,
    background_model,
    load_grey,
    matched_frames,
)
from dream.edges.calibration import edge_jackknife, moving_vertices, outline_meshes
from dream.edges.refine import align_edges
from dream.edges.score import edge_score
from dream.edges.search import scale_images
from dream.edges.settings import EdgeSettings
from dream.errors import CannotRefine, InputError
from dream.pnp import PoseFit
from dream.polish.calibration import inlier_keypoints
from dream.polish.guard import fit_shrinkage
from dream.refined_uncertainty import RefinementJackknife
from dream.robot import Robot
from dream.robot.link_geometry import LinkGeometry
from dream.sequence import Sequence
from dream.silhouette import vertices_in_base

log = logging.getLogger(__name__)

PROGRESS_EVERY_ALIGNED = 64    # progress is reported after this many frames


@dataclass(frozen=True)
class FrameEdgeResult:
    """One frame's edge alignment.

    Attributes:
        frame: its name. T_before: (4, 4) its keypoint pose. T_aligned: the alignment's
        optimum. T_after: the pose kept. kept, reason: the verdict and why.
        agreement_before, agreement_after: share of its outline on an image edge (full
        resolution) at the two poses. median_before, median_after: median distance (px) of
        its inlier keypoints (NaN without). background: whether the background model was
        used. seconds: wall time. jackknife: the jackknife of the kept pose, where computed
        (the reported frame's).
    """

    frame: str
    T_before: np.ndarray
    T_aligned: np.ndarray
    T_after: np.ndarray
    kept: bool
    reason: str
    agreement_before: float
    agreement_after: float
    median_before: float
    median_after: float
    background: bool
    seconds: float
    jackknife: RefinementJackknife | None = None


def background_explains(grey: np.ndarray, background: np.ndarray,
                        settings: EdgeSettings) -> bool:
    """Whether `background` (H, W) is the scene behind grey frames (F, H, W): in the median
    frame at least `min_static_share` of the pixels lie within `motion_threshold` of it (pure).

    >>> frames = np.zeros((9, 4, 4), np.float32)
    >>> background_explains(frames, frames[0], EdgeSettings())
    True
    >>> background_explains(frames + np.arange(9)[:, None, None], frames[0], EdgeSettings())
    False
    """
    close = np.abs(np.asarray(grey) - background) < settings.motion_threshold
    return float(np.median(close.reshape(len(close), -1).mean(axis=1))) >= \
        settings.min_static_share


def decide_frame(agreement0: float, agreement1: float, median0: float, median1: float,
                 n_keypoints: int, settings: EdgeSettings) -> tuple[bool, str]:
    """The keep rule of one frame (module doc): (kept, one sentence why)."""
    edges = f"outline on the image edges {agreement0:.1%} -> {agreement1:.1%}"
    if not agreement1 - agreement0 > settings.min_agreement_gain:
        return False, f"kept the keypoint pose: {edges}, no gain"
    if n_keypoints and np.isfinite(median0):
        allowed = median0 / fit_shrinkage(n_keypoints) + settings.frame_median_margin_px
        if not median1 <= allowed:
            return False, (f"kept the keypoint pose: {edges}, but its keypoints' median "
                           f"distance would grow {median0:.2f} -> {median1:.2f} px (limit "
                           f"{allowed:.2f})")
    return True, f"aligned to the image edges: {edges}"


def refine_frames_with_edges(sequence: Sequence, robot: Robot, result: CalibrationResult,
                             obs: Observations, settings: EdgeSettings | None = None,
                             exclude_links: SequenceOf[str] = (),
                             progress: Callable[[int, int], None] | None = None,
                             link_geometry: tuple[LinkGeometry, ...] = ()
                             ) -> tuple[FrameEdgeResult | None, ...]:
    """Align every solved frame of an "each"-mode `result` with its own image's edges (module
    doc); None for frames without a solution or an image. `progress(done, total)` is called
    every `PROGRESS_EVERY_ALIGNED` frames and at the end. `link_geometry` as in
    `dream.edges.refine_with_edges`.

    Raises:
        InputError: not an each-mode result, no frame with an image, unknown or all links
            excluded.
    """
    from dream.pipeline import joints_in_robot_order

    settings = settings or EdgeSettings()
    if result.mode != "each":
        raise InputError("refine_frames_with_edges aligns each frame's own pose (--frames "
                         "each); align an all-frames result with refine_with_edges")
    todo = [i for i, (frame, solution) in enumerate(zip(sequence.frames, result.frames,
                                                        strict=True))
            if isinstance(solution.fit, PoseFit) and frame.image_path is not None]
    if not todo:
        raise CannotRefine("--refine edges needs solved frames with images, and there are "
                           "none", sequence.source, "add the images, or use --refine none")
    meshes, usable, _ = outline_meshes(robot, settings, exclude_links, link_geometry)
    joints = joints_in_robot_order(sequence, robot)
    usable, background, _ = moving_vertices(meshes, joints, usable,
                                            _shared_background(sequence, settings), settings)
    out: list[FrameEdgeResult | None] = [None] * len(sequence)
    for done, i in enumerate(todo, start=1):
        out[i] = _align_frame(sequence, i, meshes, joints[i:i + 1], result, obs, settings,
                              background, usable, jackknife=i == result.reported_frame)
        if progress is not None and (done % PROGRESS_EVERY_ALIGNED == 0 or done == len(todo)):
            progress(done, len(todo))
    return tuple(out)


def _shared_background(sequence: Sequence, settings: EdgeSettings) -> np.ndarray | None:
    """The background model of the frames when they share one camera, are enough (counted as
    `background_indices` counts them), all have images and the model explains them
    (`background_explains`); else None."""
    chosen = background_indices(sequence, settings.background_frames)
    if len(chosen) < settings.min_background_frames or any(
            f.image_path is None for f in sequence.frames):
        return None
    try:
        camera = sequence.fixed_camera("share a background model")
    except InputError:
        return None
    grey = load_grey(sequence, chosen, camera)
    background = background_model(grey, settings)
    if not background_explains(matched_frames(grey, background, settings.exposure), background,
                               settings):
        log.info("edge alignment of each frame: the frames do not share one background (a "
                 "moving camera?); edges are matched without a background model")
        return None
    return background


def _align_frame(sequence: Sequence, i: int, meshes, joints: np.ndarray,
                 result: CalibrationResult, obs: Observations, settings: EdgeSettings,
                 background: np.ndarray | None, usable: np.ndarray,
                 jackknife: bool = False) -> FrameEdgeResult:
    """Frame i aligned alone from its keypoint pose and judged (`decide_frame`); with
    `jackknife`, a kept pose gets its jackknife (`edge_jackknife`)."""
    start = time.perf_counter()
    frame, camera = sequence.frames[i], sequence.frame_camera(i)
    T0 = np.asarray(result.frames[i].fit.T_cam_base, dtype=float)
    grey = load_grey(sequence, np.array([i]), camera)
    if background is not None and background.shape != grey.shape[1:]:
        background = None
    if background is not None:
        grey = matched_frames(grey, background, settings.exposure)
    P = vertices_in_base(meshes, joints)
    full = scale_images(grey, camera, camera.width, settings, background)
    score0 = edge_score(meshes, P, T0, full, settings, usable)
    if score0.agreement * score0.points < settings.min_outline_points:
        return FrameEdgeResult(frame.name, T0, T0, T0, False, "kept the keypoint pose: no "
                               "image edges near the outline", score0.agreement,
                               score0.agreement, float("nan"), float("nan"),
                               background is not None, time.perf_counter() - start)
    T1, _ = align_edges(P, meshes.faces, grey, camera, T0, settings, background, usable,
                        meshes.vertex_link)
    score1 = edge_score(meshes, P, T1, full, settings, usable)
    guard = inlier_keypoints(result, obs, i)
    n = 0 if guard is None else len(guard.P_base)
    med0, med1 = ((guard.median_px(camera, T0), guard.median_px(camera, T1)) if guard
                  else (float("nan"), float("nan")))
    kept, reason = decide_frame(score0.agreement, score1.agreement, med0, med1, n, settings)
    res = FrameEdgeResult(frame.name, T0, T1, T1 if kept else T0, kept, reason,
                          score0.agreement, score1.agreement, med0, med1,
                          background is not None, time.perf_counter() - start)
    if kept and jackknife:
        res = replace(res, jackknife=edge_jackknife(meshes, P, grey, camera, T1, settings,
                                                    background, usable, score1))
    return res
