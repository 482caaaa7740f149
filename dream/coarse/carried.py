"""Something the arm carries that the URDF lacks, found at the search's winner and joined to the
model the search compares (pure).

A held object or a tool moves with the hand, so the motion masks hold it in every frame where
the hand moves, and a model without it explains those pixels with nothing: the silhouette
refinement's contour points near the hand pull the hand's outline towards the object's. On
rendered scenes with a held ball as large as the upper arm the search then lands 2-5 cm off.
The carving of `dream.diagnosis.attached` finds the object in the frame of the link that
carries it from the masks the search already has and the model's silhouettes at the winner:
grid points that fall on moving, unexplained pixels in most frames. On the rendered benchmark
scenes (at the true pose) it names something in 14 of 30 and nothing in the others; the 3
scenes whose search landed more than 1 cm off are among the 14, so what it names makes the
verdict `check` (`dream.coarse.verdict.carried_finding`). On request
(`SearchSettings.join_carried`) the convex hull of the carved voxels joins that link's
meshes and the search runs again from the winner and its rival with it
(`dream.coarse.calibration.with_carried`); a hull rather than the diagnosis's box, whose
corners overhang a round object. It is off by default: the visual hull is larger than the
object, and on the rendered scenes it pulled as many poses off as it brought back.

    >>> from dream.robot import load_robot
    >>> from dream.silhouette import load_robot_meshes
    >>> meshes = load_robot_meshes(load_robot("panda"))
    >>> cube = with_hull(meshes, "panda_hand", np.array([[0.0, 0.0, 0.1]]), 0.02)
    >>> len(cube.vertices) - len(meshes.vertices), len(cube.faces) - len(meshes.faces)
    (8, 12)
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
from scipy.spatial import ConvexHull

from dream.camera import CameraIntrinsics
from dream.diagnosis.attached import (
    AttachedSettings,
    CarvingOutcome,
    carve_masks,
    unexplained_pixels,
)
from dream.errors import InputError
from dream.silhouette import RobotMeshes

CUBE_CORNERS = np.array(list(itertools.product((-0.5, 0.5), repeat=3)))   # of a unit voxel


def carried_geometry(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
                     camera: CameraIntrinsics, T_cam_base: np.ndarray,
                     settings: AttachedSettings | None = None) -> CarvingOutcome:
    """What a moving link carries that `meshes` lack, carved from the motion masks `masks`
    (n, H, W) of the frames at `joints` (n, J) seen from `T_cam_base` (module doc).

    Raises:
        InputError: masks and joints of different lengths or sizes other than `camera`'s.
    """
    settings = settings or AttachedSettings()
    masks = np.asarray(masks, bool)
    q = np.asarray(joints, float)
    if masks.ndim != 3 or masks.shape != (len(q), camera.height, camera.width):
        raise InputError(f"masks have shape {masks.shape}, expected ({len(q)}, "
                         f"{camera.height}, {camera.width})")
    moving, unexplained, share = unexplained_pixels(meshes, q, masks, T_cam_base, camera,
                                                    settings)
    return carve_masks(meshes.robot, q, T_cam_base, camera, moving, unexplained, share,
                       settings)


def with_hull(meshes: RobotMeshes, link: str, points_link: np.ndarray, voxel_m: float
              ) -> RobotMeshes:
    """`meshes` with the convex hull of the voxels (side `voxel_m`) centred on `points_link`
    (N, 3, in `link`'s frame) joined to `link` (a link without meshes of its own joins them).

    Raises:
        InputError: no points, a link the robot lacks, a voxel that is not positive.
    """
    P = np.asarray(points_link, float)
    if P.ndim != 2 or P.shape[1] != 3 or not len(P):
        raise InputError(f"points_link must be (N, 3) with N >= 1, got {P.shape}")
    if not voxel_m > 0:
        raise InputError(f"voxel_m must be positive, got {voxel_m}")
    if link not in meshes.robot.link_names:
        raise InputError(f"the robot has no link {link!r}")
    corners = (P[:, None, :] + voxel_m * CUBE_CORNERS).reshape(-1, 3)
    hull = ConvexHull(corners)
    index = np.full(len(corners), -1)
    index[hull.vertices] = np.arange(len(hull.vertices))
    links = list(meshes.links)
    if link not in links:
        links.append(link)
    return dataclasses.replace(
        meshes, links=tuple(links),
        vertices=np.concatenate([meshes.vertices, corners[hull.vertices]]),
        vertex_link=np.concatenate([meshes.vertex_link,
                                    np.full(len(hull.vertices), links.index(link))]),
        faces=np.concatenate([meshes.faces, index[hull.simplices] + len(meshes.vertices)]))
