"""The model's outline in an image and the image edges that face it.

Outline points: for a pose, each frame's robot silhouette is rendered (`dream.silhouette`) and
the mesh vertices that project within `contour_band_px` of its outline are kept, with the
outline's normal there (the gradient of the rendered silhouette's signed distance, pointing
out of the robot) and their signed distance s to the outline. They are 3D points that move
continuously with the pose, as the silhouette polish's contour points (`dream.polish`).

Edge search, in the spirit of model-based edge trackers (moving edges): from the outline point
o = uv - s n, the grey image's gradient is sampled at o + k n for k = -R..R pixels
(`search_range_px`); an edge is a local maximum of |g . n| at least `min_edge_strength` strong
whose gradient points within `max_edge_angle_rad` of the normal (either polarity: the robot may
be brighter or darker than what lies behind it). With a background model of a fixed camera
(`dream.edges.background`) an edge must also have the background just outside it and something
else just inside (`side_probe_px`, `motion_threshold`): the scene's own edges, the outline of a
held object and the edges inside the robot are passed over. The edge nearest the outline is
taken, placed to a sub-pixel by a parabola through its three samples: its offset d along n is
how far the image says the outline must move.

    >>> import numpy as np
    >>> gray = np.zeros((20, 20)); gray[:, 12:] = 1.0       # a vertical edge at x = 11.5
    >>> from dream.camera import CameraIntrinsics
    >>> camera = CameraIntrinsics(20.0, 20.0, 9.5, 9.5, 20, 20)
    >>> images = scale_images(gray[None], camera, 20, EdgeSettings())
    >>> d, found = match_edges(images, np.zeros(1, int), np.array([[9.0, 10.0]]),
    ...                        np.array([[1.0, 0.0]]), EdgeSettings())
    >>> bool(found[0]), round(float(d[0]), 2)
    (True, 2.5)
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.edges.settings import EdgeSettings
from dream.errors import InputError
from dream.polish.objective import (
    bilinear,
    evenly_spaced,
    scaled_camera,
    signed_distance_near,
)
from dream.silhouette import render_points
from dream.threads import map_frames

TINY_GRADIENT = 1e-12   # a normal is undefined where the distance field is flatter than this
SUBPIXEL_LIMIT = 0.5    # a parabola's vertex is kept within half a sample of its peak


def gradient_images(gray: np.ndarray, blur_sigma_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(gx, gy): the intensity gradient (per pixel) of a grey image (H, W) after a Gaussian
    blur of `blur_sigma_px`, by central differences."""
    g = np.asarray(gray, dtype=np.float32)
    if g.ndim != 2 or min(g.shape) < 2:
        raise InputError(f"grey image has shape {g.shape}, expected (H, W) with H, W >= 2")
    blurred = cv2.GaussianBlur(g, (0, 0), blur_sigma_px, borderType=cv2.BORDER_REPLICATE)
    gy, gx = np.gradient(blurred)
    return gx, gy


@dataclass(frozen=True)
class Outline:
    """Outline points of one round (`select_outline`), N of them.

    Attributes:
        P_base: (N, 3) the points in the base frame, m. frame: (N,) their frame index.
        vertex: (N,) their mesh vertex index. uv: (N, 2) where they project.
        normal: (N, 2) the outline's outward unit normal there.
        s: (N,) their signed distance to the rendered outline (px, negative inside).
    """

    P_base: np.ndarray
    frame: np.ndarray
    vertex: np.ndarray
    uv: np.ndarray
    normal: np.ndarray
    s: np.ndarray

    def subset(self, keep: np.ndarray) -> Outline:
        return Outline(self.P_base[keep], self.frame[keep], self.vertex[keep], self.uv[keep],
                       self.normal[keep], self.s[keep])


def _frame_outline(P: np.ndarray, faces: np.ndarray, T: np.ndarray, camera: CameraIntrinsics,
                   usable: np.ndarray | None, settings: EdgeSettings
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One frame's outline points: (vertex indices, uv, normals, s)."""
    rendered = render_points(P, faces, T, camera)
    empty = (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0))
    if not rendered.any():
        return empty
    sdf = signed_distance_near(rendered, settings.contour_band_px)[None]
    uv = project(camera, P @ T[:3, :3].T + T[:3, 3])
    margin = -(settings.search_range_px + 1.0)     # the border's outline is no image edge
    ok = np.all(np.isfinite(uv), axis=1) & camera.in_image(uv, margin)
    ok = np.flatnonzero(ok if usable is None else ok & usable)
    zeros = np.zeros(len(ok), np.int64)
    s = bilinear(sdf, zeros, uv[ok])
    ok, s = ok[np.abs(s) <= settings.contour_band_px], s[np.abs(s) <= settings.contour_band_px]
    gy, gx = np.gradient(sdf[0])
    g = np.stack([bilinear(gx[None], zeros[:len(ok)], uv[ok]),
                  bilinear(gy[None], zeros[:len(ok)], uv[ok])], axis=1)
    norm = np.linalg.norm(g, axis=1)
    good = norm > TINY_GRADIENT
    pick = evenly_spaced(np.flatnonzero(good), settings.max_points_per_frame)
    return ok[pick], uv[ok[pick]], g[pick] / norm[pick, None], s[pick]


