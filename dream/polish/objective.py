"""The silhouette objective: signed distances to the observed outline at the model's contour.

A one-sided, signed chamfer distance with continuous model points. For the current pose, render
each search frame's silhouette and keep the mesh vertices that project within `contour_band_px`
of its outline: they are the model's contour points (`select_contour`), 3D points that move
continuously with the pose (a rendered outline moves in whole pixels). Each contour point i of
frame f gives the residual
    r_i = D_f(project(T P_i)) - s_i,
where D_f is the signed distance to the observed mask's outline (pixels; negative inside;
bilinear in the distance transform of the mask, so smooth in the pose: `signed_distance`) and
s_i the same signed distance measured in the rendered silhouette where the point was selected.
s_i makes the residuals exactly zero when the rendered and observed silhouettes agree, so
points a little inside the outline do not pull it outwards. Points farther than
`max_residual_px` from agreement (parts the mask misses, mask noise) get no weight, the rest a
Huber weight (scale `huber_scale_px`). Occluders only remove robot pixels from the observed
mask, so at the true pose a contour point may lie outside it (r > 0, the robot hidden there)
but never inside: residuals r > 0 get no weight beyond the tighter `max_outside_residual_px`
(otherwise a distractor in front of the arm pulls the outline onto the visible part).
Observed outline that no model contour explains (cables, a gripper the URDF lacks) pulls
nothing: the distance is one-sided on purpose.

The search runs at a reduced resolution: masks shrunk to at most `search_width_px` pixels wide
(`shrink_mask`) and the camera scaled to match (`scaled_camera`).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.errors import InputError
from dream.optim.robust import huber_rho, huber_weight
from dream.pnp.reprojection import linearise, reprojected
from dream.polish.settings import PolishSettings
from dream.silhouette import render_points
from dream.threads import map_frames

EDGE_OFFSET_PX = 0.5        # a boundary pixel's centre lies half a pixel from the outline
COVERED_FRACTION = 0.5      # a shrunk mask's pixel is robot when this much of it was robot
SNAP_LIMIT_PX = 1024.0      # distances below this are snapped to the root of their integer square
NEAR_MARGIN_PX = 3          # `signed_distance_near` keeps this much beyond its band exact: a
#   bilinear read and the gradient beside it reach 2 px past a point


def scaled_camera(camera: CameraIntrinsics, width: int, height: int) -> CameraIntrinsics:
    """The same camera seen at another image size (pixel centres kept at integers)."""
    sx, sy = width / camera.width, height / camera.height
    return CameraIntrinsics(camera.fx * sx, camera.fy * sy, (camera.cx + EDGE_OFFSET_PX) * sx
                            - EDGE_OFFSET_PX, (camera.cy + EDGE_OFFSET_PX) * sy - EDGE_OFFSET_PX,
                            width, height, camera.distortion)


def shrink_mask(mask: np.ndarray, width: int, height: int) -> np.ndarray:
    """A bool mask resized by area averaging; robot where at least half a pixel is robot."""
    if mask.shape == (height, width):
        return mask
    area = cv2.resize(mask.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    return area >= COVERED_FRACTION


def signed_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) signed distance (pixels) of each pixel centre to the mask's outline, negative
    inside; +-0.5 on the boundary pixels, so zero half-way between them."""
    m = np.asarray(mask, dtype=bool).astype(np.uint8)
    if m.ndim != 2 or m.size == 0:
        raise InputError(f"mask has shape {m.shape}, expected (H, W)")
    d_out, d_in = exact_distance(1 - m), exact_distance(m)
    return np.where(m > 0, EDGE_OFFSET_PX - d_in, d_out - EDGE_OFFSET_PX)


def signed_distance_near(mask: np.ndarray, band_px: float) -> np.ndarray:
    """`signed_distance` where a band of `band_px` around the outline reads it: exact within
    the mask's bounding box widened by the band and `NEAR_MARGIN_PX` (cut at the image), and
    that width outside, where the true value is larger still. The same contour points as the
    whole image's, at the cost of the box's (a small silhouette in a large image).

    >>> m = np.zeros((40, 60), bool); m[10:20, 20:30] = True
    >>> near = signed_distance_near(m, 2.0)
    >>> bool(np.array_equal(near[5:25, 15:35], signed_distance(m)[5:25, 15:35]))
    True
    """
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2 or not m.any():
        return signed_distance(m)
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    pad = int(np.ceil(band_px)) + NEAR_MARGIN_PX
    y0, y1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, m.shape[0])
    x0, x1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, m.shape[1])
    out = np.full(m.shape, float(pad))
    out[y0:y1, x0:x1] = signed_distance(m[y0:y1, x0:x1])
    return out


