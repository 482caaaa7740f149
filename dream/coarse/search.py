"""The coarse search: many camera hypotheses scored on the robot's masks, the best few refined,
one chosen, and how clearly the images chose it (pure).

1. Every hypothesis on a shell around the robot is aimed at the part of the robot it sees
   (`dream.coarse.hypotheses.aim_in_view`: where the image border cuts the robot, the masks
   centre on that part); one around a guess is scored as given and aimed at the whole robot
   (`aim`), and where the masks touch the image border (`touches_border`) aimed in view too.
   Each is scored by `splat_iou` at `coarse_width_px`.
2. The `local_starts` best, no two within `distinct_m` and `distinct_rad` of each other (a
   guess's hypotheses aimed in view apart: their `in_view_starts` best besides), are
   refined by the silhouette polish's Levenberg-Marquardt (`dream.polish.refine.refine_pose`)
   at each of `local_widths_px` but the finest in turn (a round that lowers the IoU at its
   scale by more than `round_iou_tolerance` is undone and ends that scale: the polish's
   contour points are chosen again each round, and something the model lacks, a held object
   as large as the hand, can drag them off the robot round after round); the `fine_starts`
   best of those (distinct again) at the finest too, and scored by the IoU of their rendered
   silhouettes there.
3. The highest IoU wins, refined at `finish_width_px` on every frame given (the hypotheses
   and the local refinement compare only `search_frames` of them; with a carried region,
   finished again without the frames that pull its pose far harder than the others:
   `dream.coarse.scales`). The verdict's evidence: the
   best rival's IoU (a refined candidate that, finished as the winner is, stays farther than
   `rival_m` or `rival_rad` from it; the gap says how much better the winner explains the
   images; a rival that explains them better wins instead), and the basin check:
   `basin_starts` refinements started `basin_m` and `basin_rad` from the winner in random
   directions, and how many return within `basin_return_m` and `basin_return_rad` (both
   lengths scaled down for a camera nearer the robot than `basin_reference_m`).
4. The winner's precision: its finish repeated from it with each of `jackknife_groups` groups
   of frames left out in turn (every G-th frame, `dream.refined_uncertainty.frame_groups`),
   and with each link in view left out in turn (at most `jackknife_link_groups` groups of
   neighbouring links on a robot of many); the increments to those poses are the
   jackknives of `dream.coarse.calibration`'s 1-sigma (not run where the winner's IoU is
   below `min_found_iou`: the robot was not found, and the basin check's spread says so).
   A mask error of one frame (a shadow) or of one link (a link the colour of the floor, a
   tool the model lacks) moves the leave-out poses; one that every frame and link shares
   does not.

`search` runs all four steps; `find_winner` stops after step 3 and `Winner.checked` runs step
4 (`dream.coarse.checks`), so a caller that searches again from the winner
(`dream.coarse.calibration.with_carried`) spends nothing on checks it would discard.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.carried import CarriedRegion
from dream.coarse.checks import Checks, basin_ends, jackknife
from dream.coarse.evidence import (
    points_of,
    splat_iou,
    surface_samples,
)
from dream.coarse.hypotheses import aim, aim_in_view, camera_distance
from dream.coarse.scales import Scales, finish_scale
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.metrics import pose_errors
from dream.polish.objective import scaled_camera, shrink_mask
from dream.silhouette import RobotMeshes, vertices_in_base

if TYPE_CHECKING:
    from dream.coarse.calibration import SearchMasks

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Candidate:
    """A refined hypothesis: its pose, where it came from, its coarse score and the mean IoU
    of its rendered silhouettes after the local refinement; once finished, the positions among
    the search's frames of those its finish left out (`Scales.refine_reporting`) and its
    `Scales.found_iou` at the finish's scale on every frame (`found_iou`; None: not
    finished)."""

    T_cam_base: np.ndarray
    source: str
    coarse_iou: float
    iou: float
    left_out_frames: tuple[int, ...] = ()
    found_iou: float | None = None


@dataclass(frozen=True)
class SearchOutcome:
    """The search's winner and its evidence (module doc).

    Attributes:
        best: the winner. rival: the best candidate away from it (None: none refined).
        candidates: every refined candidate, best first.
        hypotheses: how many were scored, by source.
        basin_returned, basin_starts: the basin check's restarts that returned, of how many.
        basin_ends: (basin_starts, 4, 4) where the restarts ended.
        frames_xi: (G, 6) the winner's finish with each frame group left out, as increments
            from the winner (`dream.pnp.increment_between`); (0, 6) where it did not run.
        links_xi: (L, 6) the same with each link in view (or group of neighbouring links,
            `jackknife_link_groups`) left out; jackknife_links: those links, a group's
            names joined by "+".
        seconds: wall time.
        basin_m, basin_return_m: how far the restarts started and within what they counted
            as returned (`SearchSettings.basin_lengths` at the winner's camera distance).
        basin_ious: (basin_starts,) the IoU where each restart ended, as the winner's `iou`
            is measured (None: not scored).
    """

    best: Candidate
    rival: Candidate | None
    candidates: tuple[Candidate, ...]
    hypotheses: dict[str, int]
    basin_returned: int
    basin_starts: int
    basin_ends: np.ndarray
    frames_xi: np.ndarray
    links_xi: np.ndarray
    jackknife_links: tuple[str, ...]
    seconds: float
    basin_m: float = SearchSettings.basin_m
    basin_return_m: float = SearchSettings.basin_return_m
    basin_ious: np.ndarray | None = None

    @property
    def gap(self) -> float:
        """How much higher the winner's IoU is than the best rival's (its IoU without one)."""
        return self.best.iou - (self.rival.iou if self.rival is not None else 0.0)


def distinct_best(T: np.ndarray, scores: np.ndarray, count: int, distinct_m: float,
                  distinct_rad: float, among: np.ndarray | None = None,
                  taken: list[int] | None = None) -> list[int]:
    """Indices of the `count` highest `scores` (of those `among` (N,) bool, default all),
    skipping any within `distinct_m` and `distinct_rad` of one already taken (greedy, best
    first; `taken`: indices taken before, not counted).

    >>> T = np.stack([np.eye(4)] * 3); T[2, 0, 3] = 1.0
    >>> distinct_best(T, np.array([0.9, 0.8, 0.5]), 2, 0.1, 0.1)
    [0, 2]
    >>> distinct_best(T, np.array([0.9, 0.8, 0.5]), 2, 0.1, 0.1, np.array([0, 1, 1], bool))
    [1, 2]
    >>> distinct_best(T, np.array([0.9, 0.8, 0.5]), 2, 0.1, 0.1, taken=[0])
    [2]
    """
    before = list(taken or [])
    out: list[int] = []
    order = np.argsort(-scores, kind="stable")
    for i in order if among is None else order[np.asarray(among, bool)[order]]:
        if len(out) == count:
            break
        if all(not within(T[i], T[j], distinct_m, distinct_rad) for j in before + out):
            out.append(int(i))
    return out


def within(T_a: np.ndarray, T_b: np.ndarray, limit_m: float, limit_rad: float) -> bool:
    """Whether two T_cam_base lie within `limit_m` (camera centres) and `limit_rad`."""
    m, rad = pose_errors(T_a, T_b)
    return bool(m <= limit_m and rad <= limit_rad)


def touches_border(masks: np.ndarray) -> bool:
    """Whether any of the masks (F, H, W) bool reaches the image's outermost rows or columns:
    the border may cut the robot.

    >>> masks = np.zeros((2, 4, 5), bool); masks[1, 1:3, 1:4] = True
    >>> touches_border(masks), touches_border(np.roll(masks, 1, axis=1))
    (False, True)
    """
    m = np.asarray(masks, bool)
    return bool(m[:, [0, -1], :].any() or m[:, :, [0, -1]].any())


def coarse_scores(points: np.ndarray, masks: np.ndarray, camera: CameraIntrinsics,
                  T: np.ndarray, batch: int, held: bool = False) -> np.ndarray:
    """(N,) `splat_iou` of hypotheses T (N, 4, 4), `batch` at a time."""
    return np.concatenate([splat_iou(points, masks, camera, T[i:i + batch], held)
                           for i in range(0, len(T), batch)]) if len(T) else np.zeros(0)


def search(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
           camera: CameraIntrinsics, hypotheses: dict[str, np.ndarray],
           settings: SearchSettings | None = None, usable: np.ndarray | None = None,
           aimed_only: tuple[str, ...] = (), held: bool = False,
           progress: Callable[[str], None] | None = None,
           search_frames: np.ndarray | None = None,
           region: CarriedRegion | None = None) -> SearchOutcome:
    """The camera pose whose robot silhouettes best explain `masks` (module doc): `find_winner`
    with the same arguments, then its checks (`Winner.checked`)."""
    return find_winner(meshes, joints, masks, camera, hypotheses, settings, usable, aimed_only,
                       held, progress, search_frames, region).checked()


@dataclass(frozen=True)
class Winner:
    """A search's winner before its checks (steps 1-3 of the module doc): the fields of
    `SearchOutcome` known by then, and `checked()` to run the basin check and the jackknife
    (step 4). Where the winner is searched again (without what it carries), its checks need
    not run."""

    best: Candidate
    rival: Candidate | None
    candidates: tuple[Candidate, ...]
    hypotheses: dict[str, int]
    seconds: float
    run_checks: Callable[[], Checks]

    def checked(self) -> SearchOutcome:
        """The whole outcome: the winner with its basin check and jackknife."""
        start = time.perf_counter()
        c = self.run_checks()
        return SearchOutcome(self.best, self.rival, self.candidates, self.hypotheses,
                             c.basin_returned, len(c.basin_ends), c.basin_ends, c.frames_xi,
                             c.links_xi, c.jackknife_links,
                             self.seconds + time.perf_counter() - start, c.basin_m,
                             c.basin_return_m, c.basin_ious)


def find_winner(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
                camera: CameraIntrinsics, hypotheses: dict[str, np.ndarray],
                settings: SearchSettings | None = None, usable: np.ndarray | None = None,
                aimed_only: tuple[str, ...] = (), held: bool = False,
                progress: Callable[[str], None] | None = None,
                search_frames: np.ndarray | None = None,
                region: CarriedRegion | None = None) -> Winner:
    """The search's winner and rival (steps 1-3 of the module doc), its checks still to run.

    Args:
        meshes: the robot's meshes (without links the masks do not show).
        joints: (F, J) the frames' joints in `meshes.robot`'s order.
        masks: (F, H, W) bool robot masks at `camera`'s size.
        hypotheses: source name -> (n, 4, 4) T_cam_base; each is scored as given and aimed at
            the robot (where the masks touch the image border, aimed at the part of it in
            view too); those of a source in `aimed_only` only aimed at the part in view.
        usable: (V,) bool, the vertices whose outline is matched (default all).
        held: the masks are motion masks, which miss what the robot covers in most frames
            (`dream.coarse.evidence.held_pixels`).
        progress: called with one line per stage.
        search_frames: positions of the frames the hypotheses and the local refinement
            compare (default all); the winner's finish and the basin check compare all.
        region: what the arm carries, in every frame: its pixels are not compared after the
            coarse score (`Scales`).
    Raises:
        InputError: shapes that disagree, no hypothesis, empty masks.
    """
    start = time.perf_counter()
    settings = settings or SearchSettings()
    say = progress or (lambda line: None)
    masks = np.asarray(masks, bool)
    q = np.asarray(joints, float)
    if masks.ndim != 3 or masks.shape != (len(q), camera.height, camera.width):
        raise InputError(f"masks have shape {masks.shape}, expected ({len(q)}, "
                         f"{camera.height}, {camera.width})")
    if not sum(len(T) for T in hypotheses.values()):
        raise InputError("the coarse search was given no camera hypothesis")
    rng = np.random.default_rng(settings.seed)
    P_all = vertices_in_base(meshes, q)
    sub = np.arange(len(q)) if search_frames is None else np.asarray(search_frames, int)
    if not len(sub) or sub.min() < 0 or sub.max() >= len(q):
        raise InputError(f"search_frames {sub.tolist()} do not index {len(q)} frames")
    P, masks_all, masks = P_all[sub], masks, masks[sub]
    width = min(settings.coarse_width_px, camera.width)
    height = max(1, int(round(camera.height * width / camera.width)))
    coarse_camera = scaled_camera(camera, width, height)
    coarse = np.stack([shrink_mask(m, width, height) for m in masks])
    if not coarse.any():
        raise InputError("every robot mask of the search is empty at the coarse scale",
                         fix="check the images show the robot moving")
    tri, weights = surface_samples(meshes, np.ones(len(meshes.vertices), bool)
                                   if usable is None else usable, settings.surface_points, rng)
    points = points_of(P, meshes.faces, tri, weights)
    f, v, u = np.nonzero(coarse)
    centre = points.reshape(-1, 3).mean(axis=0)
    T_all, sources, extra = _aimed(hypotheses, points, centre,
                                   np.array([u.mean(), v.mean()]), coarse_camera, aimed_only,
                                   touches_border(coarse))
    scores = coarse_scores(points, coarse, coarse_camera, T_all, settings.batch, held)
    say(f"scored {len(T_all)} camera hypotheses at {width} px (best coarse IoU "
        f"{scores.max():.3f})")
    scales = Scales(P, meshes, masks, camera, settings, usable, held,
                     None if region is None else region.frames(sub))
    candidates = _refined(scales, T_all, scores, sources, extra, settings)
    finish = _finish_scales(P_all, meshes, masks_all, camera, settings, usable, scales, region)

    def finished(T: np.ndarray) -> np.ndarray:
        return T if finish is None else finish.refine(T)

    def finished_candidate(c: Candidate) -> Candidate:
        if finish is None:
            return replace(c, iou=scales.iou(c.T_cam_base),
                           found_iou=scales.found_iou(c.T_cam_base))
        T, left_out = finish.refine_reporting(c.T_cam_base)
        return replace(c, T_cam_base=T, iou=scales.iou(T), found_iou=finish.found_iou(T),
                       left_out_frames=tuple(int(i) for i in left_out))

    candidates, best, rival = _winner_and_rival(candidates, finished_candidate, settings)
    say(f"refined the {len(candidates)} best distinct hypotheses: best IoU {best.iou:.3f}"
        f"{f', best rival {rival.iou:.3f}' if rival is not None else ''}")
    if best.left_out_frames:
        say(f"the winner's finish left out {len(best.left_out_frames)} of {len(q)} frames "
            "that pull its pose far harder than the others")
    counts = {name: sources.count(name) for name in hypotheses}

    def run_checks() -> Checks:
        start_m, return_m = settings.basin_lengths(camera_distance(best.T_cam_base, centre))
        ends = basin_ends(lambda T: finished(scales.refine(T)), best.T_cam_base, settings,
                           rng, start_m)
        returned = sum(within(T, best.T_cam_base, return_m, settings.basin_return_rad)
                       for T in ends)
        say(f"basin check: {returned} of {settings.basin_starts} restarts "
            f"{start_m * 100:.1f} cm / {np.rad2deg(settings.basin_rad):.0f} deg away "
            "returned")
        frames_xi, links_xi, links = jackknife(
            P_all, meshes, masks_all, camera, settings, usable, held, best.T_cam_base,
            region) if settings.robot_found(best.iou, best.found_iou) \
            else (np.zeros((0, 6)), np.zeros((0, 6)), ())
        if len(frames_xi) or len(links_xi):
            say(f"jackknife: the finish without each of {len(frames_xi)} frame groups and "
                f"{len(links_xi)} links")
        return Checks(ends, returned, frames_xi, links_xi, links, start_m, return_m,
                      np.array([scales.iou(T) for T in ends]))

    return Winner(best, rival, tuple(candidates), counts, time.perf_counter() - start,
                  run_checks)


def searched_again(camera: CameraIntrinsics, inputs: SearchMasks, winner: Winner,
                   T_start: np.ndarray, source: str, settings: SearchSettings,
                   progress: Callable[[str], None] | None = None) -> Winner:
    """The search again through `camera` from `T_start` and the winner's rival (as `source`),
    without `inputs.region`'s pixels, its checks still to run; its counts and time include the
    first winner's."""
    starts = [T_start] + ([] if winner.rival is None else [winner.rival.T_cam_base])
    searched = find_winner(inputs.meshes, inputs.joints, inputs.masks, camera,
                           {source: np.stack(starts)}, settings, held=inputs.held,
                           progress=progress, search_frames=inputs.search,
                           region=inputs.region)
    return replace(searched, hypotheses={**winner.hypotheses, **searched.hypotheses},
                   seconds=winner.seconds + searched.seconds)


def _winner_and_rival(candidates: list[Candidate], finished: Callable[[Candidate], Candidate],
                      settings: SearchSettings
                      ) -> tuple[list[Candidate], Candidate, Candidate | None]:
    """The candidates (best first) with the winner and its rival finished: the best candidate,
    and the best other one that, finished too, stays farther than `rival_m` or `rival_rad`
    from it (a candidate whose local refinement stopped short of the winner's optimum, its
    round check refusing a step, is no rival); a rival that explains the masks better once
    finished wins instead."""
    out = list(candidates)
    out[0] = best = finished(out[0])
    for i in range(1, len(out)):
        if within(out[i].T_cam_base, best.T_cam_base, settings.rival_m, settings.rival_rad):
            continue
        out[i] = rival = finished(out[i])
        if within(rival.T_cam_base, best.T_cam_base, settings.rival_m, settings.rival_rad):
            continue
        if rival.iou > best.iou:
            out[0], out[i] = rival, best
            return out, rival, best
        return out, best, rival
    return out, best, None


def pose_iou(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
             camera: CameraIntrinsics, T_cam_base: np.ndarray,
             settings: SearchSettings | None = None, held: bool = False,
             frames: np.ndarray | None = None) -> float:
    """The mean IoU of the robot's silhouettes at `T_cam_base` with `masks`, as the search
    scores its candidates and its winner: at the finest of `local_widths_px`, on `frames`
    (the search's `search_frames`; default all), so that it compares with their `iou`."""
    settings = settings or SearchSettings()
    sub = np.arange(len(joints)) if frames is None else np.asarray(frames, int)
    P = vertices_in_base(meshes, np.asarray(joints, float)[sub])
    finest = replace(settings, local_widths_px=settings.local_widths_px[-1:])  # the only one read
    scales = Scales(P, meshes, np.asarray(masks, bool)[sub], camera, finest, None, held)
    return scales.iou(np.asarray(T_cam_base, float))


def _finish_scales(P: np.ndarray, meshes: RobotMeshes, masks: np.ndarray,
                   camera: CameraIntrinsics, settings: SearchSettings,
                   usable: np.ndarray | None, scales: Scales,
                   region: CarriedRegion | None = None) -> Scales | None:
    """`finish_scale` on every frame; None where it is neither finer than the local scales'
    finest nor on more frames."""
    finish = finish_scale(P, meshes, masks, camera, settings, usable, scales.held, region)
    finer = finish.levels[-1][0].width > scales.levels[-1][0].width
    return finish if finer or len(P) > len(scales.P) else None


def _refined(scales: Scales, T_all: np.ndarray, scores: np.ndarray, sources: list[str],
             extra: np.ndarray, settings: SearchSettings) -> list[Candidate]:
    """The `local_starts` best distinct hypotheses but the extra ones aimed in view (`extra`
    (N,) bool) and the `in_view_starts` best distinct extra ones, each refined at every local
    scale but the finest; the `fine_starts` best of all (distinct again) at the finest too;
    best first."""
    first = []
    starts = distinct_best(T_all, scores, settings.local_starts, settings.distinct_m,
                           settings.distinct_rad, ~extra)
    starts += distinct_best(T_all, scores, settings.in_view_starts, settings.distinct_m,
                            settings.distinct_rad, extra, starts)
    for i in starts:
        T = scales.refine(T_all[i], slice(0, -1))
        first.append((T, i, scales.iou_at(T, max(len(scales.levels) - 2, 0))))
    T_first = np.array([T for T, _, _ in first])
    out = []
    for k in distinct_best(T_first, np.array([iou for _, _, iou in first]),
                           settings.fine_starts, settings.distinct_m, settings.distinct_rad):
        T, i, _ = first[k]
        T = scales.refine(T, slice(-1, None))
        out.append(Candidate(T, sources[i], float(scores[i]), scales.iou(T)))
    return sorted(out, key=lambda c: -c.iou)


def _aimed(hypotheses: dict[str, np.ndarray], points: np.ndarray, centre: np.ndarray,
           uv: np.ndarray, camera: CameraIntrinsics, aimed_only: tuple[str, ...],
           cut: bool) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Every hypothesis of a source in `aimed_only` aimed at the part of the robot in view
    (`aim_in_view` of the surface `points`: where the border cuts the robot, the images'
    pixels centre on that part); every other one aimed at the whole robot and as given, and
    where the masks touch the image border (`cut`) aimed in view too; (N,) bool: those last,
    the extra ones."""
    poses, sources, extra = [], [], []
    for name, T in hypotheses.items():
        T = np.asarray(T, float).reshape(-1, 4, 4)
        aimed = aim(T, centre, uv, camera)
        if name in aimed_only:
            variants = [(aim_in_view(aimed, points, centre, uv, camera), False)]
        else:
            variants = [(aimed, False), (T, False)]
            if cut:
                variants.append((aim_in_view(aimed, points, centre, uv, camera), True))
        for V, is_extra in variants:
            poses.append(V)
            sources += [name] * len(V)
            extra.append(np.full(len(V), is_extra))
    return np.concatenate(poses), sources, np.concatenate(extra)
