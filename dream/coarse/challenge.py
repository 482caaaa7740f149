"""Another cue's optimum as one more start of the search's finish (pure).

Without keypoints, `--refine auto` writes the masks' optimum and the edge alignment is its
cross-check. The edge alignment reaches the camera from much farther off than the silhouette
polish does: on rendered scenes where no hypothesis of the search lay in the truth's basin (a
close-up, a shell camera 20 cm and 15 deg off the nearest), the alignment started at the
search's wrong winner, 0.3-0.8 m off, ended within 2 mm of the truth. So its optimum competes
with the winner on the masks' own evidence: finished as the winner was (`finish_width_px`, every
frame, what the arm carries left out) it explains the masks better or it does not. Where it
does and its finish ended outside the basin check's return limits around the winner, the
search runs again from it, the winner and the rival (`dream.coarse.search.search`, its checks
included), and that outcome replaces the first where its winner lies outside them too; where
the two optima lie within those limits of each other, there is nothing to decide. These are
`SearchSettings.basin_return_m` / `basin_return_rad` as set, not scaled for a near camera as
the basin check's own count is (`SearchSettings.basin_lengths`): the challenge decides the pose
written, and its figures on the rendered scenes were measured with these.

Then the masks choose the pose written between the two optima: the IoU at poses evenly spaced
on the segment from the winner to the other cue's optimum (`between`). The polish's contour
points stop short of the masks' own optimum where something the model lacks (a held object)
lies next to the outline: on rendered scenes with a held object the IoU rose steadily from
the winner, 11-17 mm off, towards the truth, and the point of the segment with the highest
IoU lay 5-9 mm from it; where the winner was right the highest IoU stayed at or near it.

    >>> Challenge("the edge alignment", 0.42, 0.61, 0.35, 0.5, True, 0.0, 0.61,
    ...           np.eye(4)).to_dict()["won"]
    True
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.calibration import SearchMasks
from dream.coarse.scales import Scales, finish_scale
from dream.coarse.search import SearchOutcome, search, within
from dream.coarse.settings import SearchSettings
from dream.metrics import pose_errors
from dream.pnp import apply_increment, increment_between
from dream.silhouette import vertices_in_base

CHALLENGER = "challenger"   # the hypotheses' source name of the searched-again starts
SEGMENT_STEPS = 10          # the segment between the two optima is tried at 11 poses


@dataclass(frozen=True)
class Challenge:
    """What another cue's optimum did against the search's winner: the cue, the IoU of the
    winner and of the cue's optimum finished (both at the finish scale on every frame), how far
    the cue's optimum lay from the winner (m, rad) and whether it won; then where on the
    segment from the (new) winner to the cue's optimum the masks put the pose written
    (`share`: 0 at the winner, 1 at the cue's optimum), its IoU and the pose,
    `T_cam_base_between`; and the cue's optimum finished (`T_cam_base_finished`)."""

    source: str
    iou_winner: float
    iou_challenger: float
    distance_m: float
    angle_rad: float
    won: bool
    share: float
    iou_between: float
    T_cam_base_between: np.ndarray
    T_cam_base_finished: np.ndarray | None = None

    def masks_optimum(self, T_winner: np.ndarray, settings: SearchSettings | None = None
                      ) -> np.ndarray:
        """The masks' own optimum, whose distance from the other cue's is the cues'
        disagreement: the cue's optimum finished on them (`T_cam_base_finished`) where, though
        the search run again from it returned to the winner (`T_winner`), it explains every
        frame better by more than `settings.min_gap` (the search's frames and all frames
        disagree; on a rendered Unitree B1 with a Z1 arm: IoU 0.81 against 0.73, the winner
        42 mm from the pose written, that 4 mm from the truth); else the winner."""
        better = (settings or SearchSettings()).fits_clearly_better(self.iou_challenger,
                                                                    self.iou_winner)
        if self.won or not better or self.T_cam_base_finished is None:
            return T_winner
        return self.T_cam_base_finished

    def to_dict(self) -> dict:
        return {"source": self.source, "iou_winner": self.iou_winner,
                "iou_challenger": self.iou_challenger, "distance_m": self.distance_m,
                "angle_rad": self.angle_rad, "won": self.won,
                "share_towards_other": self.share, "iou_between": self.iou_between}


def challenged(camera: CameraIntrinsics, inputs: SearchMasks, outcome: SearchOutcome,
               T_other: np.ndarray, source: str, settings: SearchSettings | None = None,
               progress: Callable[[str], None] | None = None
               ) -> tuple[SearchOutcome, Challenge | None]:
    """The search's outcome after `T_other` (T_cam_base, the optimum of the cue `source`)
    challenged its winner (module doc): the new outcome where it won, else `outcome`; the
    challenge, None where `T_other` lies within the basin check's return limits of the winner.
    """
    settings = settings or SearchSettings()
    say = progress or (lambda line: None)
    T_best, T_other = outcome.best.T_cam_base, np.asarray(T_other, float)
    if within(T_other, T_best, settings.basin_return_m, settings.basin_return_rad):
        return outcome, None
    start = time.perf_counter()
    held = inputs.held
    finish = finish_scale(vertices_in_base(inputs.meshes, inputs.joints), inputs.meshes,
                          inputs.masks, camera, settings, held=held, region=inputs.region)
    T_finished = finish.refine(T_other)
    iou_best, iou_other = finish.iou(T_best), finish.iou(T_finished)
    m, rad = pose_errors(T_other, T_best)
    say(f"{source}'s optimum, {m * 100:.1f} cm and {np.rad2deg(rad):.1f} deg from the winner, "
        f"finished on the masks: IoU {iou_other:.3f} against the winner's {iou_best:.3f}")
    won = iou_other > iou_best and not within(T_finished, T_best, settings.basin_return_m,
                                              settings.basin_return_rad)
    if won:
        say("searching again from it, the winner and its rival")
        starts = [T_finished, T_best] + ([] if outcome.rival is None
                                         else [outcome.rival.T_cam_base])
        again = search(inputs.meshes, inputs.joints, inputs.masks, camera,
                       {CHALLENGER: np.stack(starts)}, settings, held=held, progress=progress,
                       search_frames=inputs.search, region=inputs.region)
        won = not within(again.best.T_cam_base, T_best, settings.basin_return_m,
                         settings.basin_return_rad)
        if won:
            outcome = replace(again, hypotheses={**outcome.hypotheses, **again.hypotheses},
                              seconds=outcome.seconds)
    share, T_between, iou_between = between(finish, outcome.best.T_cam_base, T_other)
    if share > 0:
        say(f"the masks put the pose {share:.0%} of the way from the winner to "
            f"{source}'s optimum (IoU {iou_between:.3f})")
    outcome = replace(outcome, seconds=outcome.seconds + time.perf_counter() - start)
    return outcome, Challenge(source, iou_best, iou_other, float(m), float(rad), won, share,
                              iou_between, T_between, T_finished)


def between(scales: Scales, T_a: np.ndarray, T_b: np.ndarray,
            steps: int = SEGMENT_STEPS) -> tuple[float, np.ndarray, float]:
    """The pose of highest IoU (`scales.iou`) among `steps` + 1 evenly spaced on the segment
    from `T_a` to `T_b` (increments of `dream.pnp`), the first of equals: its share of the way
    (0 at `T_a`), the pose and its IoU."""
    xi = increment_between(T_a, T_b)
    shares = np.linspace(0.0, 1.0, steps + 1)
    poses = [apply_increment(T_a, share * xi) for share in shares]
    ious = np.array([scales.iou(T) for T in poses])
    k = int(np.argmax(ious))
    return float(shares[k]), poses[k], float(ious[k])
