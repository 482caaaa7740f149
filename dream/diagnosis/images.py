"""Image evidence in a diagnosis: does the robot's outline agree better with the photos after
each accepted effect?

The search judges effects by how well they predict held-out keypoint detections. A detector
that misplaces one link's keypoints on these photos can make an effect look significant that
the images themselves do not support. Where every frame has an image, the outline of the URDF
meshes (`dream.edges.score`) is scored against the image edges of the same frames
(`OutlineJudge`), each fit at its own extrinsic and at that extrinsic aligned to those edges
(`dream.edges.refine`): an effect may move the keypoint fit's extrinsic off the arm, or draw
an arm that fits the photos less wherever the camera is (a time offset driven by detector
errors on the wrist does), and either contradicts it. During the search, an effect
significant on the keypoints is not accepted when the outline agrees less with it than
without it (by more than `AGREEMENT_DROP`), at the fits' own extrinsics or at their aligned
ones (`OutlineJudge.veto`). For the report, the baseline and the model after each accepted
effect are scored per link and in all; an accepted effect after which the outline agrees less
(after the refits that follow it) is marked as supported by the keypoints only; links whose
outline disagrees with the images at the final model (aligned) are named (their visible shape
differs from the URDF, or the images do not show them).

`add_image_evidence` and `add_attached_geometry` (`dream.diagnosis.attached`: what a link
carries that the URDF lacks) put both into diagnosis.json's document.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dream.calibration import Observations
from dream.camera import CameraIntrinsics
from dream.diagnosis.fit import FitResult, Problem
from dream.edges.background import frames_and_background
from dream.edges.calibration import moving_vertices, usable_vertices
from dream.edges.refine import align_edges
from dream.edges.score import EdgeScore, edge_score
from dream.edges.search import ScaleImages, scale_images
from dream.edges.settings import EdgeSettings
from dream.errors import InputError
from dream.extended import extended_camera, extended_robot, image_joints, interpolated_frames
from dream.extension import HeldReadings
from dream.polish.objective import evenly_spaced
from dream.readings import reading_updates, update_times
from dream.robot import Robot
from dream.robot.link_geometry import LinkGeometry
from dream.sequence import Sequence
from dream.silhouette import RobotMeshes, load_robot_meshes, vertices_in_base

log = logging.getLogger(__name__)

AGREEMENT_DROP = 0.01   # an outline agreement lower by more than this is a loss


def fit_joints(fit: FitResult) -> np.ndarray:
    """(F, J) the joints a fit's model puts at the image times (offsets included)."""
    problem = fit.model.problem
    return image_joints(problem.robot, problem.joints, problem.times_s,
                        fit.model.extension(fit.x))


def _score_to_dict(score: EdgeScore) -> dict[str, Any]:
    return {"agreement": score.agreement, "outline_points": score.points,
            "per_link": {a.link: a.agreement for a in score.links}}


