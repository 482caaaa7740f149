"""What the images say about a camera pose without keypoints: the robot's masks, and how well
the robot's surface, seen from a hypothesis, covers them (pure).

The masks are the data's own robot masks, or motion masks of a fixed camera (the pixels that
differ from the scene behind the arm, `dream.edges.motion`: what never moves is left out of
both the masks and the model). The coarse score of a hypothesis is the mean over the frames of
the IoU between the mask and the pixels hit by points sampled on the robot's surface
(`surface_samples`, area-weighted, the same points in every frame), at a few dozen pixels of
width: no rendering, thousands of hypotheses a second. Links cut by the image border cost the
hypothesis nothing (they fall outside the image and the mask); a tool or a held object the
model lacks, a second robot that moves, and shadows lower every hypothesis' IoU, not the
ranking of the right one.

    >>> from dream.camera import CameraIntrinsics
    >>> camera = CameraIntrinsics(20.0, 20.0, 3.5, 3.5, 8, 8)
    >>> points = np.array([[[0.0, 0.0, 1.0], [0.05, 0.0, 1.0]]])   # 1 frame, 2 points
    >>> masks = np.zeros((1, 8, 8), bool); masks[0, 4, 4] = masks[0, 4, 5] = True
    >>> T = np.eye(4); T[:3, 3] = [0.025, 0.025, 0.0]
    >>> far = T.copy(); far[0, 3] = 0.1
    >>> splat_iou(points, masks, camera, np.stack([far, T])).round(2).tolist()
    [0.0, 1.0]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.edges.background import MEDIAN_SHARE
from dream.errors import InputError
from dream.silhouette import MIN_DEPTH_M, RobotMeshes
from dream.transforms import camera_coordinates


@dataclass(frozen=True)
class Evidence:
    """The masks a search compares, at one scale.

    Attributes:
        camera: the camera at the masks' size. masks: (F, h, w) bool.
        source: "the data's masks" or "motion masks".
        frames: (F,) the frames' indices in the sequence.
    """

    camera: CameraIntrinsics
    masks: np.ndarray
    source: str
    frames: np.ndarray

    def __post_init__(self) -> None:
        masks = np.asarray(self.masks, bool)
        if masks.ndim != 3 or masks.shape[1:] != (self.camera.height, self.camera.width):
            raise InputError(f"masks have shape {masks.shape}, expected (F, "
                             f"{self.camera.height}, {self.camera.width})")
        if len(self.frames) != len(masks):
            raise InputError(f"{len(self.frames)} frame indices for {len(masks)} masks")
        object.__setattr__(self, "masks", masks)

    def centroid_uv(self) -> np.ndarray:
        """(2,) the mean pixel of every mask pixel of every frame.

        Raises:
            InputError: every mask is empty.
        """
        f, v, u = np.nonzero(self.masks)
        if not len(u):
            raise InputError("every robot mask of the search is empty: the images do not show "
                             "the robot moving", fix="check the images show the arm moving, "
                             "or give a camera guess and a model")
        return np.array([u.mean(), v.mean()])


def surface_samples(meshes: RobotMeshes, usable: np.ndarray, count: int,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`count` points on the surface of the triangles whose vertices are all `usable` (V,),
    area-weighted: (triangle indices (count,), barycentric weights (count, 3)).

    Raises:
        InputError: no usable triangle.
    """
    faces = meshes.faces[np.all(usable[meshes.faces], axis=1)]
    if not len(faces):
        raise InputError("no robot geometry is left to compare with the masks",
                         fix="leave out fewer links")
    v = meshes.vertices
    # link-frame vertices: a triangle's area is the same in every pose (one link per triangle)
    area = 0.5 * np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]],
                                         v[faces[:, 2]] - v[faces[:, 0]]), axis=1)
    chosen = rng.choice(len(faces), size=count, p=area / area.sum())
    a, b = rng.random(count), rng.random(count)
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    index = np.flatnonzero(np.all(usable[meshes.faces], axis=1))[chosen]
    return index, np.stack([1 - a - b, a, b], axis=1)


def points_of(P_frames: np.ndarray, faces: np.ndarray, triangles: np.ndarray,
              weights: np.ndarray) -> np.ndarray:
    """(F, S, 3) the surface samples (`surface_samples`) in each frame's pose, from the mesh
    vertices P_frames (F, V, 3) in the base frame."""
    corners = P_frames[:, faces[triangles]]                      # (F, S, 3, 3)
    return np.einsum("fsck,sc->fsk", corners, weights)


def held_pixels(rendered: np.ndarray) -> np.ndarray:
    """(..., h, w) the pixels a robot's silhouettes (..., F, h, w) cover in more than
    `MEDIAN_SHARE` of the frames: a per-pixel median background model holds them, so motion
    masks miss them (a shoulder turning in place, the links near the base).

    >>> held_pixels(np.array([[[1, 0]], [[1, 0]], [[0, 1]]], bool)).tolist()
    [[True, False]]
    """
    return np.asarray(rendered, bool).mean(axis=-3) > MEDIAN_SHARE


