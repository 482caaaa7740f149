"""Image evidence in a diagnosis: does the robot's outline agree better with the photos after
each accepted effect?

The search judges effects by how well they predict held-out keypoint detections. A detector
that misplaces one link's keypoints on these photos can make an effect look significant that
the images themselves do not support. Where every frame has an image, the outline of the URDF
meshes (`dream.edges.score`) is scored against the image edges for the baseline and after each
accepted effect, on the same frames: per link and in all. An accepted effect after which the
outline agrees less (by more than `AGREEMENT_DROP`) is marked as supported by the keypoints
only; links whose outline disagrees with the images at the final model are named (their
visible shape differs from the URDF, or the images do not show them).

`add_image_evidence` and `add_attached_geometry` (`dream.diagnosis.attached`: what a link
carries that the URDF lacks) put both into diagnosis.json's document.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from dream.diagnosis.fit import FitResult
from dream.edges.background import frames_and_background
from dream.edges.calibration import moving_vertices, usable_vertices
from dream.edges.score import EdgeScore, edge_score
from dream.edges.search import scale_images
from dream.edges.settings import EdgeSettings
from dream.errors import InputError
from dream.extended import effective_joints, joint_offset_vector
from dream.polish.objective import evenly_spaced
from dream.robot.link_geometry import LinkGeometry
from dream.sequence import Sequence
from dream.silhouette import load_robot_meshes, vertices_in_base

log = logging.getLogger(__name__)

AGREEMENT_DROP = 0.01   # an outline agreement lower by more than this is a loss


def fit_joints(fit: FitResult) -> np.ndarray:
    """(F, J) the joints a fit's model puts at the image times (offsets included)."""
    problem = fit.model.problem
    ext = fit.model.extension(fit.x)
    q = effective_joints(problem.joints, problem.times_s, ext.time_offset_s, ext.held_readings,
                         problem.robot.joint_names)
    if ext.joint_offset_rad:
        q = q + joint_offset_vector(problem.robot, ext.joint_offset_rad)
    return q


def _score_to_dict(score: EdgeScore) -> dict[str, Any]:
    return {"agreement": score.agreement, "outline_points": score.points,
            "per_link": {a.link: a.agreement for a in score.links}}


def outline_evidence(sequence: Sequence, steps: list[tuple[str, FitResult]],
                     settings: EdgeSettings | None = None) -> dict[str, Any] | None:
    """diagnosis.json's `image_evidence` for the fits of `steps` ((label, fit): the baseline,
    then the model after each accepted effect); None where a frame has no image or the camera
    moved (one pose per step is scored)."""
    if not steps or any(f.image_path is None for f in sequence.frames):
        return None
    if any(fit.model.change_index is not None for _, fit in steps):
        return None
    settings = settings or EdgeSettings()
    problem = steps[0][1].model.problem
    camera = problem.camera
    meshes = load_robot_meshes(problem.robot, settings.max_triangles)
    chosen = evenly_spaced(np.arange(len(sequence)), settings.max_search_frames)
    gray, background = frames_and_background(sequence, chosen, settings, camera)
    usable, background, _ = moving_vertices(meshes, problem.joints,
                                            usable_vertices(meshes, ()), background, settings)
    images = scale_images(gray, camera, camera.width, settings, background)
    scored = []
    for label, fit in steps:
        P = vertices_in_base(meshes, fit_joints(fit)[chosen])
        scored.append((label, edge_score(meshes, P, fit.T_cam_base, images, settings, usable)))
    out: dict[str, Any] = {"frames": len(chosen),
                           "steps": [{"model": label, **_score_to_dict(s)}
                                     for label, s in scored],
                           "unsupported": [], "mismatched_links": list(
                               scored[-1][1].mismatched(settings))}
    for (_, before), (label, after) in zip(scored, scored[1:], strict=False):
        if after.agreement < before.agreement - AGREEMENT_DROP:
            out["unsupported"].append(label)
    log.info("outline agreement: %s", ", ".join(f"{label} {s.agreement:.1%}"
                                                for label, s in scored))
    return out


def add_image_evidence(doc: dict[str, Any], sequence: Sequence,
                       steps: list[tuple[str, FitResult]]) -> None:
    """`image_evidence` where the frames have images; an accepted effect after which the
    outline agrees less is marked and noted."""
    try:
        evidence = outline_evidence(sequence, steps)
    except InputError as exc:  # no edges near the outline: nothing to say from the images
        log.info("no image evidence: %s", exc)
        return
    if evidence is None:
        return
    doc["image_evidence"] = evidence
    agreement = {step["model"]: step["agreement"] for step in evidence["steps"]}
    for entry in doc["effects"]:
        if entry["name"] in agreement and entry["name"] in doc["verdict"]:
            entry["image_support"] = entry["name"] not in evidence["unsupported"]
    for name in evidence["unsupported"]:
        doc["notes"].append(f"{name}: the robot's outline agrees less with the images after it "
                            f"(outline agreement {agreement[name]:.1%}); only the keypoint "
                            "detections support it")


def add_attached_geometry(doc: dict[str, Any], sequence: Sequence,
                          fit: FitResult) -> LinkGeometry | None:
    """The `link_geometry` box found at the final `fit` by carving the images' unexplained
    motion (`dream.diagnosis.attached`), named in the verdict and described in
    `image_findings`; None where nothing is found, the frames lack images or the camera moved."""
    from dream.diagnosis.attached import find_attached_geometry

    if any(f.image_path is None for f in sequence.frames) or fit.model.change_index is not None:
        return None
    try:
        found = find_attached_geometry(sequence, fit.model.problem.robot, fit_joints(fit),
                                       fit.T_cam_base)
    except InputError as exc:  # too few frames, an arm that hardly moves: nothing to carve
        log.info("no attached geometry: %s", exc)
        return None
    if found is None:
        return None
    doc["verdict"].append("link_geometry")
    doc["image_findings"] = {"link_geometry": {found.geometry.link: found.to_dict()}}
    doc["notes"].append(found.note())
    return found.geometry
