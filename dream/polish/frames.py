"""Which frames of a fixed camera agree on its one extrinsic (the all-frames polish).

A frame whose joint readings do not match its image (a reading logged at another instant, a
file numbered wrongly) or whose mask shows something else than the robot pulls the common pose
towards a compromise that fits no frame well. Each frame f is measured at the common pose T:
    common_f = IoU_f(T),    own_f = IoU_f(T_f),
where T_f is f's silhouette optimum searched alone from T. The frame is left out when
- own_f < `min_frame_iou`: not even a pose of its own makes the robot at its readings look
  like its mask ("no pose fits");
- own_f - common_f > `max_frame_iou_loss`: alone it prefers another pose ("prefers another
  pose");
- common_f < median(common over the frames kept) - `max_frame_iou_drop`: it fits the common
  pose much worse than the others ("fits worse than the others").
A frame's own optimum is searched once, from the pose of all frames. The frames no pose fits
go first, together: they pull the common pose at which the others are measured. Then, one at a
time, the frame that breaks a rule by most is left out and the common pose searched again on
the rest, from T (backward elimination), until every frame kept follows the rules or after
`frame_check_rounds` searches. Frames left out stay out. No frame is left out that would leave
fewer than `min_agreeing_frames` frames, or fewer than `min_agreeing_share` of them.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dream.polish.settings import PolishSettings

log = logging.getLogger(__name__)

NO_POSE_FITS = "no pose fits"
PREFERS_ANOTHER_POSE = "prefers another pose"
FITS_WORSE = "fits worse than the others"
EMPTY_MASK = "empty mask"


@dataclass(frozen=True)
class FrameAgreement:
    """The frames' agreement with the common pose (module doc).

    Attributes:
        used: (F,) bool, the frames the common pose was searched on and is scored on.
        iou_common: (F,) IoU of each frame at the common pose.
        iou_own: (F,) IoU of each frame at its own optimum (searched alone from it).
        reasons: F strings, "" for a frame used, else why it was left out.
        rounds: measurement rounds run.
    """

    used: np.ndarray
    iou_common: np.ndarray
    iou_own: np.ndarray
    reasons: tuple[str, ...]
    rounds: int

    @property
    def left_out(self) -> np.ndarray:
        """Indices of the frames left out."""
        return np.flatnonzero(~self.used)


def frame_violations(iou_common: np.ndarray, iou_own: np.ndarray, used: np.ndarray,
                     params: PolishSettings) -> tuple[list[str], np.ndarray]:
    """Why each frame breaks a rule ("" where it follows them all) and by how much (IoU; 0
    where it follows them), given its IoU at the common pose and at its own optimum; the
    median IoU of the frames `used` is the reference (pure).

    >>> p = PolishSettings()
    >>> reasons, by = frame_violations(np.array([0.95, 0.96, 0.60, 0.80]),
    ...                                np.array([0.96, 0.96, 0.62, 0.95]), np.ones(4, bool), p)
    >>> reasons, np.round(by, 2).tolist()
    (['', '', 'no pose fits', 'prefers another pose'], [0.0, 0.0, 0.12, 0.1])
    """
    reference = float(np.median(iou_common[used])) if used.any() else float(np.max(iou_common))
    reasons, by = [], np.zeros(len(iou_common))
    for i, (common, own) in enumerate(zip(iou_common, iou_own, strict=True)):
        rules = ((NO_POSE_FITS, params.min_frame_iou - own),
                 (PREFERS_ANOTHER_POSE, own - common - params.max_frame_iou_loss),
                 (FITS_WORSE, reference - params.max_frame_iou_drop - common))
        broken = [(excess, name) for name, excess in rules if excess > 0]
        reasons.append(broken[0][1] if broken else "")
        by[i] = max((excess for excess, _ in broken), default=0.0)
    return reasons, by


def agreeing_frames(T: np.ndarray, candidates: np.ndarray,
                    search: Callable[[np.ndarray, np.ndarray], np.ndarray],
                    search_alone: Callable[[int, np.ndarray], np.ndarray],
                    ious: Callable[[np.ndarray, np.ndarray], np.ndarray],
                    params: PolishSettings) -> tuple[np.ndarray, FrameAgreement]:
    """The common pose searched on the frames that agree with it (module doc).

    Args:
        T: (4, 4) the common pose searched on all frames.
        candidates: (F,) bool, frames that may be used (a non-empty mask).
        search: search(frame_indices, T_start) -> T, the silhouette optimum of those frames.
        search_alone: search_alone(frame_index, T_start) -> T, one frame's own optimum.
        ious: ious(frame_indices, T) -> their IoUs at T.
        params: the constants.
    Returns:
        (the common pose, the `FrameAgreement` measured at it).
    """
    idx = np.flatnonzero(candidates)
    own = np.zeros(len(candidates))
    own[idx] = [ious(np.array([i]), search_alone(int(i), T))[0] for i in idx]
    used = candidates.copy()
    left_because = ["" if c else EMPTY_MASK for c in candidates]
    rounds = 0
    while True:
        common = np.zeros(len(candidates))
        common[idx] = ious(idx, T)
        reasons, by = frame_violations(common, own, used, params)
        log.debug("frame agreement round %d: IoU %s, alone %s, %s", rounds,
                  np.round(common, 3), np.round(own, 3), reasons)
        no_fit = used & np.array([r == NO_POSE_FITS for r in reasons])
        drop = no_fit if no_fit.any() else used & (by > 0)
        if not drop.any() or rounds == params.frame_check_rounds:
            break
        if not no_fit.any():                                  # the worst one alone
            drop = np.arange(len(used)) == np.argmax(np.where(used, by, -np.inf))
        if (used & ~drop).sum() < max(params.min_agreeing_frames,
                                      params.min_agreeing_share * candidates.sum()):
            break
        for i in np.flatnonzero(drop):
            left_because[i] = reasons[i]
        used = used & ~drop
        T = search(np.flatnonzero(used), T)
        rounds += 1
    return T, FrameAgreement(used, common, own, tuple(
        "" if u else r for u, r in zip(used, left_because, strict=True)), rounds)