def select_outline(P_frames: np.ndarray, faces: np.ndarray, T: np.ndarray,
                   camera: CameraIntrinsics, settings: EdgeSettings,
                   usable: np.ndarray | None = None) -> Outline:
    """The outline points at T of each frame's mesh vertices P_frames (F, V, 3) (module doc),
    at most `max_points_per_frame` per frame, away from the image border; only vertices
    `usable` (V,) bool when given (every triangle still hides what lies behind it)."""
    parts = map_frames(lambda P: _frame_outline(P, faces, T, camera, usable, settings), P_frames)
    vertex = np.concatenate([p[0] for p in parts])
    frame = np.concatenate([np.full(len(p[0]), f, np.int64) for f, p in enumerate(parts)])
    return Outline(P_base=P_frames[frame, vertex], frame=frame, vertex=vertex,
                   uv=np.concatenate([p[1] for p in parts]).reshape(-1, 2),
                   normal=np.concatenate([p[2] for p in parts]).reshape(-1, 2),
                   s=np.concatenate([p[3] for p in parts]))


@dataclass(frozen=True)
class ScaleImages:
    """The frames at one scale: the camera that sees them, their grey images (F, h, w) and
    gradients, and the background model (h, w) when there is one."""

    camera: CameraIntrinsics
    gray: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    background: np.ndarray | None = None


def scale_images(gray: np.ndarray, camera: CameraIntrinsics, width: int,
                 settings: EdgeSettings, background: np.ndarray | None = None) -> ScaleImages:
    """Grey frames (F, H, W) at `camera`'s size, and their background model (H, W) or None,
    shrunk to `width` (area averaging), with their gradients (`gradient_images`)."""
    width = min(int(width), camera.width)
    height = max(1, int(round(camera.height * width / camera.width)))

    def shrink(g: np.ndarray) -> np.ndarray:
        return g if g.shape == (height, width) else cv2.resize(
            g, (width, height), interpolation=cv2.INTER_AREA)

    small = np.stack([shrink(np.asarray(g, np.float32)) for g in gray])
    grads = [gradient_images(g, settings.blur_sigma_px) for g in small]
    return ScaleImages(scaled_camera(camera, width, height), small,
                       np.stack([g[0] for g in grads]), np.stack([g[1] for g in grads]),
                       None if background is None else shrink(np.asarray(background,
                                                                          np.float32)))


def _moving_sides(images: ScaleImages, frame: np.ndarray, pos: np.ndarray,
                  normal: np.ndarray, settings: EdgeSettings) -> np.ndarray:
    """(N, K) True where the sample pos (N, K, 2) has the background model just outside
    (along the normal) and something that differs from it just inside."""
    a = settings.side_probe_px * normal[:, None, :]
    zero = np.zeros(pos.shape[:2], np.int64)
    bg = images.background[None]

    def differs(p: np.ndarray) -> np.ndarray:
        return np.abs(bilinear(images.gray, frame, p) - bilinear(bg, zero, p))

    return (differs(pos + a) < settings.motion_threshold) & (
        differs(pos - a) >= settings.motion_threshold)


def match_edges(images: ScaleImages, frame: np.ndarray, origin: np.ndarray,
                normal: np.ndarray, settings: EdgeSettings) -> tuple[np.ndarray, np.ndarray]:
    """The nearest image edge along each normal (module doc).

    Args:
        images: the frames at the scale searched. frame: (N,) frame indices.
        origin: (N, 2) outline positions o. normal: (N, 2) outward unit normals.
    Returns:
        (d (N,) edge offsets along the normal in px, NaN where none; found (N,) bool).
    """
    R = settings.search_range_px
    k = np.arange(-np.ceil(R) - 1, np.ceil(R) + 2)                     # one sample beyond R
    pos = origin[:, None, :] + k[None, :, None] * normal[:, None, :]   # (N, K, 2)
    f = np.broadcast_to(frame[:, None], pos.shape[:2])
    H, W = images.gx.shape[1:]
    inside = (pos[..., 0] >= 0) & (pos[..., 0] <= W - 1) & (pos[..., 1] >= 0) & (
        pos[..., 1] <= H - 1)
    sx, sy = bilinear(images.gx, f, pos), bilinear(images.gy, f, pos)
    strength = np.where(inside, np.abs(sx * normal[:, None, 0] + sy * normal[:, None, 1]), 0.0)
    aligned = strength >= np.cos(settings.max_edge_angle_rad) * np.hypot(sx, sy)
    peak = np.zeros_like(aligned)
    peak[:, 1:-1] = ((strength[:, 1:-1] >= strength[:, :-2])
                     & (strength[:, 1:-1] > strength[:, 2:])
                     & (strength[:, 1:-1] >= settings.min_edge_strength) & aligned[:, 1:-1])
    peak &= np.abs(k)[None, :] <= R
    if images.background is not None:
        peak &= _moving_sides(images, f, pos, normal, settings)
    found = peak.any(axis=1)
    j = np.clip(np.argmin(np.where(peak, np.abs(k)[None, :], np.inf), axis=1), 1, len(k) - 2)
    rows = np.arange(len(origin))
    a, b, c = strength[rows, j - 1], strength[rows, j], strength[rows, j + 1]
    curvature = a - 2 * b + c
    concave = curvature < 0
    delta = np.where(concave, 0.5 * (a - c) / np.where(concave, curvature, -1.0), 0.0)
    d = np.where(found, k[j] + np.clip(delta, -SUBPIXEL_LIMIT, SUBPIXEL_LIMIT), np.nan)
    return d, found


def outline_edges(P_frames: np.ndarray, faces: np.ndarray, T: np.ndarray, images: ScaleImages,
                  settings: EdgeSettings, usable: np.ndarray | None = None
                  ) -> tuple[Outline, np.ndarray, np.ndarray]:
    """The outline points at T (`select_outline`, of the vertices `usable`) and, for each, the
    offset d of the edge facing it and whether one was found (`match_edges`)."""
    outline = select_outline(P_frames, faces, T, images.camera, settings, usable)
    origin = outline.uv - outline.s[:, None] * outline.normal
    d, found = match_edges(images, outline.frame, origin, outline.normal, settings)
    return outline, d, found
