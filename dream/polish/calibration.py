"""The polish applied to a calibration: all frames of a fixed camera, or each frame alone.

`dream calibrate --polish`: data without any mask is one error line and exit code 2 before
anything is solved (a polish that was asked for is never skipped silently), unless
`--mask-head` asks for the `--model`'s mask head and the mode is all frames (opt-in: the bundled
model's mask head made rendered scenes worse, and its masks are too coarse for a frame alone;
`check_polish_input`). All frames (`polish_calibration`): the frames with masks
(`silhouette_inputs`) that agree with each other (`dream.polish.frames`) align the one
extrinsic. The data's own masks decide alone where the silhouettes then overlap
(`min_evidence_iou`; the keypoint detections' disagreement is reported, not a veto), searched
from the keypoint pose and from the best single-frame poses (`mask_starts`); masks the tool
predicts, and a polish that did not find the robot, are guarded by the median distance of all
the keypoint detections (`dream.polish.guard`). A kept pose gets its own 1-sigma, the link
jackknife of `polish_jackknife`. `--frames each`
(`polish_frames`): every solved frame with a non-empty mask is polished alone, guarded by the
median distance of its own inlier keypoints.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, replace

import numpy as np

from dream.calibration import CalibrationResult, Observations
from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.pnp import PoseFit
from dream.polish.guard import KeypointGuard, KeypointSet, decide
from dream.polish.objective import evenly_spaced
from dream.polish.refine import PolishResult, polish, polish_jackknife
from dream.polish.settings import PolishSettings
from dream.quality import MIN_KEPT_SHARE
from dream.robot import Robot
from dream.robot.link_geometry import LinkGeometry, excluded_links, with_link_geometry
from dream.sequence import Sequence
from dream.silhouette import RobotMeshes, load_robot_meshes, without_links

log = logging.getLogger(__name__)

PROGRESS_EVERY_POLISHED = 64   # `polish_frames` reports progress after this many frames


def check_polish_input(sequence: Sequence, mode: str, network_masks: bool = False) -> None:
    """Refuse a polish that cannot run or would not help: no masks in the data unless the
    network's mask head was asked for (`network_masks`, `dream calibrate --mask-head`), and a
    frame alone (`mode` "each") with only the mask head. The mask head is opt-in: on rendered
    frames the bundled model's agrees with the true masks at IoU 0.59, polished single-frame
    poses were worse, and on 40 rendered fixed-camera scenes every all-frames polish against
    it was worse; the guard kept 7, each 15-27 mm further off than the keypoint pose
    (docs/benchmarks.md).

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
                         "instead; the bundled model's is too coarse: docs/benchmarks.md)")
    if mode == "each":
        raise InputError("--frames each --polish needs robot masks in the data (the network's "
                         "mask head is too coarse to polish a frame alone)", sequence.source,
                         "add NNNNNN.seg.png masks (DREAM layout) or mask/ (franka_offline), "
                         "use --frames all, or drop --polish")


def has_masks(sequence: Sequence) -> bool:
    """Whether any frame of `sequence` has a robot mask file."""
    return any(f.mask_path is not None for f in sequence.frames)