@dataclass(frozen=True)
class OutlineJudge:
    """The URDF outline of a diagnosis's fits scored against the image edges of the same
    frames (`chosen`: grey images `gray` and, where the camera is fixed, their `background`),
    each fit at the extrinsic that best aligns its outline with those edges: built once per
    sequence by `outline_judge`."""

    meshes: RobotMeshes
    usable: np.ndarray
    images: ScaleImages
    chosen: np.ndarray
    settings: EdgeSettings
    gray: np.ndarray
    background: np.ndarray | None
    _scores: dict = field(default_factory=dict, compare=False, repr=False)

    def _drawn(self, fit: FitResult) -> tuple[RobotMeshes, np.ndarray, np.ndarray, ScaleImages]:
        """The fit's meshes (its link lengths), their (n, V, 3) vertices at its joints at the
        image times, its first frame's pose T, and the images seen through its camera. Each
        frame's vertices are moved so that T projects them as the frame's own pose does (a
        camera move gives two poses)."""
        ext = fit.model.extension(fit.x)
        meshes = dataclasses.replace(self.meshes, robot=extended_robot(fit.model.problem.robot,
                                                                       ext))
        P = vertices_in_base(meshes, fit_joints(fit)[self.chosen])           # (n, V, 3)
        poses = fit.model.poses(fit.x)[self.chosen]
        T = poses[0]
        A = np.linalg.inv(T) @ poses
        P = np.einsum("fij,fvj->fvi", A[:, :3, :3], P) + A[:, None, :3, 3]
        images = dataclasses.replace(self.images, camera=extended_camera(self.images.camera,
                                                                         ext))
        return meshes, P, T, images

    def score(self, fit: FitResult) -> EdgeScore:
        """The outline's agreement at the fit's model: its link lengths, its joints at the
        image times, its camera, and each frame's pose. Remembered per fit."""
        return self._remembered(fit, "own", self._own)

    def aligned_score(self, fit: FitResult) -> EdgeScore:
        """`score` at the better of the fit's extrinsic and that extrinsic aligned to the image
        edges (`dream.edges.refine.align_edges`, the fit's other parameters held): the
        agreement the fit's robot, joints and camera can reach with the photos. A keypoint fit
        can be centimetres off; an effect is judged by what it does to the outline, not by the
        extrinsic it comes with. Remembered per fit."""
        return self._remembered(fit, "aligned", self._aligned_best)

    def _remembered(self, fit: FitResult, kind: str, compute) -> EdgeScore:
        """`compute(fit)`, once per fit and kind (the search and the report ask again)."""
        cached = self._scores.get((id(fit), kind))
        if cached is None or cached[0] is not fit:
            cached = (fit, compute(fit))
            self._scores[(id(fit), kind)] = cached
        return cached[1]

    def _own(self, fit: FitResult) -> EdgeScore:
        meshes, P, T, images = self._drawn(fit)
        return edge_score(meshes, P, T, images, self.settings, self.usable)

    def _aligned_best(self, fit: FitResult) -> EdgeScore:
        before = self.score(fit)
        meshes, P, T, images = self._drawn(fit)
        T1, _ = align_edges(P, meshes.faces, self.gray, images.camera, T, self.settings,
                            self.background, self.usable, meshes.vertex_link)
        after = edge_score(meshes, P, T1, images, self.settings, self.usable)
        return after if after.agreement > before.agreement else before

    def veto(self, candidate: FitResult, current: FitResult) -> str | None:
        """Why the images contradict adding an effect (`candidate`, fitted on top of
        `current`), else None: the outline agrees less by more than `AGREEMENT_DROP` at the
        fits' own extrinsics (the extrinsic the effect brings is off the edges: a keypoint bias
        changes nothing else) or at their aligned ones (`aligned_score`: the arm the effect
        draws fits the photos less wherever the camera is)."""
        for how, score in (("", self.score), (" (each extrinsic aligned to the edges)",
                                              self.aligned_score)):
            before, after = score(current), score(candidate)
            if after.agreement < before.agreement - AGREEMENT_DROP:
                return (f"the images contradict it: the outline on the image edges "
                        f"{before.agreement:.1%} -> {after.agreement:.1%}{how}")
        return None


def outline_judge(sequence: Sequence, problem: Problem, settings: EdgeSettings | None = None,
                  known: np.ndarray | None = None) -> OutlineJudge | None:
    """The `OutlineJudge` of a sequence whose every frame has an image (None otherwise, or
    where the images show no edges near the outline), scoring frames evenly spaced among
    those whose joints are `known` ((F,) bool; default all: a held log's frames after its last
    update hold a stale reading, which no effect can make agree with the image)."""
    if any(f.image_path is None for f in sequence.frames):
        return None
    settings = settings or EdgeSettings()
    meshes = load_robot_meshes(problem.robot, settings.max_triangles)
    known = np.ones(len(sequence), bool) if known is None else np.asarray(known, bool)
    if known.shape != (len(sequence),) or not known.any():
        raise InputError(f"known must be ({len(sequence)},) bool with a True, got "
                         f"{known.shape}")
    chosen = evenly_spaced(np.flatnonzero(known), settings.max_search_frames)
    try:
        gray, background = frames_and_background(sequence, chosen, settings, problem.camera)
        usable, background, _ = moving_vertices(meshes, problem.joints,
                                                usable_vertices(meshes, ()), background,
                                                settings)
        # at the camera's own size, so that a fit's corrected camera replaces it (`score`)
        images = scale_images(gray, problem.camera, problem.camera.width, settings, background)
    except InputError as exc:  # no edges near the outline: nothing to say from the images
        log.info("no image evidence: %s", exc)
        return None
    return OutlineJudge(meshes, usable, images, chosen, settings, gray, background)


