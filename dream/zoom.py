"""A second look at the robot: the network input cut from the keypoints' region of the image.

An arm that fills a small part of the image also fills a small part of the network input:
keypoints a few input pixels apart blur into each other in the belief maps. A zoomed pass cuts
the box around one pass's keypoints (widened by `margin` of its extent on every side, at most
`max_zoom` times the whole image's magnification) out of the image at the input's size and
runs the network again; its peaks map back to the image through the same `InputTransform` as
the whole image's.

The same map serves training (`train.data`, from the labels) and detection
(`dream.detection.detect_keypoints`, from the first pass's keypoints), so the network sees
what it is trained on.

    settings = ZoomSettings(margin=0.25, max_zoom=4.0)
    t = zoom_transform(preprocess, 640, 480, uv_found, settings)   # None: no gain
    x = cut_input(preprocess, image, t)        # (3, h, w) float32, as `Preprocess.apply`
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from dream.errors import InputError
from dream.preprocess import InputTransform, Preprocess

DEFAULT_MARGIN = 0.25     # of the keypoints' extent, on every side: the links around the joints
DEFAULT_MAX_ZOOM = 4.0    # times the whole image's magnification
MIN_KEYPOINTS = 2         # keypoints that span a box


@dataclass(frozen=True)
class ZoomSettings:
    """How a zoomed pass cuts its input.

    Attributes:
        margin: the box's widening on every side, as a fraction of the keypoints' extent.
        max_zoom: the most the box is magnified, relative to the whole image's input (> 1).
    """

    margin: float = DEFAULT_MARGIN
    max_zoom: float = DEFAULT_MAX_ZOOM

    def __post_init__(self) -> None:
        margin, zoom = float(self.margin), float(self.max_zoom)
        if not (np.isfinite(margin) and margin >= 0):
            raise InputError(f"zoom margin must be >= 0 (a fraction of the keypoints' extent), "
                             f"got {self.margin!r}")
        if not (np.isfinite(zoom) and zoom > 1):
            raise InputError(f"max zoom must be > 1 (times the whole image's magnification), "
                             f"got {self.max_zoom!r}")
        object.__setattr__(self, "margin", margin)
        object.__setattr__(self, "max_zoom", zoom)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> ZoomSettings:
        if not isinstance(doc, dict) or set(doc) - {"margin", "max_zoom"}:
            raise InputError(f"zoom settings must be an object with margin and max_zoom, got "
                             f"{doc!r}")
        return cls(**doc)


def zoom_transform(preprocess: Preprocess, image_width: int, image_height: int,
                   uv: np.ndarray, settings: ZoomSettings, margin: float | None = None,
                   shift: np.ndarray | None = None) -> InputTransform | None:
    """The image -> input map of the box around keypoints `uv` (K, 2), NaN rows ignored.

    Args:
        preprocess: the network's input size.
        image_width, image_height: the image's size, px.
        uv: (K, 2) image pixels of the keypoints that span the box.
        settings: margin and most magnification.
        margin: replaces `settings.margin` (training draws it at random).
        shift: (2,) moves the box's centre by this fraction of its size (training's jitter).

    Returns:
        The transform (uniform scale, the box's centre at the input's), or None where fewer
        than `MIN_KEYPOINTS` keypoints are given or the box magnifies no more than the whole
        image does.

    >>> pre = Preprocess(256, 192)
    >>> t = zoom_transform(pre, 640, 480, np.array([[100., 100.], [164., 148.]]), ZoomSettings(0.0))
    >>> round(t.scale_u / 0.4, 3), t.image_to_input(np.array([132., 124.])).round(1).tolist()
    (4.0, [127.5, 95.5])
    """
    uv = np.asarray(uv, dtype=float)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InputError(f"keypoints have shape {uv.shape}, expected (K, 2)")
    found = uv[np.isfinite(uv).all(axis=1)]
    if len(found) < MIN_KEYPOINTS:
        return None
    whole = preprocess.transform_for(image_width, image_height)
    base = min(whole.scale_u, whole.scale_v)
    lo, hi = found.min(axis=0), found.max(axis=0)
    widen = 1.0 + 2.0 * (settings.margin if margin is None else margin)
    size = np.maximum((hi - lo) * widen, np.finfo(float).eps)
    centre = (lo + hi) / 2.0 + (0.0 if shift is None else np.asarray(shift, float) * size)
    w, h = preprocess.input_width, preprocess.input_height
    scale = min(w / size[0], h / size[1], base * settings.max_zoom)
    if scale <= base:
        return None
    offset = np.array([w, h]) / 2.0 - (centre + 0.5) * scale
    return InputTransform(image_width, image_height, w, h, scale, scale, offset[0], offset[1])


def cut_input(preprocess: Preprocess, image_rgb: np.ndarray, transform: InputTransform
              ) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> the (3, h, w) float32 normalised network input of the cut
    `transform` (the letterbox padding's grey outside the image), as training and detection
    feed it."""
    return preprocess.normalize(warp_to_input(image_rgb, transform, preprocess.pad_value))


def warp_to_input(image: np.ndarray, transform: InputTransform, fill: float,
                  interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """An (H, W[, C]) image sampled on the input grid of `transform` (`fill` outside it).

    Pixel centres are integers in both spaces, as `InputTransform` assumes.
    """
    image = np.asarray(image)
    if image.shape[:2] != (transform.image_height, transform.image_width):
        raise InputError(f"image {image.shape[:2]} is not the transform's "
                         f"{transform.image_height}x{transform.image_width}")
    matrix = np.array([
        [transform.scale_u, 0.0, 0.5 * transform.scale_u - 0.5 + transform.offset_u],
        [0.0, transform.scale_v, 0.5 * transform.scale_v - 0.5 + transform.offset_v]])
    value = (fill,) * (image.shape[2] if image.ndim == 3 else 1)
    return cv2.warpAffine(image, matrix, (transform.input_width, transform.input_height),
                          flags=interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=value)
