"""Silhouette polish: refine a keypoint calibration's `T_cam_base` with the robot masks.

The keypoints fix the extrinsic from a handful of link origins per frame; the robot's outline in
the masks (`NNNNNN.seg.png` of the DREAM layout, franka_offline's `mask/`) holds thousands of
further constraints. The polish aligns the silhouette rendered from the URDF's visual meshes
(`dream.silhouette`) with the observed masks of every frame at once (fixed camera), on the CPU.

Objective (a one-sided, signed chamfer distance with continuous model points):
    For the current pose, render each search frame's silhouette and keep the mesh vertices that
    project within `contour_band_px` of its outline: they are the model's contour points, 3D
    points that move continuously with the pose (a rendered outline moves in whole pixels).
    Each contour point i of frame f gives the residual
        r_i = D_f(project(T P_i)) - s_i,
    where D_f is the signed distance to the observed mask's outline (pixels; negative inside;
    bilinear in the distance transform of the mask, so smooth in the pose) and s_i the same
    signed distance measured in the rendered silhouette where the point was selected. s_i makes
    the residuals exactly zero when the rendered and observed silhouettes agree, so points a
    little inside the outline do not pull it outwards. Points farther than `max_residual_px`
    from agreement (parts the mask misses, mask noise) get no weight, the rest a Huber weight
    (scale `huber_scale_px`). Occluders only remove robot pixels from the observed mask, so at
    the true pose a contour point may lie outside it (r > 0, the robot hidden there) but never
    inside: residuals r > 0 get no weight beyond the tighter `max_outside_residual_px`
    (otherwise a distractor in front of the arm pulls the outline onto the visible part;
    eighteenth session, README). Observed outline that no model contour explains (cables, a
    gripper the URDF lacks) pulls nothing: the distance is one-sided on purpose.
Optimiser:
    Levenberg-Marquardt over the 6-vector xi of `dream.pnp` (P_cam = exp(xi_rot) R P + t + xi_t)
    with the analytic Jacobian (distance-field gradient x projection Jacobian), a few steps on
    a fixed set of contour points, then the silhouettes are rendered again and the points
    re-selected (as in ICP), until the pose stops moving. Derivative-free searches
    (Nelder-Mead, Powell) on 1 - IoU were not used: IoU is piecewise constant in the pose, and
    each of their hundreds of evaluations renders every frame. The search runs on at most
    `max_search_frames` frames (evenly spaced, non-empty masks) with masks shrunk to at most
    `search_width_px` pixels wide.
Acceptance:
    The silhouette IoU (exact rasterisation, full resolution) is measured on every frame given
    before and after. The polished pose is kept only when the mean IoU grows by more than
    `min_iou_gain` and the keypoint fit is not broken (`KeypointGuard`):
    - "rmse" (a fixed camera, all frames): the RMS reprojection error of the calibration's
      inlier keypoints stays within max(`max_rmse_factor` x before, before + `rmse_margin_px`).
    - "median" (one frame's own pose, `--frames each`): the median pixel distance of the frame's
      n inlier keypoints may reach at most its value at the keypoint pose divided by
      `fit_shrinkage(n)` = sqrt((2n - 6) / 2n), plus `frame_median_margin_px`. A single frame's
      4-7 keypoints fix its 6 pose parameters with little redundancy: the fit follows a
      misplaced keypoint and leaves the others' residuals near zero, so any better pose raises
      the RMSE by far more than the noise; and the fit absorbs part of the noise itself (half
      of it, in RMS, for 4 keypoints), which the division gives back. The median still rises
      when the pose leaves most of the keypoints, as it does when silhouette and keypoints
      disagree.
    Otherwise the keypoint pose is kept and `reason` says why.

Command line (`dream calibrate --polish`): data without any mask is one error line and exit
code 2 before anything is solved (a polish that was asked for is never skipped silently),
unless `--mask-head` asks for the `--model`'s mask head and the mode is all frames (opt-in: the
bundled model's mask head made rendered scenes worse, and its masks are too coarse for a frame
alone; `check_polish_input`). All frames: RESULT.json gets a `polish`
object (iou_before, iou_after: means; kept; reason; per-frame IoUs, keypoint RMSEs, both
poses); when kept, its pose fields are the polished pose's. `--frames each`: every solved
frame with a non-empty mask is polished alone (`polish_frames`); each `per_frame` entry gets
its own `polish` object and, when kept, the polished `T_cam_base`; the top-level `polish`
object counts them (`frame_polish_summary`), and the top-level pose is the reported frame's
polished one when that frame's polish was kept.

Public API:
    PolishParams, KeypointSet, KeypointGuard, PolishResult, signed_distance(mask),
    fit_shrinkage(n_keypoints)
    polish(meshes, joints, masks, camera, T_cam_base, keypoints, params, frame_names,
           guard) (pure)
    check_polish_input(sequence, mode, network_masks); has_masks(sequence);
    silhouette_inputs(sequence, robot, params, predict_masks); polish_calibration(sequence,
    robot, result, obs, params, predict_masks); polish_frames(sequence, robot, result, obs, params,
    progress)
    polish_to_dict(result); result_doc_with_polish(doc, result);
    frame_polish_to_dict(result); frame_polish_summary(results);
    result_doc_with_frame_polishes(doc, results)
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from dream.calibrate import CalibrationResult, Observations
from dream.camera import CameraIntrinsics, project
from dream.errors import InputError
from dream.pnp import PoseFit, apply_increment, linearise
from dream.robot import Robot
from dream.sequence import Sequence
from dream.silhouette import (
    DEFAULT_MAX_TRIANGLES,
    RobotMeshes,
    load_robot_meshes,
    render_points,
    silhouette_iou,
    vertices_in_base,
)
from dream.transforms import invert_T, quaternion_xyzw_from_R, rotation_angle_between

log = logging.getLogger(__name__)

EDGE_OFFSET_PX = 0.5        # a boundary pixel's centre lies half a pixel from the outline
DAMPING_FACTOR = 10.0       # LM lambda is multiplied / divided by this on a rejected / kept step
MAX_DAMPING = 1e8           # the inner loop stops when lambda exceeds this
TINY = 1e-300               # keeps the damping positive for a zero diagonal entry
COVERED_FRACTION = 0.5      # a shrunk mask's pixel is robot when this much of it was robot


@dataclass(frozen=True)
class PolishParams:
    """Every constant of the silhouette polish. Metres, radians, pixels.

    Attributes:
        max_search_frames: frames used by the pose search (evenly spaced among those given).
        max_eval_frames: frames whose IoU decides (`polish_calibration` loads at most this
            many masks; `polish` scores every frame it is given).
        search_width_px: masks and camera are shrunk to at most this width during the search.
        max_triangles: triangle budget of the robot's meshes (`dream.silhouette`).
        contour_band_px: a vertex is a contour point when it projects this close to the
            rendered outline (search resolution).
        huber_scale_px: Huber scale of the contour residuals (search resolution).
        max_residual_px: residuals beyond this get no weight (search resolution).
        max_outside_residual_px: positive residuals (the model's outline outside the observed
            mask, where an occluder may hide the robot) beyond this get no weight (search
            resolution). 5 px was fixed before it was evaluated (eighteenth session, README:
            single-frame ADD AUC with `--frames each --polish` 91.3 -> 93.8 on the design set
            and 91.3 -> 94.8 on the held-out set, against 15 px, i.e. the same cut both
            sides).
        outer_iterations: render -> select contour points -> LM rounds.
        inner_iterations: LM steps on one set of contour points.
        initial_damping: LM lambda, relative to diag(J^T W J).
        step_tolerance_px: stop when a round moves the contour points less (RMS, search
            resolution).
        max_points_per_frame: contour points used per frame and round (evenly spaced).
        min_contour_points: fewer contour points in the search frames end the search.
        min_iou_gain: the mean IoU must grow by more than this for the polish to be kept.
        max_rmse_factor, rmse_margin_px: the inlier keypoints' RMSE at the polished pose must
            not exceed max(factor x RMSE before, RMSE before + margin) ("rmse" guard).
        frame_median_margin_px: a single frame's polish (the "median" guard) is kept only when
            the median distance of its n inlier keypoints stays within this of their median at
            the keypoint pose divided by `fit_shrinkage(n)`. 3 px was chosen on a rendered
            design set (`dream synth --num 300 --seed 6000`), among 2, 3 and 5, before the
            division was added (twelfth session, same set: 4 frames better, none worse).
        frame_restart_below_iou: a frame (`polish_frames`) whose polish is refused or ends
            below this IoU is polished again from each of its leave-one-keypoint-out poses.
    """

    max_search_frames: int = 10
    max_eval_frames: int = 40
    search_width_px: int = 320
    max_triangles: int = DEFAULT_MAX_TRIANGLES
    contour_band_px: float = 2.0
    huber_scale_px: float = 1.0
    max_residual_px: float = 15.0
    max_outside_residual_px: float = 5.0
    outer_iterations: int = 20
    inner_iterations: int = 3
    initial_damping: float = 1e-4
    step_tolerance_px: float = 0.05
    max_points_per_frame: int = 1500
    min_contour_points: int = 20
    min_iou_gain: float = 0.002
    max_rmse_factor: float = 1.5
    rmse_margin_px: float = 1.0
    frame_median_margin_px: float = 3.0
    frame_restart_below_iou: float = 0.95

    def __post_init__(self) -> None:
        for name in ("max_search_frames", "max_eval_frames", "search_width_px", "max_triangles",
                     "outer_iterations", "inner_iterations", "min_contour_points",
                     "max_points_per_frame"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise InputError(f"polish parameter {name} must be a positive integer, got "
                                 f"{value}")
            object.__setattr__(self, name, int(value))
        for name in ("contour_band_px", "huber_scale_px", "max_residual_px",
                     "max_outside_residual_px", "initial_damping", "step_tolerance_px",
                     "max_rmse_factor"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"polish parameter {name} must be a positive number, got "
                                 f"{value}")
        for name in ("min_iou_gain", "rmse_margin_px", "frame_median_margin_px"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise InputError(f"polish parameter {name} must be a number >= 0, got {value}")
        if not 0 <= self.frame_restart_below_iou <= 1:
            raise InputError("frame_restart_below_iou must lie in [0, 1], got "
                             f"{self.frame_restart_below_iou}")
        if self.max_rmse_factor < 1:
            raise InputError(f"max_rmse_factor must be >= 1, got {self.max_rmse_factor}")
        if self.max_residual_px <= self.huber_scale_px:
            raise InputError("max_residual_px must exceed huber_scale_px")
        if not self.huber_scale_px < self.max_outside_residual_px <= self.max_residual_px:
            raise InputError("max_outside_residual_px must exceed huber_scale_px and not exceed "
                             f"max_residual_px, got {self.max_outside_residual_px}")


@dataclass(frozen=True)
class KeypointSet:
    """The keypoint observations that guard the polish: inliers of the calibration.

    Attributes:
        P_base: (N, 3) keypoint positions in the base frame, m.
        uv: (N, 2) their observed pixels.
    """

    P_base: np.ndarray
    uv: np.ndarray

    def __post_init__(self) -> None:
        P = np.array(self.P_base, dtype=float)
        uv = np.array(self.uv, dtype=float)
        if P.ndim != 2 or P.shape[1] != 3 or uv.shape != (len(P), 2):
            raise InputError(f"keypoints have shapes {P.shape} and {uv.shape}, expected (N, 3) "
                             "and (N, 2)")
        if len(P) == 0 or not (np.all(np.isfinite(P)) and np.all(np.isfinite(uv))):
            raise InputError("the keypoint guard needs at least one finite observation")
        P.setflags(write=False)
        uv.setflags(write=False)
        object.__setattr__(self, "P_base", P)
        object.__setattr__(self, "uv", uv)

    def distances_px(self, camera: CameraIntrinsics, T_cam_base: np.ndarray) -> np.ndarray:
        """(N,) pixel distances between the projections at `T_cam_base` and the observations
        (inf where a point does not project)."""
        uv = project(camera, self.P_base @ T_cam_base[:3, :3].T + T_cam_base[:3, 3])
        d = np.linalg.norm(uv - self.uv, axis=1)
        return np.where(np.isfinite(d), d, np.inf)

    def rmse_px(self, camera: CameraIntrinsics, T_cam_base: np.ndarray) -> float:
        """RMS pixel distance between the projections at `T_cam_base` and the observations."""
        return float(np.sqrt(np.mean(self.distances_px(camera, T_cam_base) ** 2)))

    def median_px(self, camera: CameraIntrinsics, T_cam_base: np.ndarray) -> float:
        """Median pixel distance between the projections and the observations."""
        return float(np.median(self.distances_px(camera, T_cam_base)))


class KeypointGuard:
    """Which statistic of the inlier keypoints decides that a polish breaks their fit
    (module doc, Acceptance)."""

    RMSE = "rmse"       # many frames of a fixed camera
    MEDIAN = "median"   # one frame alone
    ALL = (RMSE, MEDIAN)


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
        rounds: render / select / LM rounds run; contour_points: in the last round.
        seconds: wall time of the polish.
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
    rounds: int = 0
    contour_points: int = 0
    seconds: float = 0.0

    @property
    def iou_before_mean(self) -> float:
        return float(np.mean(self.iou_before))

    @property
    def iou_after_mean(self) -> float:
        return float(np.mean(self.iou_after))

    @property
    def correction(self) -> tuple[float, float]:
        """(camera position change m, rotation change rad) from T_before to T_polished."""
        c0 = invert_T(self.T_before)[:3, 3]
        c1 = invert_T(self.T_polished)[:3, 3]
        angle = rotation_angle_between(self.T_before[:3, :3], self.T_polished[:3, :3])
        return float(np.linalg.norm(c1 - c0)), float(angle)


# ----- pieces --------------------------------------------------------------------------------

def _scaled_camera(camera: CameraIntrinsics, width: int, height: int) -> CameraIntrinsics:
    """The same camera seen at another image size (pixel centres kept at integers)."""
    sx, sy = width / camera.width, height / camera.height
    return CameraIntrinsics(camera.fx * sx, camera.fy * sy, (camera.cx + EDGE_OFFSET_PX) * sx
                            - EDGE_OFFSET_PX, (camera.cy + EDGE_OFFSET_PX) * sy - EDGE_OFFSET_PX,
                            width, height, camera.distortion)


def _shrink_mask(mask: np.ndarray, width: int, height: int) -> np.ndarray:
    """A bool mask resized by area averaging; robot where at least half a pixel is robot."""
    if mask.shape == (height, width):
        return mask
    area = cv2.resize(mask.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    return area >= COVERED_FRACTION


def signed_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) signed distance (pixels) of each pixel centre to the mask's outline, negative
    inside; +-0.5 on the boundary pixels, so zero half-way between them."""
    m = np.asarray(mask, dtype=bool).astype(np.uint8)
    if m.ndim != 2 or m.size == 0:
        raise InputError(f"mask has shape {m.shape}, expected (H, W)")
    d_out = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    d_in = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return np.where(m > 0, EDGE_OFFSET_PX - d_in, d_out - EDGE_OFFSET_PX).astype(float)


