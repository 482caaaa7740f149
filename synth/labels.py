"""Keypoint labels of a rendered frame: projections, in-frame and occlusion flags.

A keypoint is a link origin, which usually lies inside its own link's (or its neighbour's) mesh,
so a depth test alone would call every keypoint occluded. The rule here: cast a ray from the
camera centre to the keypoint; it is occluded by a distractor when the first thing the ray meets
is a distractor, and self-occluded when it is a robot link other than its own, its parent or its
child (rigid groups included) more than `SELF_OCCLUSION_MARGIN_M` in front of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.robot import Robot

SELF_OCCLUSION_MARGIN_M = 0.05   # a non-adjacent link must be this much nearer to occlude

VISIBLE, OUT_OF_FRAME, OCCLUDED_SELF, OCCLUDED_DISTRACTOR = (
    "visible", "out_of_frame", "self", "distractor")


@dataclass(frozen=True)
class KeypointLabels:
    """Labels of K keypoints in one frame.

    P_cam: (K, 3) camera frame, m. uv: (K, 2) pixels (distortion included), NaN when behind
    the camera. in_frame: (K,) inside the image. occlusion: K of VISIBLE, OUT_OF_FRAME,
    OCCLUDED_SELF, OCCLUDED_DISTRACTOR.
    """

    P_cam: np.ndarray
    uv: np.ndarray
    in_frame: np.ndarray
    occlusion: tuple[str, ...]


def rigid_group(robot: Robot, link: str) -> set[str]:
    """Links connected to `link` through fixed joints only."""
    tree = robot.tree
    group, frontier = {link}, [link]
    while frontier:
        node = frontier.pop()
        for j in tree.joints:
            if j.moves:
                continue
            for a, b in ((j.parent, j.child), (j.child, j.parent)):
                if a == node and b not in group:
                    group.add(b)
                    frontier.append(b)
    return group


def adjacent_links(robot: Robot, link: str) -> frozenset[str]:
    """The link's rigid group plus the rigid groups across its moving joints (parent, child)."""
    tree = robot.tree
    group = rigid_group(robot, link)
    out = set(group)
    for j in tree.joints:
        if j.moves and (j.child in group or j.parent in group):
            other = j.parent if j.child in group else j.child
            out |= rigid_group(robot, other)
    return frozenset(out)


def keypoint_labels(robot: Robot, P_cam: np.ndarray, camera: CameraIntrinsics,
                    hit_link: list[str | None] | None = None,
                    hit_distractor: np.ndarray | None = None,
                    hit_distance_m: np.ndarray | None = None,
                    margin_m: float = SELF_OCCLUSION_MARGIN_M) -> KeypointLabels:
    """Labels of keypoints at `P_cam` (K, 3), plus occlusion when ray casts are given.

    For each keypoint k, a ray from the camera centre towards it met first: `hit_link[k]` (the
    URDF link name of a robot geom, or None), `hit_distractor[k]` (bool) at `hit_distance_m[k]`
    (inf when nothing was hit).
    """
    P_cam = np.asarray(P_cam, dtype=float)
    uv = project(camera, P_cam)
    in_frame = camera.in_image(uv) & np.all(np.isfinite(uv), -1)
    distance = np.linalg.norm(P_cam, axis=-1)
    occlusion = []
    for k, name in enumerate(robot.keypoint_names):
        if not in_frame[k]:
            occlusion.append(OUT_OF_FRAME)
        elif hit_distance_m is None or not hit_distance_m[k] < distance[k]:
            occlusion.append(VISIBLE)
        elif hit_distractor is not None and hit_distractor[k]:
            occlusion.append(OCCLUDED_DISTRACTOR)
        elif hit_link is not None and hit_link[k] is not None and \
                hit_link[k] not in adjacent_links(robot, name) and \
                hit_distance_m[k] < distance[k] - margin_m:
            occlusion.append(OCCLUDED_SELF)
        else:
            occlusion.append(VISIBLE)
    return KeypointLabels(P_cam, uv, in_frame, tuple(occlusion))
