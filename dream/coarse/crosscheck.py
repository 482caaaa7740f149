"""The silhouettes' cross-check of a pose found another way (the keypoint fit, its edge
alignment or its silhouette polish on the data's masks): the robot's masks of the recording
(`dream.coarse.calibration.search_masks`: the data's, or motion masks), a local silhouette
search started from that pose and from the keypoint pose, and what it found. The verdict on
it is `dream.coarse.verdict.crosscheck_findings`: a written pose that the silhouettes move by
more than a few centimetres is not `good`, however well the keypoints agree with it.

Where the written pose is the edge alignment's, the silhouettes also arbitrate between it and the
keypoint pose it started from (`undoes_alignment`): an optimum much nearer the keypoint pose
says the alignment slid off along what the edges hardly constrain (the camera's depth), and the
keypoint pose is written instead; not where their optimum agrees with the aligned pose
anyway.

At the silhouettes' optimum the outlines also check the given intrinsics, as after the search:
the lens's radial distortion (`dream.coarse.distortion`), the focal length
(`dream.coarse.focal`: a scale the outlines ask for and the overlap agrees with) through the
distortion where it was asked for, and then, through both where they were asked for, the
principal point (`dream.coarse.principal`). A wrong fx, fy slides the camera along its axis
and a wrong cx, cy turns it, and the keypoints, the edges and the silhouettes all follow with
a pose that their 1-sigmas do not hold (on rendered scenes given cx, cy 12, -8 px off,
`good` up to 4.9 deg off). None is adopted here: the pose written stays the keypoints' or the
edges', and the verdict and its 1-sigma say how far the asked intrinsics move it. A
distortion left out of the given intrinsics (raw images given a rectified camera) bends the
outlines in a way a focal length and a principal point partly make up for, so where the
outlines ask for one, the keypoint path adopts the distortion alone and fits those again
through it (`dream.cli.keypoint_pass.next_adoption`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dream.coarse.away import AwayPixels, away_at_pose
from dream.coarse.calibration import SearchMasks, search_masks
from dream.coarse.distortion import DistortionEstimate, DistortionSettings, fit_distortion
from dream.coarse.focal import FocalEstimate, FocalSettings, fit_focal
from dream.coarse.principal import PrincipalEstimate, PrincipalSettings, fit_principal
from dream.coarse.search import SearchOutcome, pose_iou, search
from dream.coarse.settings import SearchSettings
from dream.coarse.verdict import cues_agree
from dream.metrics import pose_errors
from dream.pnp import increment_between
from dream.robot import Robot
from dream.sequence import Sequence
from dream.silhouette import vertices_in_base

CROSSCHECK_STARTS = 4   # the given poses, as given and aimed at the robot's masks


@dataclass(frozen=True)
class Crosscheck:
    """The silhouettes' optimum near a written pose: the search's outcome, the IoU of the
    written pose's silhouettes (scored as the search scores its optimum), the distance (m,
    rad) from the written pose to the optimum, the masks' source and how many frames, the
    masks' pixels away from the robot at the optimum (`dream.coarse.away`), the keypoint
    pose's IoU, and the focal length, principal point and radial distortion the outlines ask
    for at the optimum (None where the robot was not found there)."""

    outcome: SearchOutcome
    iou_written: float
    distance_m: float
    angle_rad: float
    source: str
    frames: int
    away: AwayPixels
    iou_keypoints: float
    focal: FocalEstimate | None = None
    principal: PrincipalEstimate | None = None
    distortion: DistortionEstimate | None = None

    @property
    def intrinsics_covariance(self) -> np.ndarray:
        """(6, 6) what the intrinsics the outlines ask for add to the written pose's covariance:
        the move from the optimum to the pose through them (the asked distortion's and focal
        length's, where asked for: `DistortionEstimate.adopted`, `FocalEstimate.adopted`; then
        the flagged or unresolved principal point's, fitted from there), and the spreads of
        those poses (`DistortionEstimate.pose_covariance`, `FocalEstimate.pose_covariance`,
        `PrincipalEstimate.spread`), and an unresolved principal point's turn
        (`PrincipalEstimate.unresolved_covariance`); zero where they agree with the given
        ones."""
        covariance, T_asked = np.zeros((6, 6)), self.outcome.best.T_cam_base
        if self.distortion is not None and self.distortion.adopted:
            covariance += self.distortion.pose_covariance
            T_asked = self.distortion.T_cam_base
        if self.focal is not None and self.focal.adopted:
            covariance += self.focal.pose_covariance
            T_asked = self.focal.T_cam_base
        if self.principal is not None and (self.principal.flagged
                                           or self.principal.unresolved):
            covariance += self.principal.spread + self.principal.unresolved_covariance
            T_asked = self.principal.T_cam_base
        move = increment_between(self.outcome.best.T_cam_base, T_asked)
        return covariance + np.outer(move, move)

    @property
    def found_iou(self) -> float:
        """The optimum's IoU without the pixels away from the robot there."""
        return self.away.iou_without(self.outcome.best.iou)

    def at_keypoints(self, T_keypoints: np.ndarray) -> Crosscheck:
        """The same check, as of the keypoint pose written instead of the aligned one."""
        m, rad = pose_errors(np.asarray(T_keypoints), self.outcome.best.T_cam_base)
        return replace(self, iou_written=self.iou_keypoints, distance_m=float(m),
                       angle_rad=float(rad))

    def to_dict(self) -> dict:
        o = self.outcome
        return {"evidence": self.source, "frames": self.frames,
                "T_cam_base_silhouettes": o.best.T_cam_base.tolist(),
                "iou_written": self.iou_written, "iou_silhouettes": o.best.iou,
                "distance_m": self.distance_m, "angle_rad": self.angle_rad,
                "basin_returned": o.basin_returned, "basin_starts": o.basin_starts,
                "basin_m": o.basin_m, "basin_return_m": o.basin_return_m,
                "away": {**self.away.to_dict(), "iou_without": self.found_iou},
                "focal": None if self.focal is None else {
                    **replace(self.focal, adopted=False).to_dict(), "asked": self.focal.adopted},
                "principal": None if self.principal is None else self.principal.to_dict(),
                "distortion": None if self.distortion is None else {
                    **replace(self.distortion, adopted=False).to_dict(),
                    "asked": self.distortion.adopted},
                "seconds": o.seconds}


def silhouette_crosscheck(sequence: Sequence, robot: Robot, T_written: np.ndarray,
                          T_keypoints: np.ndarray, settings: SearchSettings | None = None,
                          progress=None) -> Crosscheck:
    """The local silhouette search from `T_written` and `T_keypoints` (module doc).

    Raises:
        InputError: no masks can be made (a moving camera, no images, an arm that hardly
            moves).
    """
    settings = settings or SearchSettings()
    inputs = search_masks(sequence, robot, settings)
    held = inputs.held
    local = replace(settings, local_starts=CROSSCHECK_STARTS,
                    fine_starts=min(settings.fine_starts, CROSSCHECK_STARTS),
                    jackknife_groups=0)     # its pose is not written: no 1-sigma of its own
    outcome = search(inputs.meshes, inputs.joints, inputs.masks, sequence.camera,
                     {"written": np.asarray(T_written)[None],
                      "keypoints": np.asarray(T_keypoints)[None]},
                     local, held=held, progress=progress, search_frames=inputs.search)

    def scored(T: np.ndarray) -> float:     # as the search scores its optimum
        return pose_iou(inputs.meshes, inputs.joints, inputs.masks, sequence.camera, T, local,
                        held, inputs.search)

    iou = scored(T_written)
    iou_keypoints = iou if np.array_equal(T_written, T_keypoints) else scored(T_keypoints)
    m, rad = pose_errors(np.asarray(T_written), outcome.best.T_cam_base)
    away = away_at_pose(inputs.meshes, inputs.joints, inputs.masks, sequence.camera,
                        outcome.best.T_cam_base, settings.away_margin_px)
    intrinsics = intrinsics_at_optimum(sequence, inputs, outcome, settings, progress)
    return Crosscheck(outcome, iou, float(m), float(rad), inputs.source, len(inputs.frames),
                      away, iou_keypoints, *intrinsics)


def intrinsics_at_optimum(sequence: Sequence, inputs: SearchMasks, outcome: SearchOutcome,
                          settings: SearchSettings, progress=None
                          ) -> tuple[FocalEstimate | None, PrincipalEstimate | None,
                                     DistortionEstimate | None]:
    """The radial distortion, then the focal length through it, then the principal point
    through both (each where asked for), that the outlines ask for at the local search's
    optimum (module doc); (None, None, None) where the robot was not found there."""
    if not settings.robot_found(outcome.best.iou):
        return None, None, None
    P = vertices_in_base(inputs.meshes, inputs.joints)
    held, camera, T = inputs.held, sequence.camera, outcome.best.T_cam_base
    distortion = fit_distortion(P, inputs.meshes, inputs.masks, camera, T, settings,
                                DistortionSettings(), held, inputs.region)
    if distortion.adopted:
        camera, T = distortion.camera, distortion.T_cam_base
    focal = fit_focal(P, inputs.meshes, inputs.masks, camera, T, settings, FocalSettings(),
                      held, inputs.region)
    if focal.adopted:
        camera, T = focal.camera, focal.T_cam_base
    principal = fit_principal(P, inputs.meshes, inputs.masks, camera, T, settings,
                              PrincipalSettings(), held, inputs.region)
    if progress is not None:
        progress(f"intrinsics: {distortion.reason}; {focal.reason}; {principal.reason}")
    return focal, principal, distortion


def sides_with_keypoints(T_keypoints: np.ndarray, T_aligned: np.ndarray,
                         T_silhouettes: np.ndarray, ratio: float) -> tuple[bool, float, float]:
    """Whether the silhouettes' optimum `T_silhouettes` lies nearer the keypoint pose than
    `ratio` times its distance to the aligned pose (camera centres in the base frame), and
    both distances (m). All (4, 4) `T_cam_base`.

    >>> T = np.eye(4); near, far = T.copy(), T.copy()
    >>> near[2, 3], far[2, 3] = 0.004, 0.02
    >>> side, to_keypoints, to_aligned = sides_with_keypoints(T, far, near, 0.5)
    >>> side, round(to_keypoints, 6), round(to_aligned, 6)
    (True, 0.004, 0.016)
    >>> sides_with_keypoints(far, T, near, 0.5)[0]
    False
    """
    to_keypoints = float(pose_errors(np.asarray(T_keypoints), np.asarray(T_silhouettes))[0])
    to_aligned = float(pose_errors(np.asarray(T_aligned), np.asarray(T_silhouettes))[0])
    return to_keypoints < ratio * to_aligned, to_keypoints, to_aligned


def undoes_alignment(check: Crosscheck, T_keypoints: np.ndarray, T_aligned: np.ndarray,
                     settings: SearchSettings) -> tuple[bool, float, float]:
    """Whether the silhouettes undo a kept edge alignment `T_aligned` (the pose `check` was
    made at) that started from `T_keypoints`, and their optimum's distances (m) to both: where
    they disagree with the aligned pose (`dream.coarse.verdict.cues_agree`: within that the
    alignment stands) and side with the keypoint pose (`sides_with_keypoints`,
    `keypoint_side_ratio`). Masks that also hold something else moving (a person, IoU below
    `min_found_iou`) still arbitrate: on renders their optimum sided with the right pose."""
    side, to_keypoints, to_aligned = sides_with_keypoints(
        T_keypoints, T_aligned, check.outcome.best.T_cam_base, settings.keypoint_side_ratio)
    return side and not cues_agree(check.distance_m, check.angle_rad), to_keypoints, to_aligned