def pixel_hits(P_cam: np.ndarray, camera: CameraIntrinsics
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nearest pixel (u, v) of camera-frame points (..., 3) and whether it lies in
    `camera`'s image; points behind the camera (or nearer it than `MIN_DEPTH_M`) or outside
    get (0, 0) and False.

    >>> camera = CameraIntrinsics(10.0, 10.0, 1.5, 1.5, 4, 4)
    >>> [a.tolist() for a in pixel_hits(np.array([[0.1, 0.0, 1.0], [0.0, 0.0, -1.0]]), camera)]
    [[2, 0], [2, 0], [True, False]]
    """
    P_cam = np.asarray(P_cam, dtype=float)
    uv = np.rint(project(camera, P_cam))
    return _hits(uv[..., 0], uv[..., 1], P_cam[..., 2], camera)


def _hits(u: np.ndarray, v: np.ndarray, z: np.ndarray, camera: CameraIntrinsics
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`pixel_hits` of rounded pixels u, v (...) of points at depth z (...)."""
    with np.errstate(invalid="ignore"):
        inside = (z >= MIN_DEPTH_M) & (u >= 0) & (u <= camera.width - 1) & (v >= 0) & (
            v <= camera.height - 1)
    return (np.where(inside, u, 0).astype(np.int64), np.where(inside, v, 0).astype(np.int64),
            inside)


def held_vertices(P_frames: np.ndarray, T_cam_base: np.ndarray, camera: CameraIntrinsics,
                  held: np.ndarray) -> np.ndarray:
    """(V,) the vertices P_frames (F, V, 3) that project into the `held` pixels (h, w) at
    `camera`'s size in more than `MEDIAN_SHARE` of the frames, seen from T_cam_base."""
    u, v, inside = pixel_hits(P_frames @ T_cam_base[:3, :3].T + T_cam_base[:3, 3], camera)
    return (inside & held[v, u]).mean(axis=0) > MEDIAN_SHARE


def region_vertices(P_frames: np.ndarray, T_cam_base: np.ndarray, camera: CameraIntrinsics,
                    region: np.ndarray) -> np.ndarray:
    """(F, V) whether each frame's vertex P_frames (F, V, 3) projects into that frame's
    `region` pixels (F, h, w) at `camera`'s size, seen from T_cam_base.

    >>> camera = CameraIntrinsics(10.0, 10.0, 1.5, 1.5, 4, 4)
    >>> region = np.zeros((2, 4, 4), bool); region[1, 1:3, 1:3] = True
    >>> region_vertices(np.zeros((2, 1, 3)) + [0.0, 0.0, 1.0], np.eye(4), camera,
    ...                 region).tolist()
    [[False], [True]]
    """
    u, v, inside = pixel_hits(P_frames @ T_cam_base[:3, :3].T + T_cam_base[:3, 3], camera)
    return inside & region[np.arange(len(region))[:, None], v, u]


def hypothesis_hits(points: np.ndarray, T: np.ndarray, camera: CameraIntrinsics
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`pixel_hits` of points (F, S, 3, base frame) seen from each hypothesis T (B, 4, 4):
    (B, F, S) each; the camera-frame coordinates one at a time (`camera_coordinates`, and
    without `project`'s stacking where the camera has no distortion)."""
    X, Y, Z = camera_coordinates(points, T)
    if camera.distortion is not None:
        return pixel_hits(np.stack([X, Y, Z], axis=-1), camera)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.rint(camera.fx * (X / Z) + camera.cx)
        v = np.rint(camera.fy * (Y / Z) + camera.cy)
    return _hits(u, v, Z, camera)


def splat_iou(points: np.ndarray, masks: np.ndarray, camera: CameraIntrinsics,
              T_cam_base: np.ndarray, held: bool = False) -> np.ndarray:
    """(B,) the mean over frames of the IoU between each mask (F, h, w) and the pixels its
    frame's surface points (F, S, 3, base frame) hit seen from each hypothesis (B, 4, 4);
    with `held` (motion masks) without the pixels hit in most frames (`held_pixels`)."""
    points = np.asarray(points, float)
    T = np.asarray(T_cam_base, float)
    masks = np.asarray(masks, bool)
    F, h, w = masks.shape
    if points.ndim != 3 or points.shape[0] != F or points.shape[2] != 3:
        raise InputError(f"points have shape {points.shape}, expected ({F}, S, 3)")
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise InputError(f"hypotheses have shape {T.shape}, expected (B, 4, 4)")
    B = len(T)
    u, v, ok = hypothesis_hits(points, T, camera)
    plane = (np.arange(B)[:, None, None] * F + np.arange(F)[None, :, None]) * (h * w)
    hit = np.zeros(B * F * h * w, bool)
    hit[(plane + v * w + u)[ok]] = True
    hit = hit.reshape(B, F, h * w)
    if held:
        hit &= ~held_pixels(hit[:, :, None, :])
    flat = masks.reshape(1, F, h * w)
    inter = np.count_nonzero(hit & flat, axis=2)
    union = np.count_nonzero(hit, axis=2) + np.count_nonzero(flat, axis=2) - inter
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0).mean(axis=1)
