"""From an OpenGL pinhole render to a camera's image: render frustum and pixel maps.

OpenGL renders square pixels through a frustum whose horizontal extent follows the viewport's
aspect ratio. A camera with fx = fy and no distortion is rendered directly, exactly, through an
off-centre frustum. Any other camera (fx != fy, plumb_bob distortion) is rendered as an ideal
pinhole with square pixels of focal length k * max(fx, fy) into a buffer that covers the
camera's whole field of view plus a margin, then resampled: each target pixel (u, v) looks up
the render pixel of its undistorted ray (bilinear for colours; nearest for ids and depth, from
a render oversampled k times per axis so that the lookup error stays below 0.5 / k px).

Pixel convention everywhere: the centre of the top-left pixel is (0, 0) (OpenCV); in OpenGL it
is (0.5, 0.5), so the frustum edges lie at pixel coordinates -0.5 and W - 0.5.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dream.camera import CameraIntrinsics, distort_normalized, undistort_normalized
from dream.errors import InputError

SQUARE_PIXEL_TOLERANCE_PX = 1e-3  # fx, fy closer than this across the image: render directly
UNDISTORT_TOLERANCE_PX = 1e-3  # largest allowed error of the inverted distortion map
PIXEL_EDGE = 0.5  # pixel centres are integers, edges half a pixel away


@dataclass(frozen=True, eq=False)
class RenderLens:
    """How to render a camera's image.

    Attributes:
        camera: the target camera.
        width, height: render buffer size, px.
        focal_px: render focal length (square pixels), px.
        cx, cy: render principal point, px (OpenCV convention).
        map_u, map_v: (H, W) float32 render-pixel coordinates of each target pixel, or None
            when the render is the target image (direct rendering).
        nearest_index: (H * W,) int64 flat index of the render pixel nearest to each target
            pixel (nearest-neighbour resampling of ids and depth), or None.
    """

    camera: CameraIntrinsics
    width: int
    height: int
    focal_px: float
    cx: float
    cy: float
    map_u: np.ndarray | None = field(default=None, repr=False)
    map_v: np.ndarray | None = field(default=None, repr=False)
    nearest_index: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0 or not (self.focal_px > 0):
            raise InputError(f"invalid render size {self.width}x{self.height} or focal length "
                             f"{self.focal_px}")
        if (self.map_u is None) != (self.map_v is None):
            raise InputError("give both pixel maps or neither")

    @property
    def direct(self) -> bool:
        """True when the render is the target image (no resampling)."""
        return self.map_u is None

    def frustum(self, near_m: float) -> tuple[float, float, float]:
        """(center, bottom, top) of the OpenGL frustum at distance `near_m` (MuJoCo's
        `mjvGLCamera` fields; left/right follow from the viewport's aspect ratio).

        OpenGL's camera looks along -z with y up; the image's top row is at +y.
        """
        left = (-PIXEL_EDGE - self.cx) / self.focal_px
        right = (self.width - PIXEL_EDGE - self.cx) / self.focal_px
        top = (PIXEL_EDGE + self.cy) / self.focal_px  # OpenCV y down -> GL y up
        bottom = -(self.height - PIXEL_EDGE - self.cy) / self.focal_px
        return 0.5 * (left + right) * near_m, bottom * near_m, top * near_m


def _is_square_pinhole(camera: CameraIntrinsics) -> bool:
    spread = abs(camera.fx - camera.fy) / camera.fx * max(camera.width, camera.height)
    return camera.distortion is None and spread < SQUARE_PIXEL_TOLERANCE_PX


def plan_lens(camera: CameraIntrinsics, margin_px: int = 2, max_render_scale: float = 2.0,
              oversampling: int = 1) -> RenderLens:
    """The render buffer, frustum and pixel maps that produce `camera`'s image exactly.

    Args:
        camera: target intrinsics (any fx, fy, principal point, plumb_bob distortion).
        margin_px: extra render pixels around the field of view (bilinear support).
        max_render_scale: refuse a render buffer larger than this times the image per axis
            (times `oversampling`).
        oversampling: render pixels per image pixel along each axis when resampling (finer
            nearest-neighbour lookups); ignored for direct rendering.
    Raises:
        InputError: the distortion is not invertible over the image (its map folds over) or
            needs a field of view larger than `max_render_scale` allows.
    """
    if isinstance(oversampling, bool) or int(oversampling) != oversampling or oversampling < 1:
        raise InputError(f"oversampling = {oversampling} must be a whole number >= 1")
    if _is_square_pinhole(camera):
        return RenderLens(camera, camera.width, camera.height, camera.fy, camera.cx, camera.cy)
    k = int(oversampling)
    focal = k * max(camera.fx, camera.fy)
    u, v = np.meshgrid(np.arange(camera.width, dtype=float),
                       np.arange(camera.height, dtype=float))
    xy_d = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy], -1)
    coeffs = None if camera.distortion is None else camera.dist_coeffs
    xy = undistort_normalized(xy_d, coeffs)
    if coeffs is not None:
        residual = distort_normalized(xy, coeffs) - xy_d
        error_px = np.nanmax(np.abs(residual) * [camera.fx, camera.fy]) if residual.size else 0
        if not np.all(np.isfinite(xy)) or not error_px < UNDISTORT_TOLERANCE_PX:
            raise InputError(f"the distortion {camera.distortion} cannot be inverted over the "
                             f"{camera.width}x{camera.height} image (error {error_px:.3g} px)",
                             fix="give plumb_bob coefficients that map the image one to one")
    xs, ys = focal * xy[..., 0], focal * xy[..., 1]
    # principal point = the camera's plus a whole number of pixels, so that an axis with
    # f = focal_px and no distortion maps pixel centres onto pixel centres
    cx = k * camera.cx + math.ceil(k * margin_px - xs.min() - k * camera.cx)
    cy = k * camera.cy + math.ceil(k * margin_px - ys.min() - k * camera.cy)
    width = math.ceil(xs.max() + cx + k * margin_px) + 1
    height = math.ceil(ys.max() + cy + k * margin_px) + 1
    if width > max_render_scale * k * camera.width or \
            height > max_render_scale * k * camera.height:
        raise InputError(f"rendering this camera needs a {width}x{height} buffer, more than "
                         f"{max_render_scale * k} times its {camera.width}x{camera.height} "
                         "image",
                         fix="use milder distortion or raise max_render_scale")
    map_u, map_v = xs + cx, ys + cy
    nearest = (np.floor(map_v + PIXEL_EDGE).astype(np.int64) * width
               + np.floor(map_u + PIXEL_EDGE).astype(np.int64)).reshape(-1)
    return RenderLens(camera, int(width), int(height), focal, float(cx), float(cy),
                      map_u.astype(np.float32), map_v.astype(np.float32), nearest)
