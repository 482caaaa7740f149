"""The 1-sigma of a pose that an image refinement wrote: its delete-one-group jackknives.

A kept image refinement (the silhouette polish, the edge alignment) replaces the keypoint
extrinsic, whose covariance then describes a pose that was not written. The refined pose's own
uncertainty is measured the way the keypoint jackknife measures the keypoint fit's
(`dream.calibration`): the refinement is repeated from its optimum with one group of its
evidence left out at a time, and the spread of those G solutions xi_k (increments from the
refined pose, `dream.pnp.increment_between`) is the covariance
(G - 1) / G * sum_k (xi_k - mean)(xi_k - mean)^T. Two kinds of groups, their covariances added:
- links: each link's outline left out in turn. A link whose outline pulls the pose away from
  the rest (a gripper the URDF lacks, a mask that misses a link, a wrong link length) widens
  it. Links that do not shape the refinement (hidden, out of view) are not groups.
- frames (many frames of a fixed camera): every `FRAME_GROUPS`-th frame left out in turn.
  Frames whose readings or images disagree (a lagging joint log, a bumped camera) widen it.
What every link and frame share (wrong intrinsics, a URDF that differs from the arm
everywhere) moves no leave-out solution, so no jackknife sees it.

RESULT.json: the pose fields' covariance (`covariance_xi`, the 1-sigma fields) become the
jackknife's, and `uncertainty` says so (`with_refined_uncertainty`); the keypoint fit's
covariance stays there as `covariance_xi_keypoint_pose`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass
from typing import Any

import numpy as np

from dream.errors import InputError
from dream.pnp import increment_between

log = logging.getLogger(__name__)

MIN_GROUPS = 3     # leave-out solutions below which no spread is estimated (as for keypoints)
FRAME_GROUPS = 5   # frame groups of the frames jackknife: every 5th frame, from each offset


@dataclass(frozen=True)
class RefinementJackknife:
    """The jackknife of a refined extrinsic (module doc): one kind of group, or the sum.

    Attributes:
        covariance: (6, 6) covariance of xi at the refined pose (rotation about, then
            translation along the camera axes).
        left_out: the groups whose leave-out solution entered it: link names, and
            "frames A, B, ..." for frame groups.
        refined_by: the refinement, in words ("the silhouette polish", "the edge alignment").
    """

    covariance: np.ndarray
    left_out: tuple[str, ...]
    refined_by: str

    def __post_init__(self) -> None:
        cov = np.array(self.covariance, dtype=float)
        if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
            raise InputError(f"a jackknife covariance must be a finite (6, 6) matrix, got "
                             f"shape {cov.shape}")
        if len(self.left_out) < MIN_GROUPS:
            raise InputError(f"a refinement jackknife needs at least {MIN_GROUPS} leave-out "
                             f"solutions, got {len(self.left_out)}")
        cov.setflags(write=False)
        object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "left_out", tuple(self.left_out))


def jackknife_spread(samples: np.ndarray) -> np.ndarray:
    """(n, n) delete-one-group jackknife covariance of G leave-out estimates (G, n) of any n
    quantities: (G - 1) / G * sum_k (x_k - mean)(x_k - mean)^T.

    >>> round(float(jackknife_spread(np.array([[0.0], [0.0], [0.0], [0.004]]))[0, 0]) ** 0.5, 4)
    0.003
    """
    samples = np.asarray(samples, dtype=float)
    if samples.ndim != 2 or len(samples) < 2:
        raise InputError(f"leave-out estimates have shape {samples.shape}, expected (G >= 2, n)")
    d = samples - samples.mean(axis=0)
    G = len(samples)
    return (G - 1) / G * (d.T @ d)


def jackknife_covariance(xis: np.ndarray) -> np.ndarray:
    """(6, 6) delete-one-group jackknife covariance of G leave-out increments xis (G, 6)
    (`jackknife_spread`).

    >>> xis = np.zeros((4, 6)); xis[0, 3] = 0.004
    >>> round(float(np.sqrt(jackknife_covariance(xis)[3, 3])), 4)
    0.003
    """
    xis = np.asarray(xis, dtype=float)
    if xis.ndim != 2 or xis.shape[1] != 6 or len(xis) < 2:
        raise InputError(f"leave-out increments have shape {xis.shape}, expected (G >= 2, 6)")
    return jackknife_spread(xis)


def group_jackknife(T_refined: np.ndarray, groups: SequenceOf[str],
                    refine_without: Callable[[str], np.ndarray | None],
                    refined_by: str) -> RefinementJackknife | None:
    """The jackknife of `T_refined` (4, 4) over `groups`: `refine_without(group)` repeats the
    refinement from `T_refined` without that group's evidence and returns its pose (None where
    it cannot). None when fewer than `MIN_GROUPS` solve."""
    xis, names = [], []
    for group in groups:
        T = refine_without(group)
        if T is None or not np.all(np.isfinite(T)):
            log.debug("%s without %s: no pose", refined_by, group)
            continue
        xis.append(increment_between(T_refined, T))
        names.append(group)
    if len(xis) < MIN_GROUPS:
        log.info("%s: %d leave-out solutions, too few for a spread", refined_by, len(xis))
        return None
    return RefinementJackknife(jackknife_covariance(np.array(xis)), tuple(names), refined_by)


def frame_groups(frames: int, groups: int = FRAME_GROUPS) -> dict[str, np.ndarray]:
    """The frame groups of a frames jackknife: every `groups`-th of `frames` frames from each
    offset, by name ("frames 0, 5, 10"); none for fewer than `MIN_GROUPS` frames.

    >>> list(frame_groups(7, 3))
    ['frames 0, 3, 6', 'frames 1, 4', 'frames 2, 5']
    """
    if frames < MIN_GROUPS:
        return {}
    out = {}
    for k in range(min(groups, frames)):
        members = np.arange(k, frames, min(groups, frames))
        out["frames " + ", ".join(str(i) for i in members)] = members
    return out


def combined(*jackknives: RefinementJackknife | None) -> RefinementJackknife | None:
    """The sum of the jackknives that could be estimated (None where none)."""
    done = [j for j in jackknives if j is not None]
    if not done:
        return None
    return RefinementJackknife(sum(j.covariance for j in done),
                               tuple(g for j in done for g in j.left_out), done[0].refined_by)


def links_with_points(vertex_link: np.ndarray, points_vertex: np.ndarray,
                      link_names: SequenceOf[str], min_points: int) -> tuple[str, ...]:
    """The links with at least `min_points` of the refinement's image points (vertex indices
    `points_vertex` into the meshes' `vertex_link`), in the meshes' order.

    >>> links_with_points(np.array([0, 0, 1, 2]), np.array([0, 1, 2, 2, 3]), ("a", "b", "c"), 2)
    ('a', 'b')
    """
    counts = np.bincount(np.asarray(vertex_link)[np.asarray(points_vertex, dtype=np.int64)],
                         minlength=len(link_names))
    return tuple(name for name, n in zip(link_names, counts, strict=True) if n >= min_points)


def set_covariance(doc: dict[str, Any], covariance: np.ndarray) -> None:
    """Set a RESULT.json document's `covariance_xi` and its 1-sigma fields (about the camera
    axes, and of the camera position in the base frame) for the pose it holds."""
    from dream.transforms import camera_position_covariance

    cov = np.asarray(covariance, dtype=float)
    T = np.asarray(doc["T_cam_base"], dtype=float)
    doc["covariance_xi"] = cov.tolist()
    doc["sigma_rotation_rad"] = np.sqrt(np.diag(cov)[:3]).tolist()
    doc["sigma_translation_m"] = np.sqrt(np.diag(cov)[3:]).tolist()
    doc["sigma_camera_position_base_m"] = np.sqrt(np.diag(
        camera_position_covariance(T, cov))).tolist()


def with_refined_uncertainty(doc: dict[str, Any],
                             jackknife: RefinementJackknife | None) -> None:
    """Set a RESULT.json document's covariance and 1-sigma fields to those of the refined pose
    it holds (`jackknife`), keeping the keypoint fit's as `covariance_xi_keypoint_pose`; with
    None (no jackknife estimable) `uncertainty.method` says that the 1-sigma is still the
    keypoint pose's."""
    uncertainty = dict(doc.get("uncertainty") or {})
    uncertainty.setdefault("covariance_xi_keypoint_pose", doc.get("covariance_xi"))
    if jackknife is None:
        uncertainty["method"] = (f"{uncertainty.get('method', 'fit')} of the keypoint pose (the "
                                 "refined pose had too few links and frames for its own)")
        doc["uncertainty"] = uncertainty
        return
    set_covariance(doc, jackknife.covariance)
    uncertainty["method"] = f"jackknife of {jackknife.refined_by}"
    uncertainty["refined_by"] = jackknife.refined_by
    uncertainty["jackknife_left_out"] = list(jackknife.left_out)
    doc["uncertainty"] = uncertainty


def with_cue_term(doc: dict, T_other: np.ndarray | None, T_own: np.ndarray | None = None
                  ) -> tuple[dict, tuple[float, float] | None]:
    """Where the other image cue's optimum `T_other` (the edge alignment's, or the masks'
    when the edges' was written) differs from the written cue's own optimum `T_own` (default
    the pose written; the masks' optimum where the pose written lies between the two), the
    covariance of the pose written gains the outer product of that difference (an error both
    frames and links share, which no jackknife sees); returns the document and the difference
    (m, rad), None without one."""
    from dream.metrics import pose_errors

    T = np.asarray(doc["T_cam_base"]) if T_own is None else np.asarray(T_own)
    if T_other is None or np.allclose(T, T_other):
        return doc, None
    delta = increment_between(T, np.asarray(T_other))
    set_covariance(doc, np.asarray(doc["covariance_xi"]) + np.outer(delta, delta))
    doc["uncertainty"]["cue_disagreement_xi"] = delta.tolist()
    doc["uncertainty"]["method"] += " + the image cues' disagreement"
    m, rad = pose_errors(T, T_other)
    return doc, (float(m), float(rad))
