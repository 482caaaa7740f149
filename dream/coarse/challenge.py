"""Another cue's optimum as one more start of the search's finish (pure).

Without keypoints, `--refine auto` writes the masks' optimum and the edge alignment is its
cross-check. The edge alignment reaches the camera from much farther off than the silhouette
polish does: on rendered scenes where no hypothesis of the search lay in the truth's basin (a
close-up, a shell camera 20 cm and 15 deg off the nearest), the alignment started at the
search's wrong winner, 0.3-0.8 m off, ended within 2 mm of the truth. So its optimum competes
with the winner on the masks' own evidence: finished as the winner was (`finish_width_px`, every
frame, what the arm carries left out) it explains the masks better or it does not. Where it
does, the search runs again from it, the winner and the rival (`dream.coarse.search.search`,
its checks included) and that outcome replaces the first; where the two poses lie within the
basin check's return limits of each other, there is nothing to decide.

    >>> Challenge("the edge alignment", 0.42, 0.61, 0.35, 0.5, True).to_dict()["won"]
    True
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.calibration import MOTION_MASKS, SearchMasks
from dream.coarse.scales import Scales
from dream.coarse.search import SearchOutcome, search, within
from dream.coarse.settings import SearchSettings
from dream.metrics import pose_errors
from dream.silhouette import vertices_in_base

CHALLENGER = "challenger"   # the hypotheses' source name of the searched-again starts


@dataclass(frozen=True)
class Challenge:
    """What another cue's optimum did against the search's winner: the cue, the IoU of the
    winner and of the cue's optimum finished (both at the finish scale on every frame), how far
    the cue's optimum lay from the winner (m, rad) and whether it won."""

    source: str
    iou_winner: float
    iou_challenger: float
    distance_m: float
    angle_rad: float
    won: bool

    def to_dict(self) -> dict:
        return {"source": self.source, "iou_winner": self.iou_winner,
                "iou_challenger": self.iou_challenger, "distance_m": self.distance_m,
                "angle_rad": self.angle_rad, "won": self.won}


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
    held = inputs.source == MOTION_MASKS
    finish = Scales(vertices_in_base(inputs.meshes, inputs.joints), inputs.meshes, inputs.masks,
                    camera, replace(settings, local_widths_px=(settings.finish_width_px,)),
                    None, held, inputs.region)
    T_finished = finish.refine(T_other)
    iou_best, iou_other = finish.iou(T_best), finish.iou(T_finished)
    m, rad = pose_errors(T_other, T_best)
    say(f"{source}'s optimum, {m * 100:.1f} cm and {np.rad2deg(rad):.1f} deg from the winner, "
        f"finished on the masks: IoU {iou_other:.3f} against the winner's {iou_best:.3f}")
    won = iou_other > iou_best
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
    outcome = replace(outcome, seconds=outcome.seconds + time.perf_counter() - start)
    return outcome, Challenge(source, iou_best, iou_other, float(m), float(rad), won)
