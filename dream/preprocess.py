"""Image -> network input: resize or letterbox, normalise, and the exact inverse for pixels.

Shared by training (`train/`) and by the onnxruntime inference, so it uses numpy and OpenCV only.

Coordinate spaces (pixels, u right, v down, the centre of the top-left pixel at (0, 0)):
- image: the camera image, `image_width` x `image_height`;
- input: the network input, `input_width` x `input_height`.

Resizing follows OpenCV's pixel-centre convention: an image of width W scaled to width w maps
`u_input = (u_image + 0.5) * w / W - 0.5`; letterboxing then adds an integer padding offset.
So `image_to_input` and `input_to_image` are exact inverses, and a feature drawn at `uv` in the
image lands at `image_to_input(uv)` in the input (up to the interpolation's blur).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from dream.errors import InputError

LETTERBOX = "letterbox"
RESIZE = "resize"
MODES = (LETTERBOX, RESIZE)
IMAGENET_MEAN = (0.485, 0.456, 0.406)  # RGB, on the [0, 1] scale
IMAGENET_STD = (0.229, 0.224, 0.225)
UINT8_MAX = 255.0
RGB_CHANNELS = 3


def _check_positive_int(value: Any, what: str) -> int:
    if isinstance(value, bool) or int(value) != value or value <= 0:
        raise InputError(f"{what} must be a positive integer, got {value!r}")
    return int(value)


def _check_uv(uv: np.ndarray) -> np.ndarray:
    uv = np.asarray(uv, dtype=float)
    if uv.shape[-1:] != (2,):
        raise InputError(f"pixel coordinates have shape {uv.shape}, expected (..., 2)")
    return uv


@dataclass(frozen=True)
class InputTransform:
    """The affine map image pixels -> input pixels of one preprocessed image.

    `uv_input = (uv_image + 0.5) * scale - 0.5 + offset`, per axis (u, v). NaN stays NaN.

    Attributes:
        image_width, image_height: size of the source image, px.
        input_width, input_height: size of the network input, px.
        scale_u, scale_v: resized size / source size, per axis.
        offset_u, offset_v: letterbox padding on the left / top, input px (0 for "resize").
    """

    image_width: int
    image_height: int
    input_width: int
    input_height: int
    scale_u: float
    scale_v: float
    offset_u: float
    offset_v: float

    def __post_init__(self) -> None:
        for name in ("image_width", "image_height", "input_width", "input_height"):
            object.__setattr__(self, name, _check_positive_int(getattr(self, name), name))
        for name in ("scale_u", "scale_v", "offset_u", "offset_v"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise InputError(f"{name} must be finite, got {value}")
            object.__setattr__(self, name, value)
        if self.scale_u <= 0 or self.scale_v <= 0:
            raise InputError(f"scales must be positive, got {self.scale_u}, {self.scale_v}")

    @property
    def _scale(self) -> np.ndarray:
        return np.array([self.scale_u, self.scale_v])

    @property
    def _offset(self) -> np.ndarray:
        return np.array([self.offset_u, self.offset_v])

    def image_to_input(self, uv_image: np.ndarray) -> np.ndarray:
        """Image pixels (..., 2) -> input pixels (..., 2)."""
        uv = _check_uv(uv_image)
        return (uv + 0.5) * self._scale - 0.5 + self._offset

    def input_to_image(self, uv_input: np.ndarray) -> np.ndarray:
        """Input pixels (..., 2) -> image pixels (..., 2); the exact inverse of image_to_input."""
        uv = _check_uv(uv_input)
        return (uv + 0.5 - self._offset) / self._scale - 0.5

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> InputTransform:
        return cls(**doc)


@dataclass(frozen=True)
class Preprocess:
    """How an RGB image becomes the network input.

    Attributes:
        input_width, input_height: network input size, px.
        mode: "letterbox" (keep the aspect ratio, pad right/bottom-and-left/top evenly with
            `pad_value`) or "resize" (stretch to the input size).
        mean, std: per-channel RGB normalisation on the [0, 1] scale:
            `x = (rgb / 255 - mean) / std`.
        pad_value: uint8 grey level of the letterbox padding (before normalisation).
    """

    input_width: int
    input_height: int
    mode: str = LETTERBOX
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD
    pad_value: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "input_width", _check_positive_int(self.input_width,
                                                                    "input_width"))
        object.__setattr__(self, "input_height", _check_positive_int(self.input_height,
                                                                     "input_height"))
        if self.mode not in MODES:
            raise InputError(f"preprocessing mode must be one of {', '.join(MODES)}, got "
                             f"{self.mode!r}")
        for name in ("mean", "std"):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != RGB_CHANNELS or not all(np.isfinite(values)):
                raise InputError(f"{name} must be 3 finite numbers (R, G, B), got "
                                 f"{getattr(self, name)!r}")
            object.__setattr__(self, name, values)
        if min(self.std) <= 0:
            raise InputError(f"std must be positive, got {self.std}")
        if isinstance(self.pad_value, bool) or int(self.pad_value) != self.pad_value or \
                not 0 <= self.pad_value <= UINT8_MAX:
            raise InputError(f"pad_value must be an integer 0..255, got {self.pad_value!r}")
        object.__setattr__(self, "pad_value", int(self.pad_value))

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable fields (for checkpoints and ONNX metadata)."""
        doc = asdict(self)
        doc["mean"], doc["std"] = list(self.mean), list(self.std)
        return doc

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Preprocess:
        return cls(**doc)

    def transform_for(self, image_width: int, image_height: int) -> InputTransform:
        """The image -> input transform of an image of this size."""
        W = _check_positive_int(image_width, "image width")
        H = _check_positive_int(image_height, "image height")
        w, h = self.input_width, self.input_height
        if self.mode == RESIZE:
            return InputTransform(W, H, w, h, w / W, h / H, 0.0, 0.0)
        scale = min(w / W, h / H)
        new_w = min(w, max(1, round(W * scale)))
        new_h = min(h, max(1, round(H * scale)))
        return InputTransform(W, H, w, h, new_w / W, new_h / H, float((w - new_w) // 2),
                              float((h - new_h) // 2))

    def _resized_size(self, transform: InputTransform) -> tuple[int, int]:
        return (round(transform.scale_u * transform.image_width),
                round(transform.scale_v * transform.image_height))

    def _place(self, resized: np.ndarray, transform: InputTransform, fill: int) -> np.ndarray:
        """Put the resized image at the transform's offset in an input-sized canvas."""
        if transform.offset_u == 0 and transform.offset_v == 0 and \
                resized.shape[:2] == (self.input_height, self.input_width):
            return resized
        canvas = np.full((self.input_height, self.input_width) + resized.shape[2:], fill,
                         dtype=resized.dtype)
        u0, v0 = int(transform.offset_u), int(transform.offset_v)
        canvas[v0:v0 + resized.shape[0], u0:u0 + resized.shape[1]] = resized
        return canvas

    def resize_image(self, image_rgb: np.ndarray) -> tuple[np.ndarray, InputTransform]:
        """(H, W, 3) uint8 RGB -> (input_height, input_width, 3) uint8 RGB and its transform.

        Shrinking uses area averaging (no aliasing), enlarging bilinear interpolation.
        """
        image = np.asarray(image_rgb)
        if image.ndim != 3 or image.shape[2] != RGB_CHANNELS or image.dtype != np.uint8:
            raise InputError(f"image must be (H, W, 3) uint8 RGB, got {image.shape} "
                             f"{image.dtype}")
        transform = self.transform_for(image.shape[1], image.shape[0])
        size = self._resized_size(transform)
        shrink = size[0] < image.shape[1] or size[1] < image.shape[0]
        if size != (image.shape[1], image.shape[0]):
            image = cv2.resize(image, size, interpolation=cv2.INTER_AREA if shrink
                               else cv2.INTER_LINEAR)
        return self._place(image, transform, self.pad_value), transform

    def normalize(self, image_rgb: np.ndarray) -> np.ndarray:
        """(h, w, 3) uint8 RGB -> (3, h, w) float32 normalised."""
        x = np.asarray(image_rgb, dtype=np.float32) / np.float32(UINT8_MAX)
        x = (x - np.asarray(self.mean, np.float32)) / np.asarray(self.std, np.float32)
        return np.ascontiguousarray(x.transpose(2, 0, 1))

    def apply(self, image_rgb: np.ndarray) -> tuple[np.ndarray, InputTransform]:
        """(H, W, 3) uint8 RGB image -> ((3, input_height, input_width) float32, transform)."""
        resized, transform = self.resize_image(image_rgb)
        return self.normalize(resized), transform

    def apply_mask(self, mask: np.ndarray) -> np.ndarray:
        """(H, W) bool robot mask -> (input_height, input_width) float32 robot fraction per
        input pixel (area-averaged; 0 in the letterbox padding)."""
        mask = np.asarray(mask)
        if mask.ndim != 2:
            raise InputError(f"mask must be (H, W), got {mask.shape}")
        transform = self.transform_for(mask.shape[1], mask.shape[0])
        size = self._resized_size(transform)
        m = mask.astype(np.float32)
        if size != (mask.shape[1], mask.shape[0]):
            shrink = size[0] < mask.shape[1] or size[1] < mask.shape[0]
            m = cv2.resize(m, size, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        return self._place(m, transform, 0)