def _bilinear(images: np.ndarray, frame: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Values of images (F, H, W) at pixels uv (N, 2) of frames `frame` (N,), clamped."""
    _, H, W = images.shape
    x = np.clip(uv[:, 0], 0.0, W - 1.0)
    y = np.clip(uv[:, 1], 0.0, H - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(W - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(H - 2, 0))
    x1 = np.minimum(x0 + 1, W - 1)
    y1 = np.minimum(y0 + 1, H - 1)
    ax, ay = x - x0, y - y0
    return ((images[frame, y0, x0] * (1 - ax) + images[frame, y0, x1] * ax) * (1 - ay)
            + (images[frame, y1, x0] * (1 - ax) + images[frame, y1, x1] * ax) * ay)


def _evenly_spaced(candidates: np.ndarray, n: int) -> np.ndarray:
    if len(candidates) <= n:
        return candidates
    return candidates[np.unique(np.round(np.linspace(0, len(candidates) - 1, n)).astype(int))]


@dataclass(frozen=True)
class _Contour:
    """Contour points of one round: base-frame points, frame index, selection distance."""

    P_base: np.ndarray   # (N, 3)
    frame: np.ndarray    # (N,)
    s: np.ndarray        # (N,)


def _select_contour(P_frames: np.ndarray, faces: np.ndarray, T: np.ndarray,
                    camera: CameraIntrinsics, params: PolishParams) -> _Contour:
    points, frames, dists = [], [], []
    for f, P in enumerate(P_frames):
        rendered = render_points(P, faces, T, camera)
        if not rendered.any():
            continue
        uv = project(camera, P @ T[:3, :3].T + T[:3, 3])
        ok = np.all(np.isfinite(uv), axis=1) & camera.in_image(uv)
        s = np.full(len(P), np.inf)
        s[ok] = _bilinear(signed_distance(rendered)[None], np.zeros(int(ok.sum()), np.int64),
                          uv[ok])
        pick = np.flatnonzero(np.abs(s) <= params.contour_band_px)
        pick = _evenly_spaced(pick, params.max_points_per_frame)
        points.append(P[pick])
        frames.append(np.full(len(pick), f))
        dists.append(s[pick])
    if not points:
        return _Contour(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0))
    return _Contour(np.concatenate(points), np.concatenate(frames), np.concatenate(dists))


class _Objective:
    """Huber cost of the contour residuals, truncated at `max_residual_px` below zero and at
    `max_outside_residual_px` above (module doc)."""

    def __init__(self, sdf: np.ndarray, camera: CameraIntrinsics, params: PolishParams):
        self.sdf = sdf
        self.grad_y, self.grad_x = np.gradient(sdf, axis=(1, 2))
        self.camera = camera
        self.k = params.huber_scale_px
        self.cut_inside = params.max_residual_px
        self.cut_outside = params.max_outside_residual_px

    def residuals(self, contour: _Contour, T: np.ndarray, jacobian: bool
                  ) -> tuple[np.ndarray, np.ndarray | None] | None:
        lin = linearise(contour.P_base, np.zeros((len(contour.P_base), 2)), self.camera, T)
        if lin is None:
            return None
        uv, J_uv = lin
        r = _bilinear(self.sdf, contour.frame, uv) - contour.s
        if not jacobian:
            return r, None
        # the SDF's central differences, interpolated as the SDF is: smoother than the exact
        # derivative of the bilinear interpolant (piecewise constant), a few per cent from it
        # (tests); zero along an axis where `_bilinear` clamps, as the residual is flat there
        _, H, W = self.sdf.shape
        inside = (uv >= 0.0) & (uv <= [W - 1.0, H - 1.0])
        g = np.stack([_bilinear(self.grad_x, contour.frame, uv),
                      _bilinear(self.grad_y, contour.frame, uv)], axis=1) * inside
        return r, np.einsum("nk,nkj->nj", g, J_uv)

    def cut(self, r: np.ndarray) -> np.ndarray:
        """The truncation of each residual: the outside one where r > 0."""
        return np.where(r > 0, self.cut_outside, self.cut_inside)

    def rho(self, r: np.ndarray) -> np.ndarray:
        a = np.minimum(np.abs(r), self.cut(r))
        return np.where(a <= self.k, 0.5 * a * a, self.k * (a - 0.5 * self.k))

    def weight(self, r: np.ndarray) -> np.ndarray:
        a = np.abs(r)
        return np.where(a > self.cut(r), 0.0,
                        np.where(a <= self.k, 1.0, self.k / np.maximum(a, TINY)))

    def cost(self, contour: _Contour, T: np.ndarray) -> float:
        out = self.residuals(contour, T, jacobian=False)
        return float("inf") if out is None else float(np.sum(self.rho(out[0])))


def _lm_steps(objective: _Objective, contour: _Contour, T: np.ndarray,
              params: PolishParams) -> np.ndarray:
    """A few Levenberg-Marquardt steps on one set of contour points."""
    out = objective.residuals(contour, T, jacobian=True)
    if out is None:
        return T
    r, J = out
    cost = float(np.sum(objective.rho(r)))
    lam = params.initial_damping
    for _ in range(params.inner_iterations):
        w = objective.weight(r)
        H = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        improved = False
        while lam < MAX_DAMPING:
            try:
                xi = np.linalg.solve(H + lam * np.diag(np.diag(H) + TINY), -g)
            except np.linalg.LinAlgError:
                lam *= DAMPING_FACTOR
                continue
            T_new = apply_increment(T, xi)
            new_cost = objective.cost(contour, T_new)
            if new_cost < cost:
                T, cost = T_new, new_cost
                r, J = objective.residuals(contour, T, jacobian=True)
                lam = max(lam / DAMPING_FACTOR, TINY)
                improved = True
                break
            lam *= DAMPING_FACTOR
        if not improved:
            break
    return T


def _rms_motion_px(P_base: np.ndarray, T0: np.ndarray, T1: np.ndarray,
                   camera: CameraIntrinsics) -> float:
    uv0 = project(camera, P_base @ T0[:3, :3].T + T0[:3, 3])
    uv1 = project(camera, P_base @ T1[:3, :3].T + T1[:3, 3])
    d2 = np.sum((uv1 - uv0) ** 2, axis=1)
    return float(np.sqrt(np.mean(d2))) if np.all(np.isfinite(d2)) else float("inf")


def _refine_pose(P_frames: np.ndarray, faces: np.ndarray, masks: np.ndarray,
                 camera: CameraIntrinsics, T_cam_base: np.ndarray,
                 params: PolishParams) -> tuple[np.ndarray, int, int]:
    """The silhouette optimum near `T_cam_base` (search resolution already applied).

    Args:
        P_frames: (F, V, 3) mesh vertices of each frame in the base frame, m.
        faces: (T, 3) triangles. masks: (F, H, W) observed masks at `camera`'s size.
    Returns:
        (T (4, 4), rounds run, contour points of the last round).
    """
    objective = _Objective(np.stack([signed_distance(m) for m in masks]), camera, params)
    T = np.array(T_cam_base, dtype=float)
    rounds, points = 0, 0
    for rounds in range(1, params.outer_iterations + 1):
        contour = _select_contour(P_frames, faces, T, camera, params)
        points = len(contour.s)
        if points < params.min_contour_points:
            log.info("silhouette polish: only %d contour points, stopping", points)
            break
        T_new = _lm_steps(objective, contour, T, params)
        moved = _rms_motion_px(contour.P_base, T, T_new, camera)
        T = T_new
        log.debug("silhouette polish round %d: %d points, moved %.3g px", rounds, points, moved)
        if moved < params.step_tolerance_px:
            break
    return T, rounds, points


# ----- the polish ----------------------------------------------------------------------------

def polish(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
           camera: CameraIntrinsics, T_cam_base: np.ndarray, keypoints: KeypointSet | None,
           params: PolishParams | None = None,
           frame_names: SequenceOf[str] | None = None,
           guard: str = KeypointGuard.RMSE) -> PolishResult:
    """Refine `T_cam_base` by aligning rendered and observed robot silhouettes (module doc).

    Args:
        meshes: the robot's meshes (`dream.silhouette.load_robot_meshes`).
        joints: (F, J) joint vectors of the frames, in `meshes.robot.joint_names` order.
        masks: (F, H, W) bool observed robot masks at the camera's resolution.
        camera: the camera's intrinsics.
        T_cam_base: (4, 4) the starting (keypoint) extrinsic.
        keypoints: the calibration's inlier observations (the guard), or None for no guard.
        params: the constants; default `PolishParams()`.
        frame_names: F names (default "0", "1", ...).
        guard: `KeypointGuard.RMSE` (many frames) or `KeypointGuard.MEDIAN` (one frame alone).
    Returns:
        A `PolishResult`; `T_after` is the pose to use.
    Raises:
        InputError: shapes that disagree, no frame with a non-empty mask, an unknown guard.
    """
    start = time.perf_counter()
    params = params or PolishParams()
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
    P_all = vertices_in_base(meshes, q)                                    # (F, V, 3)
    search = _evenly_spaced(non_empty, params.max_search_frames)
    width = min(camera.width, params.search_width_px)
    height = max(1, int(round(camera.height * width / camera.width)))
    small = _scaled_camera(camera, width, height)
    small_masks = np.stack([_shrink_mask(masks[i], width, height) for i in search])
    T1, rounds, points = _refine_pose(P_all[search], meshes.faces, small_masks, small, T0, params)

    def ious(T: np.ndarray) -> np.ndarray:
        return np.array([silhouette_iou(render_points(P_all[i], meshes.faces, T, camera),
                                        masks[i]) for i in range(F)])

    iou0, iou1 = ious(T0), ious(T1)
    if keypoints is not None:
        rmse0, rmse1 = keypoints.rmse_px(camera, T0), keypoints.rmse_px(camera, T1)
        median0, median1 = keypoints.median_px(camera, T0), keypoints.median_px(camera, T1)
    else:
        rmse0 = rmse1 = median0 = median1 = float("nan")
    before, after = (rmse0, rmse1) if guard == KeypointGuard.RMSE else (median0, median1)
    n_guard = 0 if keypoints is None else len(keypoints.P_base)
    kept, reason = _decide(float(iou0.mean()), float(iou1.mean()), before, after, n_guard,
                           params, guard)
    log.info("silhouette polish: %s", reason)
    return PolishResult(T_before=T0, T_polished=T1, T_after=T1 if kept else T0, frames=names,
                        iou_before=iou0, iou_after=iou1, kept=kept, reason=reason,
                        rmse_before=rmse0, rmse_after=rmse1, median_before=median0,
                        median_after=median1, guard=guard, guard_keypoints=n_guard,
                        search_frames=tuple(names[i] for i in search), rounds=rounds,
                        contour_points=points, seconds=time.perf_counter() - start)


def fit_shrinkage(n_keypoints: int) -> float:
    """The factor by which a least-squares pose fit (6 parameters) shrinks the residuals of the
    n keypoints it was fitted to (2 n coordinates): their RMS is sqrt((2 n - 6) / 2 n) times
    the detection noise's (1 where n <= 3: no redundancy to measure)."""
    m = 2 * n_keypoints
    return float(np.sqrt((m - 6) / m)) if m > 6 else 1.0


def _decide(iou0: float, iou1: float, kp0: float, kp1: float, n_guard: int,
            params: PolishParams, guard: str) -> tuple[bool, str]:
    """Keep or not (module doc, Acceptance); kp0 / kp1: the guard's keypoint statistic over its
    `n_guard` keypoints (0: no guard)."""
    gain = iou1 - iou0
    ious = f"mean IoU {iou0:.4f} -> {iou1:.4f}"
    if not gain > params.min_iou_gain:
        return False, (f"not kept: {ious} gains {gain:+.4f}, not more than "
                       f"{params.min_iou_gain:g}")
    if n_guard == 0:
        return True, f"kept: {ious} (no keypoints to check)"
    if guard == KeypointGuard.RMSE:
        allowed = max(params.max_rmse_factor * kp0, kp0 + params.rmse_margin_px)
        stats = f"keypoint RMSE {kp0:.3f} -> {kp1:.3f} px"
    else:
        # the keypoint pose was fitted to these keypoints: its median understates their noise
        allowed = kp0 / fit_shrinkage(n_guard) + params.frame_median_margin_px
        stats = f"keypoint median distance {kp0:.3f} -> {kp1:.3f} px"
    if not kp1 <= allowed:
        return False, f"not kept: {ious} but {stats}, above the {allowed:.3f} px allowed"
    return True, f"kept: {ious}, {stats} (at most {allowed:.3f} px allowed)"


# ----- glue for `dream calibrate --polish` ---------------------------------------------------

def check_polish_input(sequence: Sequence, mode: str, network_masks: bool = False) -> None:
    """Refuse a polish that cannot run or would not help: no masks in the data unless the
    network's mask head was asked for (`network_masks`, `dream calibrate --mask-head`), and a
    frame alone (`mode` "each") with only the mask head. The mask head is opt-in: on rendered
    frames the bundled model's agrees with the true masks at IoU 0.59, polished single-frame
    poses were worse, and on 40 rendered fixed-camera scenes every all-frames polish against
    it was worse; the guard kept 7, each 15-27 mm further off than the keypoint pose (README).

    Raises:
        InputError: one line naming the data and the fix.
    """
    if has_masks(sequence):
        return
    if not network_masks:
        raise InputError(f"--polish needs robot masks, and none of the {len(sequence)} frames "
                         "has one", sequence.source,
                         "add NNNNNN.seg.png masks (DREAM layout) or mask/ (franka_offline), "
                         "or drop --polish (--mask-head aligns with the --model's mask head "
                         "instead; the bundled model's is too coarse: README)")
    if mode == "each":
        raise InputError("--frames each --polish needs robot masks in the data (the network's "
                         "mask head is too coarse to polish a frame alone)", sequence.source,
                         "add NNNNNN.seg.png masks (DREAM layout) or mask/ (franka_offline), "
                         "use --frames all, or drop --polish")


def has_masks(sequence: Sequence) -> bool:
    """Whether any frame of `sequence` has a robot mask file."""
    return any(f.mask_path is not None for f in sequence.frames)


def _inlier_keypoints(result: CalibrationResult, obs: Observations,
                      frames: int | slice) -> KeypointSet | None:
    """The guard: the inlier observations of `frames` (an index or a slice), None if none."""
    inlier = result.inlier[frames] & obs.found[frames]
    if not inlier.any():
        return None
    return KeypointSet(obs.P_base[frames][inlier], obs.uv[frames][inlier])


@dataclass(frozen=True)
class SilhouetteInputs:
    """What `polish` needs of a fixed-camera sequence besides the starting pose and the guard
    (`silhouette_inputs`).

    Attributes:
        meshes: the robot's meshes. joints: (E, J) the chosen frames' joints, in the robot's
        order. masks: (E, H, W) their robot masks. frame_names: their E names.
    """

    meshes: RobotMeshes
    joints: np.ndarray
    masks: np.ndarray
    frame_names: tuple[str, ...]


def silhouette_inputs(sequence: Sequence, robot: Robot, params: PolishParams,
                      predict_masks: Callable[[list[int]], np.ndarray] | None = None
                      ) -> SilhouetteInputs:
    """The frames an all-frames polish of `sequence` scores (at most `max_eval_frames`, evenly
    spaced, among those with a mask), their joints and masks, and the robot's meshes. Without
    masks in the data, `predict_masks(frame_indices) -> (n, H, W) bool` supplies them."""
    from dream.io import load_mask
    from dream.pipeline import joints_in_robot_order

    with_mask = np.flatnonzero([f.mask_path is not None for f in sequence.frames])
    if len(with_mask):                                   # `has_masks`
        chosen = _evenly_spaced(with_mask, params.max_eval_frames)
        masks = np.stack([load_mask(f, sequence.camera) for f in
                          (sequence.frames[i] for i in chosen)])
    else:
        if predict_masks is None:
            raise InputError("the data has no robot masks and no mask source was given",
                             sequence.source, "add masks or pass predict_masks")
        chosen = _evenly_spaced(np.arange(len(sequence)), params.max_eval_frames)
        masks = predict_masks([int(i) for i in chosen]).astype(np.uint8)
    return SilhouetteInputs(load_robot_meshes(robot, params.max_triangles),
                            joints_in_robot_order(sequence, robot)[chosen], masks,
                            tuple(sequence.frames[i].name for i in chosen))


def polish_calibration(sequence: Sequence, robot: Robot, result: CalibrationResult,
                       obs: Observations, params: PolishParams | None = None,
                       predict_masks: Callable[[list[int]], np.ndarray] | None = None
                       ) -> PolishResult:
    """Polish an "all"-mode calibration of `sequence` with its masks (`silhouette_inputs`),
    guarded by the calibration's inlier keypoints.

    Without masks in the data, `predict_masks(frame_indices) -> (n, H, W) bool` supplies them
    (the keypoint network's mask head, `dream.detect.predict_masks`)."""
    params = params or PolishParams()
    if result.mode != "all":
        raise InputError("polish_calibration polishes the one extrinsic of a fixed camera; "
                         "polish an --frames each result with polish_frames")
    check_polish_input(sequence, "all", network_masks=predict_masks is not None)
    inputs = silhouette_inputs(sequence, robot, params, predict_masks)
    return polish(inputs.meshes, inputs.joints, inputs.masks, sequence.camera,
                  result.fit.T_cam_base, _inlier_keypoints(result, obs, slice(None)), params,
                  inputs.frame_names)


PROGRESS_EVERY_POLISHED = 64   # `polish_frames` reports progress after this many frames


def polish_frames(sequence: Sequence, robot: Robot, result: CalibrationResult,
                  obs: Observations, params: PolishParams | None = None,
                  progress: Callable[[int, int], None] | None = None
                  ) -> tuple[PolishResult | None, ...]:
    """Polish every frame's own pose of an "each"-mode calibration with that frame's mask from
    the data (`check_polish_input`) and its own camera (`sequence.frame_camera`), guarded by
    the median distance of its inlier keypoints (`KeypointGuard.MEDIAN`).

    A search only finds the silhouette optimum near its start, and a frame's keypoint pose can
    lie far from it when it followed a misplaced keypoint. So a frame whose polish is refused
    or ends below `frame_restart_below_iou` is polished again from the frame's poses solved
    without each of its keypoints in turn (`FrameSolution.leave_outs`, from `calibrate_each`);
    each result is judged against the keypoint pose with the same guard, and the one with the
    highest IoU that passes is kept (`_restarts`).

    Frames without a solution, without a mask file or with an empty mask get None.
    `progress(done, total)` is called every `PROGRESS_EVERY_POLISHED` frames and at the end.
    """
    from dream.io import load_mask
    from dream.pipeline import joints_in_robot_order

    params = params or PolishParams()
    if result.mode != "each":
        raise InputError("polish_frames polishes each frame's own pose (--frames each); "
                         "polish an all-frames result with polish_calibration")
    check_polish_input(sequence, "each")
    todo = [i for i, (frame, solution) in enumerate(zip(sequence.frames, result.frames,
                                                        strict=True))
            if isinstance(solution.fit, PoseFit) and frame.mask_path is not None]
    joints = joints_in_robot_order(sequence, robot)
    meshes = load_robot_meshes(robot, params.max_triangles)
    out: list[PolishResult | None] = [None] * len(sequence)
    for done, i in enumerate(todo, start=1):
        frame, solution = sequence.frames[i], result.frames[i]
        camera = sequence.frame_camera(i)
        mask = load_mask(frame, camera)
        if mask.any():
            out[i] = _polish_frame(meshes, joints[i:i + 1], mask, camera,
                                   solution.fit.T_cam_base, _inlier_keypoints(result, obs, i),
                                   params, frame.name, solution.leave_outs)
        else:
            log.info("frame %s: empty robot mask, not polished", frame.name)
        if progress is not None and (done % PROGRESS_EVERY_POLISHED == 0 or done == len(todo)):
            progress(done, len(todo))
    return tuple(out)


def _polish_frame(meshes: RobotMeshes, joints: np.ndarray, mask: np.ndarray,
                  camera: CameraIntrinsics, T_keypoints: np.ndarray,
                  keypoints: KeypointSet | None, params: PolishParams, name: str,
                  other_starts: SequenceOf[tuple[str, np.ndarray]]) -> PolishResult:
    """One frame polished from its keypoint pose and, when that is refused or ends below
    `frame_restart_below_iou`, from `other_starts` (keypoint left out, T) too (`_restarts`)."""
    def polish_from(T: np.ndarray) -> PolishResult:
        return polish(meshes, joints, mask[None], camera, T, keypoints, params, [name],
                      guard=KeypointGuard.MEDIAN)

    first = polish_from(T_keypoints)
    if first.kept and first.iou_after_mean >= params.frame_restart_below_iou:
        return first
    return _restarts(first, other_starts, polish_from, params)


def _restarts(first: PolishResult, starts: SequenceOf[tuple[str, np.ndarray]],
              polish_from: Callable[[np.ndarray], PolishResult],
              params: PolishParams) -> PolishResult:
    """The best of `first` (a frame polished from its keypoint pose) and the polishes
    `polish_from(T)` of the other `starts`, each judged against the keypoint pose (its IoU and
    keypoint median) with the median guard; the highest IoU among those kept wins."""
    best = first if first.kept else None
    seconds = first.seconds
    for left_out, T_start in starts:
        candidate = polish_from(T_start)
        seconds += candidate.seconds
        kept, reason = _decide(first.iou_before_mean, candidate.iou_after_mean,
                               first.median_before, candidate.median_after,
                               first.guard_keypoints, params, KeypointGuard.MEDIAN)
        if kept and (best is None or candidate.iou_after_mean > best.iou_after_mean):
            best = replace(candidate, T_before=first.T_before, T_after=candidate.T_polished,
                           iou_before=first.iou_before, kept=True,
                           reason=f"{reason}; searched from the pose without {left_out}",
                           rmse_before=first.rmse_before, median_before=first.median_before,
                           start=left_out)
    return replace(best or first, seconds=seconds)


def _floats(a: np.ndarray) -> list[float]:
    return [float(x) for x in a]


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def polish_to_dict(res: PolishResult) -> dict[str, Any]:
    """The `polish` object of RESULT.json."""
    moved_m, moved_rad = res.correction
    return {
        "iou_before": res.iou_before_mean,
        "iou_after": res.iou_after_mean,
        "kept": bool(res.kept),
        "reason": res.reason,
        "frames": list(res.frames),
        "iou_before_per_frame": _floats(res.iou_before),
        "iou_after_per_frame": _floats(res.iou_after),
        "rmse_px_before": _finite_or_none(res.rmse_before),
        "rmse_px_after": _finite_or_none(res.rmse_after),
        "median_px_before": _finite_or_none(res.median_before),
        "median_px_after": _finite_or_none(res.median_after),
        "keypoint_guard": res.guard,
        "started_without_keypoint": res.start or None,
        "T_cam_base_keypoints": res.T_before.tolist(),
        "T_cam_base_polished": res.T_polished.tolist(),
        "camera_position_change_m": moved_m,
        "rotation_change_rad": moved_rad,
        "search_frames": list(res.search_frames),
        "seconds": res.seconds,
    }


def _with_pose(doc: dict[str, Any], T: np.ndarray, rmse_px: float) -> None:
    """Set a RESULT.json document's pose fields (`T_cam_base`, `translation_m`,
    `quaternion_xyzw`, `T_base_cam`, `sigma_camera_position_base_m`) and, when finite,
    `rmse_px` to those of the polished pose `T` (the covariance stays the keypoint fit's)."""
    from dream.result import camera_position_covariance

    doc["T_cam_base"] = T.tolist()
    doc["translation_m"] = T[:3, 3].tolist()
    doc["quaternion_xyzw"] = quaternion_xyzw_from_R(T[:3, :3]).tolist()
    doc["T_base_cam"] = invert_T(T).tolist()
    if np.isfinite(rmse_px):
        doc["rmse_px"] = float(rmse_px)
    if doc.get("covariance_xi") is not None:
        cov = camera_position_covariance(T, np.asarray(doc["covariance_xi"], dtype=float))
        doc["sigma_camera_position_base_m"] = np.sqrt(np.diag(cov)).tolist()


def result_doc_with_polish(doc: dict[str, Any], res: PolishResult) -> dict[str, Any]:
    """A copy of an all-frames RESULT.json document with its `polish` object; when the polish
    is kept, the pose fields and `rmse_px` describe the polished pose (`_with_pose`)."""
    out = dict(doc)
    out["polish"] = polish_to_dict(res)
    if res.kept:
        _with_pose(out, res.T_after, res.rmse_after)
    return out


_MULTI_FRAME_KEYS = ("frames", "iou_before_per_frame", "iou_after_per_frame", "search_frames")


def frame_polish_to_dict(res: PolishResult) -> dict[str, Any]:
    """The `polish` object of a `per_frame` entry ("each" mode): `polish_to_dict` without the
    lists of frames."""
    return {k: v for k, v in polish_to_dict(res).items() if k not in _MULTI_FRAME_KEYS}


def frame_polish_summary(results: SequenceOf[PolishResult | None]) -> dict[str, Any]:
    """The top-level `polish` object of an "each"-mode RESULT.json: how many frames were
    polished and kept, their mean IoU before, at the polished poses, and at the poses kept."""
    done = [r for r in results if r is not None]
    if not done:
        return {"mode": "each", "frames_polished": 0, "frames_kept": 0, "iou_before": None,
                "iou_after": None, "iou_kept": None, "seconds": 0.0}
    return {
        "mode": "each",
        "frames_polished": len(done),
        "frames_kept": sum(r.kept for r in done),
        "iou_before": float(np.mean([r.iou_before_mean for r in done])),
        "iou_after": float(np.mean([r.iou_after_mean for r in done])),
        "iou_kept": float(np.mean([r.iou_after_mean if r.kept else r.iou_before_mean
                                   for r in done])),
        "seconds": float(sum(r.seconds for r in done)),
    }


def result_doc_with_frame_polishes(doc: dict[str, Any],
                                   results: SequenceOf[PolishResult | None]) -> dict[str, Any]:
    """A copy of an "each"-mode RESULT.json document with each polished frame's `polish`
    object and, where kept, its polished `T_cam_base` and `rmse_px`; the top-level `polish`
    object is `frame_polish_summary`, and the top-level pose is the reported frame's polished
    one when that frame's polish was kept (`_with_pose`)."""
    if doc.get("frames_mode") != "each" or len(doc["per_frame"]) != len(results):
        raise InputError(f"per-frame polishes need an each-mode result with {len(results)} "
                         "frames")
    out = dict(doc)
    per_frame = []
    for entry, res in zip(doc["per_frame"], results, strict=True):
        entry = dict(entry)
        if res is not None:
            entry["polish"] = frame_polish_to_dict(res)
            if res.kept:
                entry["T_cam_base"] = res.T_after.tolist()
                if np.isfinite(res.rmse_after):
                    entry["rmse_px"] = float(res.rmse_after)
            if entry["frame"] == doc.get("reported_frame") and res.kept:
                _with_pose(out, res.T_after, res.rmse_after)
        per_frame.append(entry)
    out["per_frame"] = per_frame
    out["polish"] = frame_polish_summary(results)
    return out