def inlier_keypoints(result: CalibrationResult, obs: Observations,
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


def polish_meshes(robot: Robot, params: PolishSettings,
                  link_geometry: tuple[LinkGeometry, ...] = (),
                  leave_out_links: SequenceOf[str] = ()) -> RobotMeshes:
    """The meshes whose silhouettes are rendered: a model extension's `link_geometry` applied
    (boxes added, links scaled), without its excluded links and `leave_out_links`."""
    meshes = with_link_geometry(load_robot_meshes(robot, params.max_triangles), link_geometry)
    left_out = (*leave_out_links, *excluded_links(link_geometry))
    return without_links(meshes, tuple(left_out)) if left_out else meshes


def silhouette_inputs(sequence: Sequence, robot: Robot, params: PolishSettings,
                      predict_masks: Callable[[list[int]], np.ndarray] | None = None,
                      link_geometry: tuple[LinkGeometry, ...] = (),
                      leave_out_links: SequenceOf[str] = ()) -> SilhouetteInputs:
    """The frames an all-frames polish of `sequence` scores (at most `max_eval_frames`, evenly
    spaced, among those with a mask), their joints and masks, and the meshes to render
    (`polish_meshes`). Without masks in the data, `predict_masks(frame_indices) -> (n, H, W)
    bool` supplies them."""
    from dream.io import load_mask
    from dream.pipeline import joints_in_robot_order

    with_mask = np.flatnonzero([f.mask_path is not None for f in sequence.frames])
    if len(with_mask):                                   # `has_masks`
        chosen = evenly_spaced(with_mask, params.max_eval_frames)
        masks = np.stack([load_mask(f, sequence.camera) for f in
                          (sequence.frames[i] for i in chosen)])
    else:
        if predict_masks is None:
            raise InputError("the data has no robot masks and no mask source was given",
                             sequence.source, "add masks or pass predict_masks")
        chosen = evenly_spaced(np.arange(len(sequence)), params.max_eval_frames)
        masks = predict_masks([int(i) for i in chosen]).astype(np.uint8)
    return SilhouetteInputs(polish_meshes(robot, params, link_geometry, leave_out_links),
                            joints_in_robot_order(sequence, robot)[chosen], masks,
                            tuple(sequence.frames[i].name for i in chosen))


def polish_calibration(sequence: Sequence, robot: Robot, result: CalibrationResult,
                       obs: Observations, params: PolishSettings | None = None,
                       predict_masks: Callable[[list[int]], np.ndarray] | None = None,
                       leave_out_links: SequenceOf[str] = (),
                       link_geometry: tuple[LinkGeometry, ...] = ()) -> PolishResult:
    """Polish an "all"-mode calibration of `sequence` with its masks (`silhouette_inputs`),
    guarded by all its keypoint detections.

    Without masks in the data, `predict_masks(frame_indices) -> (n, H, W) bool` supplies them
    (the keypoint network's mask head, `dream.detection.predict_masks`; motion masks,
    `dream.edges.motion`). The silhouettes rendered leave out `leave_out_links` (links that
    masks do not show: those that never move, for motion masks). `link_geometry` (a model
    extension's) corrects the rendered geometry: a tool the URDF lacks, a scaled link; its
    excluded links are left out of the silhouettes."""
    params = params or PolishSettings()
    if result.mode != "all":
        raise InputError("polish_calibration polishes the one extrinsic of a fixed camera; "
                         "polish an --frames each result with polish_frames")
    check_polish_input(sequence, "all", network_masks=predict_masks is not None)
    inputs = silhouette_inputs(sequence, robot, params, predict_masks, link_geometry,
                               leave_out_links)
    detections = all_detections(obs)
    inliers = inlier_keypoints(result, obs, slice(None))
    camera = sequence.camera
    res = None
    trusted = (detections is not None and inliers is not None
               and len(inliers.P_base) >= MIN_KEPT_SHARE * len(detections.P_base))
    if predict_masks is None:          # the data's own masks: the detections do not veto
        res = _polish_on_data_masks(inputs, camera, result, params, trusted)
        if res.iou_after_mean >= params.min_evidence_iou or detections is None:
            res = _with_detector_report(res, detections, inliers, camera)
        else:
            log.info("silhouette polish: mean IoU %.3f below %.2f, guarded by the keypoint "
                     "detections", res.iou_after_mean, params.min_evidence_iou)
            res = None
    if res is None:
        res = polish(inputs.meshes, inputs.joints, inputs.masks, camera, result.fit.T_cam_base,
                     detections, params, inputs.frame_names, guard=KeypointGuard.ALL_MEDIAN,
                     inliers=inliers if trusted else None)
    if not res.kept:
        return res
    used = res.used
    return replace(res, jackknife=polish_jackknife(inputs.meshes, inputs.joints[used],
                                                   inputs.masks[used], camera, res.T_after,
                                                   params))


def _polish_on_data_masks(inputs: SilhouetteInputs, camera: CameraIntrinsics,
                          result: CalibrationResult, params: PolishSettings,
                          trusted_fit: bool) -> PolishResult:
    """The all-frames polish against the data's own masks (no keypoint veto), from the
    keypoint pose and, where that ends below `frame_restart_below_iou` and the keypoint fit is
    not `trusted_fit` (it kept less than `MIN_KEPT_SHARE` of the detections: a biased few may
    have pulled it far off), from the `mask_starts` single-frame poses whose silhouettes
    overlap the masks best (`_ranked_frame_starts`); the polish with the highest IoU wins,
    judged against the keypoint pose."""
    def polish_from(T: np.ndarray) -> PolishResult:
        return polish(inputs.meshes, inputs.joints, inputs.masks, camera, T, None, params,
                      inputs.frame_names, guard=KeypointGuard.NONE)

    first = polish_from(result.fit.T_cam_base)
    if first.iou_after_mean >= params.frame_restart_below_iou or trusted_fit:
        return first
    best, best_start, seconds = first, "", first.seconds
    for name, T_start in _ranked_frame_starts(inputs, camera, result, params):
        candidate = polish_from(T_start)
        seconds += candidate.seconds
        if candidate.iou_after_mean > best.iou_after_mean:
            best = candidate
            best_start = name
    if best is first:
        return replace(first, seconds=seconds)
    iou0 = float(first.iou_before[best.used].mean())
    kept, reason = decide(iou0, best.iou_after_mean, float("nan"), float("nan"), 0, params,
                          KeypointGuard.NONE)
    return replace(best, T_before=first.T_before, T_after=best.T_polished if kept else
                   first.T_before, iou_before=first.iou_before, kept=kept,
                   reason=f"{reason}; searched from frame {best_start}'s own keypoint pose",
                   start=f"frame {best_start}", seconds=seconds)


def _ranked_frame_starts(inputs: SilhouetteInputs, camera: CameraIntrinsics,
                         result: CalibrationResult, params: PolishSettings
                         ) -> list[tuple[str, np.ndarray]]:
    """The `mask_starts` single-frame keypoint poses (name, T) of `result.frames` whose
    silhouettes overlap the masks most (mean IoU over `rank_frames` evenly spaced frames),
    leaving out those equal to the all-frames pose."""
    from dream.silhouette import render_frames, silhouette_iou, vertices_in_base

    starts = [(f.name, f.fit.T_cam_base) for f in result.frames if isinstance(f.fit, PoseFit)
              and not np.allclose(f.fit.T_cam_base, result.fit.T_cam_base, atol=SAME_POSE)]
    if not starts or params.mask_starts == 0:
        return []
    frames = evenly_spaced(np.flatnonzero(inputs.masks.reshape(len(inputs.masks), -1)
                                          .any(axis=1)), params.rank_frames)
    P = vertices_in_base(inputs.meshes, inputs.joints[frames])

    def overlap(T: np.ndarray) -> float:
        rendered = render_frames(P, inputs.meshes.faces, T, camera)
        return float(np.mean([silhouette_iou(r, inputs.masks[i])
                              for r, i in zip(rendered, frames, strict=True)]))

    ranked = sorted(starts, key=lambda start: -overlap(start[1]))
    return ranked[:params.mask_starts]


SAME_POSE = 1e-6   # starts this close (every matrix entry) to the all-frames pose are not new


def _with_detector_report(res: PolishResult, detections: KeypointSet | None,
                          inliers: KeypointSet | None, camera: CameraIntrinsics
                          ) -> PolishResult:
    """A polish decided by the data's masks alone, with the keypoint detections' median
    distance and the fit's inlier RMSE at both poses, and, when kept, the detections'
    disagreement named in its reason."""
    if detections is None:
        return res
    T0, T1 = res.T_before, res.T_polished
    median0, median1 = detections.median_px(camera, T0), detections.median_px(camera, T1)
    rmse0, rmse1 = ((inliers.rmse_px(camera, T0), inliers.rmse_px(camera, T1))
                    if inliers is not None else (float("nan"), float("nan")))
    reason = res.reason
    if res.kept:
        reason += (f"; the {len(detections.P_base)} keypoint "
                   f"detections lie a median {median1:.2f} px from the polished pose "
                   f"({median0:.2f} px from the keypoint pose), the detector's disagreement "
                   "with these images")
    return replace(res, reason=reason, median_before=median0, median_after=median1,
                   rmse_before=rmse0, rmse_after=rmse1)


def all_detections(obs: Observations | None) -> KeypointSet | None:
    """Every keypoint detection of `obs`, inlier of a fit or not (the "all-median" guard);
    None without any."""
    if obs is None or not obs.found.any():
        return None
    return KeypointSet(obs.P_base[obs.found], obs.uv[obs.found])


def polish_frames(sequence: Sequence, robot: Robot, result: CalibrationResult,
                  obs: Observations, params: PolishSettings | None = None,
                  progress: Callable[[int, int], None] | None = None,
                  link_geometry: tuple[LinkGeometry, ...] = ()
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
    `link_geometry` as in `polish_calibration`. `progress(done, total)` is called every
    `PROGRESS_EVERY_POLISHED` frames and at the end.
    """
    from dream.io import load_mask
    from dream.pipeline import joints_in_robot_order

    params = params or PolishSettings()
    if result.mode != "each":
        raise InputError("polish_frames polishes each frame's own pose (--frames each); "
                         "polish an all-frames result with polish_calibration")
    check_polish_input(sequence, "each")
    todo = [i for i, (frame, solution) in enumerate(zip(sequence.frames, result.frames,
                                                        strict=True))
            if isinstance(solution.fit, PoseFit) and frame.mask_path is not None]
    joints = joints_in_robot_order(sequence, robot)
    meshes = polish_meshes(robot, params, link_geometry)
    out: list[PolishResult | None] = [None] * len(sequence)
    for done, i in enumerate(todo, start=1):
        frame, solution = sequence.frames[i], result.frames[i]
        camera = sequence.frame_camera(i)
        mask = load_mask(frame, camera)
        if mask.any():
            res = _polish_frame(meshes, joints[i:i + 1], mask, camera, solution.fit.T_cam_base,
                                inlier_keypoints(result, obs, i), params, frame.name,
                                solution.leave_outs)
            if res.kept and i == result.reported_frame:    # the pose written gets its 1-sigma
                res = replace(res, jackknife=polish_jackknife(meshes, joints[i:i + 1],
                                                              mask[None], camera, res.T_after,
                                                              params))
            out[i] = res
        else:
            log.info("frame %s: empty robot mask, not polished", frame.name)
        if progress is not None and (done % PROGRESS_EVERY_POLISHED == 0 or done == len(todo)):
            progress(done, len(todo))
    return tuple(out)


def _polish_frame(meshes: RobotMeshes, joints: np.ndarray, mask: np.ndarray,
                  camera: CameraIntrinsics, T_keypoints: np.ndarray,
                  keypoints: KeypointSet | None, params: PolishSettings, name: str,
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
              params: PolishSettings) -> PolishResult:
    """The best of `first` (a frame polished from its keypoint pose) and the polishes
    `polish_from(T)` of the other `starts`, each judged against the keypoint pose (its IoU and
    keypoint median) with the median guard; the highest IoU among those kept wins."""
    best = first if first.kept else None
    seconds = first.seconds
    for left_out, T_start in starts:
        candidate = polish_from(T_start)
        seconds += candidate.seconds
        kept, reason = decide(first.iou_before_mean, candidate.iou_after_mean,
                              first.median_before, candidate.median_after,
                              first.guard_keypoints, params, KeypointGuard.MEDIAN)
        if kept and (best is None or candidate.iou_after_mean > best.iou_after_mean):
            best = replace(candidate, T_before=first.T_before, T_after=candidate.T_polished,
                           iou_before=first.iou_before, kept=True,
                           reason=f"{reason}; searched from the pose without {left_out}",
                           rmse_before=first.rmse_before, median_before=first.median_before,
                           start=left_out)
    return replace(best or first, seconds=seconds)