def exact_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float64 Euclidean distance of each pixel centre to the nearest zero pixel of
    `mask` (uint8): OpenCV's exact transform, whose float32 result lies within a rounding of
    the square root of a whole number of squared pixels, and not always the same rounding
    from call to call (on an 80x60 mask, 34 pixels flip by 4.8e-7 between calls), snapped to
    that root below `SNAP_LIMIT_PX` (where the rounding moves the square by less than 0.13),
    so that the same mask always gives the same distances.

    >>> exact_distance(np.array([[0, 1, 1, 1]], np.uint8)).tolist()
    [[0.0, 1.0, 2.0, 3.0]]
    """
    d = cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64)
    return np.where(d < SNAP_LIMIT_PX, np.sqrt(np.rint(d * d)), d)


def bilinear(images: np.ndarray, frame: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Values of images (F, H, W) at pixels uv (..., 2) of frames `frame` (...,), clamped to
    the image.

    >>> bilinear(np.arange(6.0).reshape(1, 2, 3), np.zeros(2, int), np.array([[0.5, 0.5],
    ...                                                                       [9.0, -1.0]]))
    array([2., 2.])
    """
    return sampled(images, bilinear_taps(images.shape, frame, uv))


class Taps(NamedTuple):
    """Where `bilinear` reads images of one shape: the flat index of each sample's top-left
    neighbour, the steps to its right and lower neighbours, and the fractions along x, y."""

    i00: np.ndarray
    step_x: np.ndarray
    step_y: np.ndarray
    ax: np.ndarray
    ay: np.ndarray


def bilinear_taps(shape: tuple[int, int, int], frame: np.ndarray, uv: np.ndarray) -> Taps:
    """The `Taps` of pixels uv (..., 2) of frames `frame` (...,) in images of `shape` (F, H,
    W), clamped to the image: computed once for several images of that shape."""
    _, H, W = shape
    x = np.clip(uv[..., 0], 0.0, W - 1.0)
    y = np.clip(uv[..., 1], 0.0, H - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(W - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(H - 2, 0))
    return Taps((frame * H + y0) * W + x0,
                np.minimum(x0 + 1, W - 1) - x0,          # 0 in an image one pixel wide
                (np.minimum(y0 + 1, H - 1) - y0) * W, x - x0, y - y0)


def sampled(images: np.ndarray, taps: Taps) -> np.ndarray:
    """`bilinear`'s values of images (F, H, W) at `taps` (gathered by flat index: half the
    time of images[f, y, x])."""
    flat = images.reshape(-1)
    i10 = taps.i00 + taps.step_y
    ax, ay = taps.ax, taps.ay
    return ((flat.take(taps.i00) * (1 - ax) + flat.take(taps.i00 + taps.step_x) * ax) * (1 - ay)
            + (flat.take(i10) * (1 - ax) + flat.take(i10 + taps.step_x) * ax) * ay)


def evenly_spaced(candidates: np.ndarray, n: int) -> np.ndarray:
    """At most n of `candidates`, evenly spaced along it (all of them when there are fewer)."""
    if len(candidates) <= n:
        return candidates
    return candidates[np.unique(np.round(np.linspace(0, len(candidates) - 1, n)).astype(int))]


@dataclass(frozen=True)
class Contour:
    """Contour points of one round: base-frame points, frame index, selection distance and
    (where known) the mesh vertex each point is."""

    P_base: np.ndarray   # (N, 3)
    frame: np.ndarray    # (N,)
    s: np.ndarray        # (N,)
    vertex: np.ndarray | None = None   # (N,)


def select_contour(P_frames: np.ndarray, faces: np.ndarray, T: np.ndarray,
                   camera: CameraIntrinsics, params: PolishSettings,
                   usable: np.ndarray | None = None,
                   silhouettes: np.ndarray | None = None) -> Contour:
    """The contour points at T: of each frame's mesh vertices P_frames (F, V, 3), those that
    project within `contour_band_px` of the silhouette rendered at T (at most
    `max_points_per_frame`, evenly spaced), with their signed distance there; `usable` (V,)
    or per frame (F, V) bool: only these vertices may be contour points (the whole mesh is
    still rendered);
    `silhouettes` (F, H, W): the frames' silhouettes at T where already rendered. The frames
    run in parallel (`dream.threads`)."""

    def frame_contour(f: int) -> tuple[np.ndarray, np.ndarray] | None:
        P = P_frames[f]
        rendered = render_points(P, faces, T, camera) if silhouettes is None else silhouettes[f]
        if not rendered.any():
            return None
        uv = project(camera, P @ T[:3, :3].T + T[:3, 3])
        ok = np.all(np.isfinite(uv), axis=1) & camera.in_image(uv)
        s = np.full(len(P), np.inf)
        s[ok] = bilinear(signed_distance_near(rendered, params.contour_band_px)[None],
                         np.zeros(int(ok.sum()), np.int64), uv[ok])
        near = np.abs(s) <= params.contour_band_px
        pick = np.flatnonzero(near if usable is None else
                              near & (usable if usable.ndim == 1 else usable[f]))
        pick = evenly_spaced(pick, params.max_points_per_frame)
        return pick, s[pick]

    points, frames, dists, vertices = [], [], [], []
    for f, found in enumerate(map_frames(frame_contour, range(len(P_frames)))):
        if found is None:
            continue
        pick, s = found
        points.append(P_frames[f][pick])
        frames.append(np.full(len(pick), f))
        dists.append(s)
        vertices.append(pick)
    if not points:
        return Contour(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0),
                       np.zeros(0, np.int64))
    return Contour(np.concatenate(points), np.concatenate(frames), np.concatenate(dists),
                   np.concatenate(vertices))


