"""The coarse search's result (`dream.coarse.calibration.coarse_start`) for what runs after it:
its 1-sigma, the spread of its finish over frame groups and links left out (jackknives) and of
its basin check's restarts around the winner (where they do not return, it is large and says
so), and a stand-in keypoint result at its pose for the image refinements and RESULT.json.
"""

from __future__ import annotations

import numpy as np

from dream.calibration import CalibrationResult, FrameSolution, Observations
from dream.coarse.distortion import DistortionEstimate
from dream.coarse.focal import FocalEstimate
from dream.coarse.principal import PrincipalEstimate
from dream.coarse.search import SearchOutcome, within
from dream.coarse.settings import SearchSettings
from dream.coarse.timing import LagEstimate
from dream.errors import InputError
from dream.pnp import NoSolution, PoseFit, increment_between
from dream.refined_uncertainty import MIN_GROUPS, jackknife_covariance
from dream.sequence import Sequence

RESOLUTION_FRACTION = 0.5   # of the basin check's return limits: its 1-sigma without a jackknife
JACKKNIFE_SHRINKAGE = 0.25  # of the search's jackknife covariance towards its diagonal (set
#   on rendered scenes: a winner 4.7 mm off lay at chi-square 62 under the raw sum, 4.7 here)


def search_covariance(outcome: SearchOutcome, settings: SearchSettings | None = None,
                      focal: FocalEstimate | None = None, timing: LagEstimate | None = None,
                      principal: PrincipalEstimate | None = None,
                      distortion: DistortionEstimate | None = None) -> np.ndarray:
    """(6, 6) the search's own 1-sigma (xi of `dream.pnp` at the winner): the jackknives of
    its finish over frame groups and over links (`SearchOutcome.frames_xi`, `links_xi`;
    `dream.refined_uncertainty.jackknife_covariance`; their sum shrunk towards its diagonal by
    `JACKKNIFE_SHRINKAGE`, since some 15 leave-out poses estimate the correlations of six
    axes poorly), plus the second moment about the winner of the basin check's restarts that
    returned to it (where none did, of those the masks cannot tell from it, `alike_ends`: then
    the pose is not resolved). Without a jackknife (too few frames and links),
    (`RESOLUTION_FRACTION` x the return limits)^2 stands in for it on the diagonal: a restart
    that ends within the outcome's `basin_return_m` / `basin_return_rad` counts as returned
    (`SearchSettings.basin_lengths`), so the check alone does not resolve the pose below
    that. The restarts that ended elsewhere are the verdict's basin finding, not spread of
    this pose. An adopted focal-length scale (`focal`) adds its own uncertainty
    (`FocalEstimate.pose_covariance`), and so does an adopted lag of the joint log
    (`LagEstimate.pose_covariance`), and a principal point the outlines ask for beyond the
    check's limits its move and the spread of the pose through it
    (`PrincipalEstimate.pose_covariance`), and an adopted radial distortion its own
    (`DistortionEstimate.pose_covariance`)."""
    settings = settings or SearchSettings()
    T_best = outcome.best.T_cam_base
    ends = outcome.basin_ends
    if not len(ends):
        raise InputError("the coarse search ran no basin check, so it has no 1-sigma",
                         fix="set basin_starts above 0")
    returned = [T for T in ends
                if within(T, T_best, outcome.basin_return_m, settings.basin_return_rad)]
    spread = returned or alike_ends(outcome, settings)
    xi = np.array([increment_between(T_best, T) for T in spread]).reshape(-1, 6)
    jackknives = [xis for xis in (outcome.frames_xi, outcome.links_xi) if len(xis) >= MIN_GROUPS]
    if jackknives:
        J = sum(jackknife_covariance(xis) for xis in jackknives)
        precision = (1 - JACKKNIFE_SHRINKAGE) * J + JACKKNIFE_SHRINKAGE * np.diag(np.diag(J))
    else:
        precision = np.diag((np.repeat([settings.basin_return_rad, outcome.basin_return_m], 3)
                             * RESOLUTION_FRACTION) ** 2)
    extras = [extra.pose_covariance for extra in (focal, timing, principal, distortion)
              if extra is not None]
    basin = xi.T @ xi / len(xi) if len(xi) else np.zeros((6, 6))
    return basin + precision + sum(extras, np.zeros((6, 6)))


def alike_ends(outcome: SearchOutcome, settings: SearchSettings) -> list[np.ndarray]:
    """The basin check's restarts whose ends the masks cannot tell from the winner: their
    IoU within `min_gap` of the winner's (all of them where they were not scored). One that
    ended where the masks fit clearly worse is a rival the winner beat, as the gap test reads
    rivals, not spread of its pose (on a rendered 7-frame Kinova scene the four restarts from
    a pose 4 mm off, IoU 0.79, ended 20-25 cm away by the first winner's basin, 0.51: a
    1-sigma of 444 mm for a pose the masks resolve)."""
    ends, ious = outcome.basin_ends, outcome.basin_ious
    if ious is None:
        return list(ends)
    return [T for T, iou in zip(ends, ious, strict=True)
            if not settings.fits_clearly_better(outcome.best.iou, iou)]


def stand_in_result(sequence: Sequence, T_cam_base: np.ndarray, covariance: np.ndarray
                    ) -> tuple[CalibrationResult, Observations]:
    """A keypoint-free "all" result at `T_cam_base` with `covariance`, and observations with
    no keypoints, for the image refinements and RESULT.json."""
    F = len(sequence)
    names = tuple(f.name for f in sequence.frames)
    obs = Observations(np.zeros((F, 0, 3)), np.zeros((F, 0, 2)), np.zeros((F, 0)), names, ())
    fit = PoseFit(np.asarray(T_cam_base, float), np.zeros((0, 2)), np.zeros(0, bool),
                  np.zeros(0), np.asarray(covariance, float), float("nan"), 0)
    frames = tuple(FrameSolution(name, NoSolution("no keypoints: the camera pose was found "
                                                  "from the robot's silhouettes"), 0)
                   for name in names)
    return CalibrationResult("all", fit, frames, np.zeros((F, 0, 2)), np.zeros((F, 0), bool)), \
        obs
