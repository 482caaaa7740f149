"""Something the arm carries that the URDF lacks, found at the search's winner and left out of
what the search compares (pure).

A held object or a tool moves with the hand, so the motion masks hold it in every frame where
the hand moves, and a model without it explains those pixels with nothing: the silhouette
refinement's contour points near the hand pull the hand's outline towards the object's. On
rendered scenes with a held ball as large as the upper arm the search then lands 2-5 cm off.
The carving of `dream.diagnosis.attached` finds the object in the frame of the link that
carries it from the masks the search already has and the model's silhouettes at the winner:
grid points that fall on moving, unexplained pixels in most frames (`carried_geometry`; on the
rendered benchmark scenes, at the true pose, it names something in 14 of 30 and nothing in the
others). What it names makes the verdict `check` (`dream.coarse.verdict.carried_finding`), and
the search runs again from the winner and its rival without the pixels of the carved voxels'
convex hull in each frame (`CarriedRegion`; `dream.coarse.calibration.with_carried`). The
pixels are left out rather than the hull joined to the model: a visual hull is larger than the
object (thicker along the camera's line of sight), so a model with it pulls the hand's outline
as the object did.

    >>> from dream.robot import load_robot
    >>> robot = load_robot("panda")
    >>> region = carried_region(robot, np.zeros((2, robot.num_joints)), "panda_hand",
    ...                         np.array([[0.0, 0.0, 0.1]]), 0.02, margin_px=1)
    >>> region.P_frames.shape, region.faces.shape
    ((2, 8, 3), (12, 3))
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import cv2
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
from dream.robot import Robot
from dream.silhouette import RobotMeshes, render_frames

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


def voxel_hull(points_link: np.ndarray, voxel_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The convex hull of the voxels (side `voxel_m`) centred on `points_link` (N, 3): its
    vertices (V, 3) and triangles (T, 3).

    >>> vertices, faces = voxel_hull(np.zeros((1, 3)), 0.02)
    >>> vertices.shape, faces.shape, float(vertices.max())
    ((8, 3), (12, 3), 0.01)

    Raises:
        InputError: no points, a voxel that is not positive.
    """
    P = np.asarray(points_link, float)
    if P.ndim != 2 or P.shape[1] != 3 or not len(P):
        raise InputError(f"points_link must be (N, 3) with N >= 1, got {P.shape}")
    if not voxel_m > 0:
        raise InputError(f"voxel_m must be positive, got {voxel_m}")
    corners = (P[:, None, :] + voxel_m * CUBE_CORNERS).reshape(-1, 3)
    hull = ConvexHull(corners)
    index = np.full(len(corners), -1)
    index[hull.vertices] = np.arange(len(hull.vertices))
    return corners[hull.vertices], index[hull.simplices]


@dataclass(frozen=True)
class CarriedRegion:
    """Where the carried object lies in each frame's image: its carved hull in each frame's
    pose, `P_frames` (F, V, 3) in the base frame with triangles `faces` (T, 3), rendered from a
    camera pose and widened by `margin_px` pixels of the scale rendered at (`pixels`). The
    search leaves these pixels out of the IoU it scores and takes no contour point there
    (`dream.coarse.search`): the masks show the object, which the model lacks, and its hull
    is a visual hull, larger than the object, so it is neither matched nor joined to the
    model.

    Raises:
        InputError: vertices that are not (F, V, 3), a negative margin.
    """

    P_frames: np.ndarray
    faces: np.ndarray
    margin_px: int

    def __post_init__(self) -> None:
        P = np.asarray(self.P_frames, float)
        if P.ndim != 3 or P.shape[2] != 3:
            raise InputError(f"P_frames has shape {P.shape}, expected (F, V, 3)")
        if self.margin_px < 0:
            raise InputError(f"margin_px must not be negative, got {self.margin_px}")
        object.__setattr__(self, "P_frames", P)

    def frames(self, index: np.ndarray) -> CarriedRegion:
        """The region of the frames `index` only."""
        return replace(self, P_frames=self.P_frames[np.asarray(index, int)])

    def pixels(self, T_cam_base: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
        """(F, H, W) bool at `camera`'s size: the hull seen from `T_cam_base`, widened."""
        rendered = render_frames(self.P_frames, self.faces, T_cam_base, camera)
        if not self.margin_px:
            return rendered
        side = 2 * self.margin_px + 1
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))
        return np.stack([cv2.dilate(r.astype(np.uint8), kernel) > 0 for r in rendered])


def carried_region(robot: Robot, joints: np.ndarray, link: str, points_link: np.ndarray,
                   voxel_m: float, margin_px: int) -> CarriedRegion:
    """The `CarriedRegion` of the voxels (side `voxel_m`) centred on `points_link` (N, 3, in
    `link`'s frame) at the frames' joints (F, J).

    Raises:
        InputError: a link the robot lacks, and `voxel_hull`'s.
    """
    if link not in robot.link_names:
        raise InputError(f"the robot has no link {link!r}")
    vertices, faces = voxel_hull(points_link, voxel_m)
    T_base_link = robot.link_poses(np.asarray(joints, float), [link])[:, 0]     # (F, 4, 4)
    P = np.einsum("fij,vj->fvi", T_base_link[:, :3, :3], vertices) + T_base_link[:, None, :3, 3]
    return CarriedRegion(P, faces, margin_px)