class Objective:
    """Huber cost of the contour residuals, truncated at `max_residual_px` below zero and at
    `max_outside_residual_px` above (module doc). `sdf`: (F, H, W) signed distances to the
    observed outlines (`signed_distance`)."""

    def __init__(self, sdf: np.ndarray, camera: CameraIntrinsics, params: PolishSettings):
        self.sdf = sdf
        self.grad_y, self.grad_x = np.gradient(sdf, axis=(1, 2))
        self.camera = camera
        self.k = params.huber_scale_px
        self.cut_inside = params.max_residual_px
        self.cut_outside = params.max_outside_residual_px

    def with_camera(self, camera: CameraIntrinsics) -> Objective:
        """The same objective seen through another camera of the same image size (the
        distance fields shared)."""
        if (camera.width, camera.height) != (self.camera.width, self.camera.height):
            raise InputError(f"a {camera.width}x{camera.height} camera for "
                             f"{self.camera.width}x{self.camera.height} distance fields")
        other = copy.copy(self)
        other.camera = camera
        return other

    def residuals(self, contour: Contour, T: np.ndarray, jacobian: bool
                  ) -> tuple[np.ndarray, np.ndarray | None] | None:
        if not jacobian:
            uv = reprojected(contour.P_base, self.camera, T)
            return None if uv is None else (bilinear(self.sdf, contour.frame, uv) - contour.s,
                                            None)
        lin = linearise(contour.P_base, np.zeros((len(contour.P_base), 2)), self.camera, T)
        if lin is None:
            return None
        uv, J_uv = lin
        taps = bilinear_taps(self.sdf.shape, contour.frame, uv)
        r = sampled(self.sdf, taps) - contour.s
        # the SDF's central differences, interpolated as the SDF is: smoother than the exact
        # derivative of the bilinear interpolant (piecewise constant), a few per cent from it
        # (tests); zero along an axis where `bilinear` clamps, as the residual is flat there
        _, H, W = self.sdf.shape
        inside = (uv >= 0.0) & (uv <= [W - 1.0, H - 1.0])
        g = np.stack([sampled(self.grad_x, taps), sampled(self.grad_y, taps)], axis=1) * inside
        return r, g[:, 0, None] * J_uv[:, 0] + g[:, 1, None] * J_uv[:, 1]

    def cut(self, r: np.ndarray) -> np.ndarray:
        """The truncation of each residual: the outside one where r > 0."""
        return np.where(r > 0, self.cut_outside, self.cut_inside)

    def rho(self, r: np.ndarray) -> np.ndarray:
        """Huber cost of each residual, constant beyond its cut."""
        return huber_rho(np.minimum(np.abs(r), self.cut(r)), self.k)

    def weight(self, r: np.ndarray) -> np.ndarray:
        """Huber IRLS weight of each residual, 0 beyond its cut."""
        return np.where(np.abs(r) > self.cut(r), 0.0, huber_weight(r, self.k))

    def cost(self, contour: Contour, T: np.ndarray) -> float:
        out = self.residuals(contour, T, jacobian=False)
        return float("inf") if out is None else float(np.sum(self.rho(out[0])))