def outline_evidence(judge: OutlineJudge | None, steps: list[tuple[str, FitResult]]
                     ) -> dict[str, Any] | None:
    """diagnosis.json's `image_evidence` for the fits of `steps` ((label, fit): the baseline,
    then the model after each accepted effect); None without a judge."""
    if judge is None or not steps:
        return None
    scored = [(label, judge.aligned_score(fit)) for label, fit in steps]
    own = [judge.score(fit).agreement for _, fit in steps]
    out: dict[str, Any] = {"frames": len(judge.chosen),
                           "steps": [{"model": label, **_score_to_dict(s),
                                      "agreement_at_fit": at_fit}
                                     for (label, s), at_fit in zip(scored, own, strict=True)],
                           "unsupported": [], "mismatched_links": list(
                               scored[-1][1].mismatched(judge.settings))}
    for i in range(1, len(steps)):
        if (scored[i][1].agreement < scored[i - 1][1].agreement - AGREEMENT_DROP
                or own[i] < own[i - 1] - AGREEMENT_DROP):
            out["unsupported"].append(steps[i][0])
    log.info("outline agreement, each extrinsic aligned to the edges: %s",
             ", ".join(f"{label} {s.agreement:.1%}" for label, s in scored))
    return out


def add_image_evidence(doc: dict[str, Any], judge: OutlineJudge | None,
                       steps: list[tuple[str, FitResult]]) -> None:
    """`image_evidence` where the frames have images (`judge`); an accepted effect after which
    the outline agrees less is marked and noted."""
    evidence = outline_evidence(judge, steps)
    if evidence is None:
        return
    doc["image_evidence"] = evidence
    agreement = {step["model"]: step["agreement"] for step in evidence["steps"]}
    for entry in doc["effects"]:
        if entry["name"] in agreement and entry["name"] in doc["verdict"]:
            entry["image_support"] = entry["name"] not in evidence["unsupported"]
    for name in evidence["unsupported"]:
        support = ("the log's runs of identical readings show it, but the images may not be "
                   "timed as the log says" if name == "held_readings"
                   else "only the keypoint detections support it")
        doc["notes"].append(f"{name}: the robot's outline agrees less with the images after it "
                            f"(outline agreement {agreement[name]:.1%}); {support}")


def carving_view(sequence: Sequence, robot: Robot, joints: np.ndarray, camera: CameraIntrinsics,
                 T_cam_base: np.ndarray, guard: Observations | None
                 ) -> tuple[Sequence, np.ndarray, bool]:
    """What the carving looks from: the sequence at a fit's `joints` (image times) and
    `camera`, and the fit's extrinsic aligned with the image edges
    (`dream.edges.refine_with_edges`, guarded by the detections `guard` at the fit's keypoints)
    where that alignment is kept: a keypoint fit can be centimetres off, and then the model's
    silhouette misses the arm it should explain. Returns (sequence, T_cam_base, aligned)."""
    from dream.edges import refine_with_edges
    from dream.pipeline import with_robot_joints

    seq = dataclasses.replace(with_robot_joints(sequence, robot, joints), camera=camera)
    try:
        aligned = refine_with_edges(seq, robot, T_cam_base, guard)
    except InputError as exc:   # no edges near the outline: carve from the fit's pose
        log.info("the carving looks from the fit's pose: %s", exc)
        return seq, T_cam_base, False
    return seq, aligned.T_after, aligned.kept


