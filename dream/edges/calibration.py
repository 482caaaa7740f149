"""The edge alignment applied to a fixed-camera calibration, and whether its pose is kept.

`refine_with_edges`: the frames with images (at most `max_search_frames`, evenly spaced), their
grey images, the background model of the whole sequence (`dream.edges.background`, when it has
enough frames), the robot's meshes, then the coarse-to-fine alignment from the keypoint
extrinsic (`dream.edges.refine`). The aligned pose is kept when its outline agrees with more of
the images' edges than the keypoint pose's (`dream.edges.score`, full resolution) and all the
keypoint detections, not only the inliers of the keypoint fit, do not contradict it: their
median distance stays within max(`max_keypoint_factor` x before, before + `keypoint_margin_px`).
A keypoint fit that kept a small, biased consensus leaves most detections far from its pose,
so their median does not protect it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, replace

import numpy as np

from dream.calibration import Observations
from dream.edges.background import frames_and_background
from dream.edges.refine import EdgeTrace, align_edges
from dream.edges.score import EdgeScore, edge_score
from dream.edges.search import scale_images
from dream.edges.settings import EdgeSettings
from dream.errors import CannotRefine, InputError
from dream.polish.calibration import all_detections
from dream.polish.objective import evenly_spaced
from dream.refined_uncertainty import (
    RefinementJackknife,
    combined,
    frame_groups,
    group_jackknife,
)
from dream.robot import Robot
from dream.robot.link_geometry import LinkGeometry, excluded_links, with_link_geometry
from dream.sequence import Sequence
from dream.silhouette import RobotMeshes, load_robot_meshes, static_links, vertices_in_base
from dream.transforms import invert_T, rotation_angle_between

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EdgeResult:
    """Outcome of the edge alignment of one extrinsic.

    Attributes:
        T_before: (4, 4) the keypoint extrinsic. T_aligned: (4, 4) the alignment's optimum.
        T_after: (4, 4) the extrinsic kept: `T_aligned` when `kept`, else `T_before`.
        kept: whether the aligned pose was kept; reason: why (one sentence).
        frames: names of the frames aligned and scored.
        score_before, score_after: the outline's agreement at `T_before` / `T_aligned`.
        keypoint_median_before, keypoint_median_after: median distance (px) of all keypoint
            detections at the two poses (NaN without detections).
        background: whether a background model was used.
        excluded_links: links left out of the comparison by name.
        static_links: links left out because they stay in the background model.
        mismatched_links: links whose outline agrees less than `mismatch_ratio` x the whole
            outline's agreement at the kept pose.
        trace: rounds per scale, matched points. seconds: wall time.
        jackknife: the jackknife of the kept pose (`edge_jackknife`), where computed.
    """

    T_before: np.ndarray
    T_aligned: np.ndarray
    T_after: np.ndarray
    kept: bool
    reason: str
    frames: tuple[str, ...]
    score_before: EdgeScore
    score_after: EdgeScore
    keypoint_median_before: float
    keypoint_median_after: float
    background: bool
    excluded_links: tuple[str, ...]
    static_links: tuple[str, ...]
    mismatched_links: tuple[str, ...]
    trace: EdgeTrace
    seconds: float
    jackknife: RefinementJackknife | None = None

    @property
    def score_kept(self) -> EdgeScore:
        """The agreement at the pose kept (`T_after`)."""
        return self.score_after if self.kept else self.score_before

    @property
    def correction(self) -> tuple[float, float]:
        """(camera position change m, rotation change rad) from T_before to T_aligned."""
        c0, c1 = invert_T(self.T_before)[:3, 3], invert_T(self.T_aligned)[:3, 3]
        return (float(np.linalg.norm(c1 - c0)),
                float(rotation_angle_between(self.T_before[:3, :3], self.T_aligned[:3, :3])))


def decide_edges(before: EdgeScore, after: EdgeScore, median_before: float,
                 median_after: float, settings: EdgeSettings) -> tuple[bool, str]:
    """The keep rule (module doc): (kept, one sentence why)."""
    gain = after.agreement - before.agreement
    agreement = (f"outline on the image edges {before.agreement:.1%} -> {after.agreement:.1%}"
                 f" of {after.points} points")
    if not gain > settings.min_agreement_gain:
        return False, f"kept the pose it started from: {agreement}, no gain"
    if np.isfinite(median_before):
        limit = max(settings.max_keypoint_factor * median_before,
                    median_before + settings.keypoint_margin_px)
        if not median_after <= limit:
            return False, (f"kept the keypoint pose: {agreement}, but the keypoint detections' "
                           f"median distance would grow {median_before:.2f} -> "
                           f"{median_after:.2f} px (limit {limit:.2f})")
        return True, (f"aligned to the image edges: {agreement}; keypoint detections' median "
                      f"distance {median_before:.2f} -> {median_after:.2f} px")
    return True, f"aligned to the image edges: {agreement}"


def usable_vertices(meshes: RobotMeshes, exclude_links: SequenceOf[str]) -> np.ndarray:
    """(V,) True for the vertices of the links not excluded.

    Raises:
        InputError: an unknown link name, or every link excluded.
    """
    unknown = sorted(set(exclude_links) - set(meshes.links))
    if unknown:
        raise InputError(f"unknown link(s) {', '.join(unknown)} to leave out of the edge "
                         f"alignment", fix=f"use links of the robot: {', '.join(meshes.links)}")
    excluded = np.isin(np.arange(len(meshes.links)),
                       [meshes.links.index(name) for name in exclude_links])
    if excluded.all():
        raise InputError("every link is left out of the edge alignment, so nothing is left to "
                         "align", fix="leave out fewer links (--exclude-links)")
    return ~excluded[meshes.vertex_link]


def outline_meshes(robot: Robot, settings: EdgeSettings, exclude_links: SequenceOf[str],
                   link_geometry: tuple[LinkGeometry, ...]
                   ) -> tuple[RobotMeshes, np.ndarray, tuple[str, ...]]:
    """The meshes whose outline is aligned (a model extension's `link_geometry` applied), the
    vertices usable for it (`usable_vertices`) and the links left out: `exclude_links` and the
    extension's excluded ones."""
    meshes = with_link_geometry(load_robot_meshes(robot, settings.max_triangles), link_geometry)
    excluded = (*exclude_links, *excluded_links(link_geometry))
    return meshes, usable_vertices(meshes, excluded), excluded


def moving_vertices(meshes: RobotMeshes, joints: np.ndarray, usable: np.ndarray,
                    background: np.ndarray | None, settings: EdgeSettings
                    ) -> tuple[np.ndarray, np.ndarray | None, tuple[str, ...]]:
    """With a background model, the links that never move over joints (F, J) are in it, so
    their vertices leave `usable`; an arm that does not move at all is in it whole, so the
    background model is dropped instead. Returns (usable, background, the static links)."""
    if background is None:
        return usable, None, ()
    static = static_links(meshes, joints, settings.static_link_m)
    if set(static) >= set(meshes.links):
        log.info("the arm does not move in these frames, so the background model holds all of "
                 "it: edges are matched without it")
        return usable, None, ()
    if static:
        log.info("left out of the edge alignment, in the background model: %s",
                 ", ".join(static))
        usable = usable & usable_vertices(meshes, static)
    return usable, background, static


def refine_with_edges(sequence: Sequence, robot: Robot, T_cam_base: np.ndarray,
                      obs: Observations | None = None, settings: EdgeSettings | None = None,
                      exclude_links: SequenceOf[str] = (),
                      link_geometry: tuple[LinkGeometry, ...] = ()) -> EdgeResult:
    """Align the one extrinsic of a fixed-camera `sequence` to its images' edges, from
    `T_cam_base` (the keypoint extrinsic), and keep it or not (module doc). `link_geometry`
    (a model extension's) adds or scales link geometry, or leaves links out.

    Raises:
        InputError: frames without images, a camera that is not one fixed camera, unknown or
            all links excluded, or no image edge near the robot's outline at the start.
    """
    from dream.pipeline import joints_in_robot_order

    start = time.perf_counter()
    settings = settings or EdgeSettings()
    camera = sequence.fixed_camera("align the robot's outline with the image edges")
    missing = [f.name for f in sequence.frames if f.image_path is None]
    if missing:
        raise InputError(f"--refine edges needs the images, and frame {missing[0]} has none",
                         sequence.source, "add the images, or use --refine none")
    meshes, usable, exclude_links = outline_meshes(robot, settings, exclude_links,
                                                   link_geometry)
    chosen = evenly_spaced(np.arange(len(sequence)), settings.max_search_frames)
    gray, background = frames_and_background(sequence, chosen, settings, camera)
    if background is None:
        log.info("%d frames are too few for a background model: edges are matched without it",
                 len(sequence))
    joints = joints_in_robot_order(sequence, robot)
    usable, background, static = moving_vertices(meshes, joints, usable, background, settings)
    P = vertices_in_base(meshes, joints[chosen])
    full = scale_images(gray, camera, camera.width, settings, background)
    T0 = np.asarray(T_cam_base, dtype=float)
    score0 = edge_score(meshes, P, T0, full, settings, usable)
    if score0.points == 0 or score0.agreement * score0.points < settings.min_outline_points:
        raise CannotRefine(f"no image edges near the robot's outline at the start pose "
                           f"({score0.points} outline points, {score0.agreement:.0%} on an "
                           "edge)", sequence.source, "check the images show the robot and the "
                           "camera and joints belong to them, or use --refine none")
    T1, trace = align_edges(P, meshes.faces, gray, camera, T0, settings, background, usable,
                           meshes.vertex_link)
    score1 = edge_score(meshes, P, T1, full, settings, usable)
    guard = all_detections(obs)
    med0, med1 = ((guard.median_px(camera, T0), guard.median_px(camera, T1)) if guard
                  else (float("nan"), float("nan")))
    kept, reason = decide_edges(score0, score1, med0, med1, settings)
    log.info("edge alignment: %s", reason)
    T_after = T1 if kept else T0
    jackknife = (edge_jackknife(meshes, P, gray, camera, T1, settings, background, usable,
                                score1) if kept else None)
    return EdgeResult(T0, T1, T_after, kept, reason,
                      tuple(sequence.frames[i].name for i in chosen), score0, score1, med0,
                      med1, background is not None, tuple(exclude_links), static,
                      (score1 if kept else score0).mismatched(settings), trace,
                      time.perf_counter() - start, jackknife)


JACKKNIFE_ROUNDS = 4   # rounds at the finest scale of each leave-one-link alignment


def edge_jackknife(meshes: RobotMeshes, P: np.ndarray, gray: np.ndarray, camera,
                   T_aligned: np.ndarray, settings: EdgeSettings,
                   background: np.ndarray | None, usable: np.ndarray,
                   score: EdgeScore) -> RefinementJackknife | None:
    """The 1-sigma of an aligned pose (`dream.refined_uncertainty`): the alignment repeated
    from `T_aligned` at the finest scale with each link's outline left out in turn, over the
    links with at least `min_outline_points` outline points in `score` (the aligned pose's),
    and, with several frames, each frame group left out in turn; P (F, V, 3) and gray
    (F, H, W) of the frames aligned."""
    links = tuple(a.link for a in score.links if a.points >= settings.min_outline_points)
    fine = replace(settings, scale_widths_px=settings.scale_widths_px[-1:],
                   rounds_per_scale=JACKKNIFE_ROUNDS)
    groups = frame_groups(len(P))

    def without_link(link: str) -> np.ndarray:
        keep = usable & (meshes.vertex_link != meshes.links.index(link))
        return align_edges(P, meshes.faces, gray, camera, T_aligned, fine, background, keep,
                           meshes.vertex_link)[0]

    def without_frames(name: str) -> np.ndarray:
        keep = np.setdiff1d(np.arange(len(P)), groups[name])
        return align_edges(P[keep], meshes.faces, gray[keep], camera, T_aligned, fine,
                           background, usable, meshes.vertex_link)[0]

    return combined(group_jackknife(T_aligned, links, without_link, "the edge alignment"),
                    group_jackknife(T_aligned, tuple(groups), without_frames,
                                    "the edge alignment"))
