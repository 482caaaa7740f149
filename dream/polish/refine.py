"""The polish of one pose: Levenberg-Marquardt on the silhouette objective, then the verdict.

Levenberg-Marquardt (`dream.optim.levenberg_marquardt`) over the 6-vector xi of `dream.pnp`
(P_cam = exp(xi_rot) R P + t + xi_t) with the analytic Jacobian (distance-field gradient x
projection Jacobian), a few steps on a fixed set of contour points
(`dream.polish.objective`), then the silhouettes are rendered again and the points re-selected
(as in ICP), until the pose stops moving. Derivative-free searches (Nelder-Mead, Powell) on
1 - IoU do not suit it: IoU is piecewise constant in the pose, and each of their hundreds of
evaluations renders every frame. The search runs on at most `max_search_frames` frames
(evenly spaced, non-empty masks) with masks shrunk to at most `search_width_px` pixels wide;
a wider camera's search is finished by `fine_rounds` rounds at its own resolution.
`polish` then scores both poses and keeps or refuses the polished one (`dream.polish.guard`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.errors import InputError
from dream.optim import LMSettings, levenberg_marquardt
from dream.optim.robust import TINY
from dream.pnp import apply_increment
from dream.polish.frames import FrameAgreement, agreeing_frames
from dream.polish.guard import KeypointGuard, KeypointSet, decide
from dream.polish.objective import (
    Contour,
    Objective,
    evenly_spaced,
    scaled_camera,
    select_contour,
    shrink_mask,
    signed_distance,
)
from dream.polish.settings import PolishSettings
from dream.refined_uncertainty import (
    RefinementJackknife,
    combined,
    frame_groups,
    group_jackknife,
    links_with_points,
)
from dream.silhouette import (
    RobotMeshes,
    render_frames,
    silhouette_iou,
    vertices_in_base,
)
from dream.transforms import invert_T, rotation_angle_between

log = logging.getLogger(__name__)

DAMPING_FACTOR = 10.0       # LM lambda is multiplied / divided by this on a rejected / kept step
MAX_DAMPING = 1e8           # the inner loop stops when lambda exceeds this


@dataclass(frozen=True)
class PolishResult:
    """Outcome of a polish.

    Attributes:
        T_before: (4, 4) the keypoint extrinsic.
        T_polished: (4, 4) the silhouette optimum, whether kept or not.
        T_after: (4, 4) the extrinsic kept: `T_polished` when `kept`, else `T_before`.
        frames: names of the frames scored.
        iou_before, iou_after: (E,) silhouette IoU per frame at `T_before` / `T_polished`.
        kept: whether the polished pose was kept.
        reason: why (one sentence).
        rmse_before, rmse_after: inlier keypoint RMSE (px) at `T_before` / `T_polished`; NaN
            without keypoints.
        median_before, median_after: their median distance (px), likewise.
        guard: the `KeypointGuard` statistic that decided.
        guard_keypoints: the number of keypoints it was measured on (0: no guard).
        start: where the search started: "" for `T_before`, else the keypoint left out of the
            frame's solution it started from (`polish_frames`' restarts).
        search_frames: names of the frames the search used.
        agreement: the frames' agreement with the common pose (`dream.polish.frames`), None
            where it was not measured; the frames it leaves out are not in the IoU means.
        rounds: render / select / LM rounds of the first search (all frames);
            contour_points: in its last round.
        seconds: wall time of the polish.
        jackknife: the jackknife of the kept pose (`polish_jackknife`), where computed.
    """

    T_before: np.ndarray
    T_polished: np.ndarray
    T_after: np.ndarray
    frames: tuple[str, ...]
    iou_before: np.ndarray
    iou_after: np.ndarray
    kept: bool
    reason: str
    rmse_before: float
    rmse_after: float
    median_before: float = float("nan")
    median_after: float = float("nan")
    guard: str = KeypointGuard.RMSE
    guard_keypoints: int = 0
    start: str = ""
    search_frames: tuple[str, ...] = field(default=())
    agreement: FrameAgreement | None = None
    rounds: int = 0
    contour_points: int = 0
    seconds: float = 0.0
    jackknife: RefinementJackknife | None = None

    @property
    def used(self) -> np.ndarray:
        """(E,) bool, the frames the IoU means are over (all but those left out)."""
        return (self.agreement.used if self.agreement is not None
                else np.ones(len(self.iou_before), bool))

    @property
    def iou_before_mean(self) -> float:
        return float(np.mean(self.iou_before[self.used]))

    @property
    def iou_after_mean(self) -> float:
        return float(np.mean(self.iou_after[self.used]))

    @property
    def correction(self) -> tuple[float, float]:
        """(camera position change m, rotation change rad) from T_before to T_polished."""
        c0 = invert_T(self.T_before)[:3, 3]
        c1 = invert_T(self.T_polished)[:3, 3]
        angle = rotation_angle_between(self.T_before[:3, :3], self.T_polished[:3, :3])
        return float(np.linalg.norm(c1 - c0)), float(angle)


class _ContourProblem:
    """`dream.optim.lm`'s view of the silhouette objective on one set of contour points, over
    T_cam_base. A state is the residuals and Jacobian at a pose when known, else None."""

    def __init__(self, objective: Objective, contour: Contour):
        self.objective, self.contour = objective, contour

    def evaluate(self, T: np.ndarray) -> tuple[float, Any]:
        return self.objective.cost(self.contour, T), None

    def normal_equations(self, T: np.ndarray, state: Any) -> tuple[np.ndarray, np.ndarray]:
        r, J = self.objective.residuals(self.contour, T, jacobian=True) if state is None \
            else state
        w = self.objective.weight(r)
        return J.T @ (w[:, None] * J), J.T @ (w * r)

    def retract(self, T: np.ndarray, xi: np.ndarray) -> np.ndarray:
        return apply_increment(T, xi)


def inner_lm_settings(initial_damping: float, iterations: int) -> LMSettings:
    """The LM loop of a few steps on one fixed set of image correspondences (the polish's
    contour points, the edge alignment's matched edges): a step is kept only when it lowers the
    cost."""
    return LMSettings(initial_damping=initial_damping, damping_up=DAMPING_FACTOR,
                      damping_down=DAMPING_FACTOR, min_damping=TINY, max_damping=MAX_DAMPING,
                      max_iterations=iterations, strict_decrease=True)


def _lm_steps(objective: Objective, contour: Contour, T: np.ndarray,
              params: PolishSettings) -> np.ndarray:
    """A few Levenberg-Marquardt steps on one set of contour points (a step is kept only when
    it lowers the cost)."""
    out = objective.residuals(contour, T, jacobian=True)
    if out is None:
        return T
    settings = inner_lm_settings(params.initial_damping, params.inner_iterations)
    start = (float(np.sum(objective.rho(out[0]))), out)
    return levenberg_marquardt(_ContourProblem(objective, contour), T, settings, start).x


def rms_motion_px(P_base: np.ndarray, T0: np.ndarray, T1: np.ndarray,
                  camera: CameraIntrinsics) -> float:
    """RMS pixel motion of the points P_base (N, 3) from pose T0 to T1 (inf where one does not
    project)."""
    uv0 = project(camera, P_base @ T0[:3, :3].T + T0[:3, 3])
    uv1 = project(camera, P_base @ T1[:3, :3].T + T1[:3, 3])
    d2 = np.sum((uv1 - uv0) ** 2, axis=1)
    return float(np.sqrt(np.mean(d2))) if np.all(np.isfinite(d2)) else float("inf")


def search_camera(camera: CameraIntrinsics, params: PolishSettings) -> CameraIntrinsics:
    """The camera of the pose search: `camera` shrunk to at most `search_width_px` wide."""
    width = min(camera.width, params.search_width_px)
    height = max(1, int(round(camera.height * width / camera.width)))
    return scaled_camera(camera, width, height)


def refine_pose(P_frames: np.ndarray, faces: np.ndarray, masks: np.ndarray,
                camera: CameraIntrinsics, T_cam_base: np.ndarray,
                params: PolishSettings, usable: np.ndarray | None = None,
                keep: Callable[[np.ndarray, np.ndarray], bool] | None = None,
                objective: Objective | None = None,
                render: Callable[[np.ndarray], np.ndarray] | None = None
                ) -> tuple[np.ndarray, int, int]:
    """The silhouette optimum near `T_cam_base` (search resolution already applied).

    Args:
        P_frames: (F, V, 3) mesh vertices of each frame in the base frame, m.
        faces: (T, 3) triangles. masks: (F, H, W) observed masks at `camera`'s size.
        usable: (V,) or per frame (F, V) bool, the vertices that may be contour points
            (default all).
        keep: called with each round's pose and the frames' silhouettes there (F, H, W, the
            renders the next round selects its contour points from); where it says False the
            round is undone and the refinement stops (the contour points are chosen again
            each round, so a round may lower its own cost and still move the outline off the
            masks: a held object as large as the hand drags the contour inside it outwards,
            round after round).
        objective: the masks' `Objective` at `camera` with `params`, where already built.
        render: the frames' silhouettes (F, H, W) at a pose, as `render_frames` of
            `P_frames`, `faces` and `camera` gives them (the default); a caller that renders
            the same poses itself passes its own, which may return them again unrendered.
    Returns:
        (T (4, 4), rounds run, contour points of the last round).
    """
    if objective is None:
        objective = Objective(np.stack([signed_distance(m) for m in masks]), camera, params)
    if render is None:
        def render(T: np.ndarray) -> np.ndarray:
            return render_frames(P_frames, faces, T, camera)
    T = kept = np.array(T_cam_base, dtype=float)
    rounds, points = 0, 0
    for rounds in range(1, params.outer_iterations + 1):
        silhouettes = render(T)
        if keep is not None and T is not kept:
            if not keep(T, silhouettes):
                log.debug("silhouette polish round %d refused by its check", rounds - 1)
                T, rounds = kept, rounds - 1
                break
            kept = T
        contour = select_contour(P_frames, faces, T, camera, params, usable, silhouettes)
        points = len(contour.s)
        if points < params.min_contour_points:
            log.info("silhouette polish: only %d contour points, stopping", points)
            break
        T_new = _lm_steps(objective, contour, T, params)
        moved = rms_motion_px(contour.P_base, T, T_new, camera)
        T = T_new
        log.debug("silhouette polish round %d: %d points, moved %.3g px", rounds, points, moved)
        if moved < params.step_tolerance_px:
            break
    if keep is not None and T is not kept and not keep(T, render(T)):
        log.debug("silhouette polish round %d refused by its check", rounds)
        T = kept
    return T, rounds, points


def polish(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
           camera: CameraIntrinsics, T_cam_base: np.ndarray, keypoints: KeypointSet | None,
           params: PolishSettings | None = None,
           frame_names: SequenceOf[str] | None = None,
           guard: str = KeypointGuard.RMSE, check_frames: bool = True,
           inliers: KeypointSet | None = None) -> PolishResult:
    """Refine `T_cam_base` by aligning rendered and observed robot silhouettes (the module docs
    of `dream.polish.objective`, `dream.polish.refine` and `dream.polish.guard`).

    Args:
        meshes: the robot's meshes (`dream.silhouette.load_robot_meshes`).
        joints: (F, J) joint vectors of the frames, in `meshes.robot.joint_names` order.
        masks: (F, H, W) bool observed robot masks at the camera's resolution.
        camera: the camera's intrinsics.
        T_cam_base: (4, 4) the starting (keypoint) extrinsic.
        keypoints: the calibration's inlier observations (the guard), or None for no guard.
        params: the constants; default `PolishSettings()`.
        frame_names: F names (default "0", "1", ...).
        guard: a `KeypointGuard`: RMSE or ALL_MEDIAN (many frames), MEDIAN (one frame alone).
        check_frames: leave out frames that disagree with the others (`dream.polish.frames`;
            with more than `min_agreeing_frames` frames).
        inliers: with the ALL_MEDIAN guard, the keypoint fit's inliers, whose RMSE must not
            grow either (`dream.polish.guard`; None: not checked); `rmse_before` and
            `rmse_after` are then theirs.
    Returns:
        A `PolishResult`; `T_after` is the pose to use.
    Raises:
        InputError: shapes that disagree, no frame with a non-empty mask, an unknown guard.
    """
    start = time.perf_counter()
    params = params or PolishSettings()
    q, masks, T0, names, non_empty = _checked(meshes, joints, masks, camera, T_cam_base,
                                              frame_names, guard)
    F = len(q)
    P_all = vertices_in_base(meshes, q)                                    # (F, V, 3)
    small = search_camera(camera, params)
    width, height = small.width, small.height
    small_masks = {int(i): shrink_mask(masks[i], width, height) for i in non_empty}

    def refine(frames: np.ndarray, T: np.ndarray, settings: PolishSettings
               ) -> tuple[np.ndarray, int, int]:
        chosen = evenly_spaced(frames, params.max_search_frames)
        return refine_pose(P_all[chosen], meshes.faces,
                           np.stack([small_masks[i] for i in chosen]), small, T, settings)

    def search(frames: np.ndarray, T: np.ndarray) -> np.ndarray:
        return refine(frames, T, params)[0]

    def search_alone(frame: int, T: np.ndarray) -> np.ndarray:
        alone = replace(params, outer_iterations=params.frame_alone_rounds)
        return refine(np.array([frame]), T, alone)[0]

    def ious(frames: np.ndarray, T: np.ndarray) -> np.ndarray:
        rendered = render_frames(P_all[frames], meshes.faces, T, camera)
        return np.array([silhouette_iou(r, masks[i])
                         for r, i in zip(rendered, frames, strict=True)])

    T1, rounds, points = refine(non_empty, T0, params)
    agreement = None
    if check_frames and len(non_empty) > params.min_agreeing_frames:
        candidates = np.isin(np.arange(F), non_empty)
        T1, agreement = agreeing_frames(T1, candidates, search, search_alone, ious,
                                        params)
    used = agreement.used if agreement is not None else np.ones(F, bool)
    used_search = evenly_spaced(np.flatnonzero(used & np.isin(np.arange(F), non_empty)),
                                params.max_search_frames)
    if width < camera.width:          # finish at the camera's own resolution
        T1 = refine_pose(P_all[used_search], meshes.faces, masks[used_search], camera, T1,
                         replace(params, outer_iterations=params.fine_rounds))[0]
    iou0, iou1 = ious(np.arange(F), T0), ious(np.arange(F), T1)
    if keypoints is not None:
        rmse0, rmse1 = keypoints.rmse_px(camera, T0), keypoints.rmse_px(camera, T1)
        median0, median1 = keypoints.median_px(camera, T0), keypoints.median_px(camera, T1)
    else:
        rmse0 = rmse1 = median0 = median1 = float("nan")
    before, after = (rmse0, rmse1) if guard == KeypointGuard.RMSE else (median0, median1)
    n_guard = 0 if keypoints is None else len(keypoints.P_base)
    fit_rmse = None
    if inliers is not None:
        rmse0, rmse1 = inliers.rmse_px(camera, T0), inliers.rmse_px(camera, T1)
        fit_rmse = (rmse0, rmse1)
    kept, reason = decide(float(iou0[used].mean()), float(iou1[used].mean()), before, after,
                          n_guard, params, guard, fit_rmse)
    if agreement is not None and not used.all():
        reason += f"; {int((~used).sum())} of {F} frames left out (they disagree with the rest)"
    log.info("silhouette polish: %s", reason)
    return PolishResult(T_before=T0, T_polished=T1, T_after=T1 if kept else T0, frames=names,
                        iou_before=iou0, iou_after=iou1, kept=kept, reason=reason,
                        rmse_before=rmse0, rmse_after=rmse1, median_before=median0,
                        median_after=median1, guard=guard, guard_keypoints=n_guard,
                        search_frames=tuple(names[i] for i in used_search),
                        rounds=rounds, contour_points=points,
                        agreement=agreement, seconds=time.perf_counter() - start)


def _checked(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
             camera: CameraIntrinsics, T_cam_base: np.ndarray,
             frame_names: SequenceOf[str] | None, guard: str
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[str, ...], np.ndarray]:
    """`polish`'s inputs checked: joints (F, J), bool masks (F, H, W), T_cam_base, the F frame
    names and the indices of the frames whose mask is not empty."""
    if guard not in KeypointGuard.ALL:
        raise InputError(f"unknown keypoint guard '{guard}'; use one of "
                         f"{', '.join(KeypointGuard.ALL)}")
    robot = meshes.robot
    q = np.asarray(joints, dtype=float)
    masks = np.asarray(masks)
    T0 = np.asarray(T_cam_base, dtype=float)
    if q.ndim != 2 or q.shape[1] != robot.num_joints:
        raise InputError(f"joints have shape {q.shape}, expected (F, {robot.num_joints})")
    F = len(q)
    if masks.shape != (F, camera.height, camera.width):
        raise InputError(f"masks have shape {masks.shape}, expected ({F}, {camera.height}, "
                         f"{camera.width}) (one per frame, at the camera's resolution)")
    if T0.shape != (4, 4) or not np.all(np.isfinite(T0)):
        raise InputError("T_cam_base must be a finite 4x4 matrix")
    names = tuple(str(n) for n in frame_names) if frame_names is not None else tuple(
        str(i) for i in range(F))
    if len(names) != F:
        raise InputError(f"{len(names)} frame names for {F} frames")
    masks = masks.astype(bool)
    non_empty = np.flatnonzero(masks.reshape(F, -1).any(axis=1))
    if not len(non_empty):
        raise InputError("every robot mask is empty; the silhouette polish needs masks that "
                         "show the robot")
    return q, masks, T0, names, non_empty


JACKKNIFE_MIN_CONTOUR_POINTS = 20   # a link with fewer contour points does not shape the polish
JACKKNIFE_ROUNDS = 5                # rounds of each leave-one-link polish from the optimum


def polish_jackknife(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
                     camera: CameraIntrinsics, T_polished: np.ndarray,
                     params: PolishSettings | None = None) -> RefinementJackknife | None:
    """The 1-sigma of a polished pose (`dream.refined_uncertainty`): the polish repeated from
    `T_polished` with each link's contour points left out in turn, and, with several frames,
    each frame group left out in turn; on the search frames and at the search resolution of
    `polish`; joints (F, J) and masks (F, H, W) of the frames that decided it. Links with fewer
    than `JACKKNIFE_MIN_CONTOUR_POINTS` contour points at `T_polished` are not groups."""
    params = params or PolishSettings()
    q, masks, T1, _, non_empty = _checked(meshes, joints, masks, camera, T_polished, None,
                                          KeypointGuard.RMSE)
    chosen = evenly_spaced(non_empty, params.max_search_frames)
    small = search_camera(camera, params)
    P = vertices_in_base(meshes, q[chosen])
    small_masks = np.stack([shrink_mask(masks[i], small.width, small.height) for i in chosen])
    contour = select_contour(P, meshes.faces, T1, small, params)
    links = links_with_points(meshes.vertex_link, contour.vertex, meshes.links,
                              JACKKNIFE_MIN_CONTOUR_POINTS)
    short = replace(params, outer_iterations=JACKKNIFE_ROUNDS)
    groups = frame_groups(len(chosen))

    def without_link(link: str) -> np.ndarray:
        usable = meshes.vertex_link != meshes.links.index(link)
        return refine_pose(P, meshes.faces, small_masks, small, T1, short, usable)[0]

    def without_frames(name: str) -> np.ndarray:
        keep = np.setdiff1d(np.arange(len(chosen)), groups[name])
        return refine_pose(P[keep], meshes.faces, small_masks[keep], small, T1, short)[0]

    return combined(group_jackknife(T1, links, without_link, "the silhouette polish"),
                    group_jackknife(T1, tuple(groups), without_frames, "the silhouette polish"))
