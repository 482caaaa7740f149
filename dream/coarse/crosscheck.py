"""The silhouettes' cross-check of a pose found another way (the keypoint fit and its edge
alignment): the robot's masks of the recording (`dream.coarse.calibration.search_masks`: the
data's, or motion masks), a local silhouette search started from that pose and from the
keypoint pose, and what it found. The verdict on it is `dream.coarse.verdict.crosscheck_findings`:
a written pose that the silhouettes move by more than a few centimetres is not `good`, however
well the keypoints agree with it.

Where the written pose is the edge alignment's, the silhouettes also arbitrate between it and the
keypoint pose it started from (`undoes_alignment`): an optimum much nearer the keypoint pose
says the alignment slid off along what the edges hardly constrain (the camera's depth), and the
keypoint pose is written instead; not where their optimum agrees with the aligned pose
anyway.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dream.coarse.away import AwayPixels, away_at_pose
from dream.coarse.calibration import MOTION_MASKS, search_masks
from dream.coarse.search import SearchOutcome, pose_iou, search
from dream.coarse.settings import SearchSettings
from dream.coarse.verdict import cues_agree
from dream.metrics import pose_errors
from dream.robot import Robot
from dream.sequence import Sequence

CROSSCHECK_STARTS = 4   # the given poses, as given and aimed at the robot's masks


@dataclass(frozen=True)
class Crosscheck:
    """The silhouettes' optimum near a written pose: the search's outcome, the IoU of the
    written pose's silhouettes (scored as the search scores its optimum), the distance (m,
    rad) from the written pose to the optimum, the masks' source and how many frames, the
    masks' pixels away from the robot at the optimum (`dream.coarse.away`), and the keypoint
    pose's IoU."""

    outcome: SearchOutcome
    iou_written: float
    distance_m: float
    angle_rad: float
    source: str
    frames: int
    away: AwayPixels
    iou_keypoints: float

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
    held = inputs.source == MOTION_MASKS
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
    return Crosscheck(outcome, iou, float(m), float(rad), inputs.source, len(inputs.frames),
                      away, iou_keypoints)


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