def add_attached_geometry(doc: dict[str, Any], sequence: Sequence, fit: FitResult,
                          obs: Observations | None = None, held: HeldReadings | None = None
                          ) -> LinkGeometry | None:
    """The `link_geometry` box found at the final `fit` (its link lengths, joints at the image
    times and camera) by carving the images' unexplained motion (`dream.diagnosis.attached`)
    from `carving_view`, named in the verdict and described in `image_findings`. With `held`
    readings (the fit's joints interpolated from the sequence's logged ones), the frames
    nearest the log's updates are carved (`carving_frames`). What the carving kept,
    found or not, goes to `attached_search`, and a note says why nothing was named. None
    where nothing is found, the frames lack images or the camera moved."""
    from dream.diagnosis.attached import AttachedSettings, find_attached_geometry

    if any(f.image_path is None for f in sequence.frames) or fit.model.change_index is not None:
        return None
    problem, ext = fit.model.problem, fit.model.extension(fit.x)
    robot, joints = extended_robot(problem.robot, ext), fit_joints(fit)
    guard = None if obs is None else dataclasses.replace(obs, P_base=fit.model.points(fit.x))
    try:
        seq, T_cam_base, aligned = carving_view(sequence, robot, joints,
                                                extended_camera(problem.camera, ext),
                                                fit.T_cam_base, guard)
        settings = AttachedSettings()
        outcome = find_attached_geometry(seq, robot, joints, T_cam_base, settings, carving_frames(
            sequence.joints, problem.times_s, ext.time_offset_s, held, robot.joint_names,
            settings.frames))
    except InputError as exc:  # too few frames, an arm that hardly moves: nothing to carve
        doc["attached_search"] = {"named": None, "reason": str(exc)}
        doc["notes"].append(f"link_geometry: not looked for: {exc}")
        return None
    doc["attached_search"] = {**outcome.to_dict(), "carved_at": _carved_at(aligned)}
    doc["notes"].append(outcome.note())
    found = outcome.finding
    if found is None:
        log.info("%s", outcome.note())
        return None
    doc["verdict"].append("link_geometry")
    doc["image_findings"] = {"link_geometry": {found.geometry.link: {
        **found.to_dict(), "carved_at": _carved_at(aligned)}}}
    return found.geometry


def carving_frames(logged: np.ndarray, times_s: np.ndarray | None, time_offset_s: float | None,
                   held: HeldReadings | None, joint_names: tuple[str, ...], count: int
                   ) -> np.ndarray:
    """(F,) bool: the frames to carve (at least `count` where there are as many).

    The carving keeps a point that falls on the arm's motion in almost every frame, so it
    needs the joints right in each. Interpolated held readings are exact at the log's updates,
    least sure midway between them, and unknown past the last update
    (`interpolated_frames`). With `held` readings (`logged`: the readings as logged), the
    frames nearest each update come first, then the next nearest, and so on over the
    interpolated frames, until there are `count`; otherwise every frame."""
    usable = interpolated_frames(logged, times_s, time_offset_s, held, joint_names)
    if held is None or times_s is None:
        return usable
    t = np.asarray(times_s, dtype=float)
    updates = reading_updates(t, logged)
    if not updates.held:
        return usable
    shift = (time_offset_s or 0.0) + held.phase_s
    gap = np.abs(t[:, None] + shift - update_times(t, updates.update_index)[None, :])
    nearest, distance = gap.argmin(axis=1), gap.min(axis=1)
    candidates = np.flatnonzero(usable)
    order = candidates[np.lexsort((distance[candidates], nearest[candidates]))]
    first = np.r_[True, nearest[order][1:] != nearest[order][:-1]]
    rank = np.full(len(t), np.iinfo(int).max)
    rank[order] = np.arange(len(order)) - np.maximum.accumulate(
        np.where(first, np.arange(len(order)), 0))
    tiers = np.sort(rank[order])
    return rank <= tiers[min(count, len(tiers)) - 1] if len(tiers) else usable


def _carved_at(aligned: bool) -> str:
    return "edge-aligned pose" if aligned else "fit's pose"
