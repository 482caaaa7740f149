"""Image augmentation with the keypoints (and mask) carried along (albumentations).

Photometric: Gaussian and ISO noise, brightness/contrast, hue/saturation, blur, motion blur, JPEG
re-compression. Geometric: one affine shift-scale-rotate that moves the keypoints and the mask
with the image. Probabilities and ranges come from `train.config.AugmentConfig`.

Conventions checked in tests/test_train.py: albumentations 2.x rotates and scales keypoints
about ((W - 1) / 2, (H - 1) / 2), i.e. with pixel centres at integer coordinates like ours and
OpenCV's `warpAffine`, so an "xy" keypoint needs no half-pixel shift. Absent (NaN) keypoints stay
NaN; keypoints outside the image are kept (`remove_invisible=False`) and transformed, and one
that the transform brings into the frame becomes absent (NaN): it would sit on the fill, where
nothing of the robot is visible. A keypoint pushed out of the frame keeps its coordinates. The
border is filled with a constant (a reflecting border would mirror the robot without its
keypoints), and motion blur is centred (`allow_shifted=False`), which would otherwise shift the
image under the keypoints.

Zoom (`zoom_p`): after the rest, a sample may be cut around its labelled keypoints in the image
(`dream.zoom`, the cut detection makes around a first pass's keypoints), its margin and centre
drawn around detection's; `Augment.zoom` draws it and `train.data` applies it.

Random state: albumentations' `Compose(seed=...)` seeds every transform with the same seed,
which makes their random draws identical; `Augment` hands one shared generator to all of them
instead (`reseed`), and the data loader reseeds it in every worker.
"""

from __future__ import annotations

import math
import os
import random

# albumentations asks PyPI for its latest version at import unless told not to: no network here
os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")

import albumentations as A  # noqa: E402
import cv2
import numpy as np

from dream.errors import InputError
from dream.preprocess import InputTransform, Preprocess
from dream.zoom import zoom_transform
from train.config import AugmentConfig

FILL_VALUE = 0  # image and mask value where the affine transform uncovers the border


def build_transforms(config: AugmentConfig) -> list[A.BasicTransform]:
    """The albumentations transforms of `config`, geometric first."""
    return [
        A.Affine(scale=config.scale, translate_percent=(-config.translate, config.translate),
                 rotate=(-math.degrees(config.rotate_rad), math.degrees(config.rotate_rad)),
                 keep_ratio=True,
                 interpolation=cv2.INTER_LINEAR,
                 mask_interpolation=cv2.INTER_NEAREST, border_mode=cv2.BORDER_CONSTANT,
                 fill=FILL_VALUE, fill_mask=FILL_VALUE, p=config.affine_p),
        A.RandomBrightnessContrast(brightness_limit=config.brightness,
                                   contrast_limit=config.contrast,
                                   p=config.brightness_contrast_p),
        A.HueSaturationValue(hue_shift_limit=config.hue_shift,
                             sat_shift_limit=config.saturation_shift,
                             val_shift_limit=config.value_shift, p=config.hue_saturation_p),
        A.Blur(blur_limit=config.blur_limit, p=config.blur_p),
        A.MotionBlur(blur_limit=config.motion_blur_limit, allow_shifted=False,
                     p=config.motion_blur_p),
        A.GaussNoise(std_range=config.gauss_noise_std, p=config.gauss_noise_p),
        A.ISONoise(color_shift=config.iso_color_shift, intensity=config.iso_intensity,
                   p=config.iso_noise_p),
        A.ImageCompression(compression_type="jpeg", quality_range=config.jpeg_quality,
                           p=config.jpeg_p),
    ]


def inside_image(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """(K,) bool: (K, 2) pixels inside a width x height image (pixel centres 0 .. size - 1)."""
    with np.errstate(invalid="ignore"):
        return ((uv[:, 0] >= -0.5) & (uv[:, 0] <= width - 0.5) & (uv[:, 1] >= -0.5)
                & (uv[:, 1] <= height - 0.5))


class Augment:
    """Random augmentation of one image with its keypoints and optional mask.

    Args:
        config: probabilities and ranges (`enabled` false: the identity).
        seed: seed of the shared random generator.
    """

    def __init__(self, config: AugmentConfig, seed: int = 0):
        self.config = config
        self.zoom_settings = config.zoom_settings()
        self.compose = A.Compose(
            build_transforms(config),
            keypoint_params=A.KeypointParams(format="xy", remove_invisible=False)
        ) if config.enabled else None
        self.reseed(seed)

    def reseed(self, seed: int) -> None:
        """One generator for every transform (see the module docstring)."""
        self.rng = np.random.default_rng(seed)
        if self.compose is not None:
            self.compose.set_random_state(self.rng, random.Random(seed))

    def zoom(self, uv: np.ndarray, width: int, height: int, preprocess: Preprocess
             ) -> InputTransform | None:
        """With probability `zoom_p`, the input map of a cut around the keypoints of `uv`
        (K, 2) inside the width x height image, its margin and centre drawn; else None."""
        c = self.config
        if self.zoom_settings is None or self.rng.random() >= c.zoom_p:
            return None
        inside = inside_image(np.nan_to_num(uv, nan=-1.0), width, height)
        margin = c.zoom_margin + self.rng.uniform(-1.0, 1.0) * c.zoom_margin_jitter
        shift = self.rng.uniform(-1.0, 1.0, 2) * c.zoom_shift
        return zoom_transform(preprocess, width, height, uv[inside], self.zoom_settings, margin,
                              shift)

    def __call__(self, image: np.ndarray, uv: np.ndarray, mask: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Augment (H, W, 3) uint8 RGB, (K, 2) image-pixel keypoints (NaN: absent) and an
        optional (H, W) bool mask. Returns the same types and shapes."""
        image = np.asarray(image)
        uv = np.asarray(uv, dtype=float)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise InputError(f"image must be (H, W, 3) uint8 RGB, got {image.shape} "
                             f"{image.dtype}")
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise InputError(f"keypoints have shape {uv.shape}, expected (K, 2)")
        if mask is not None and np.shape(mask) != image.shape[:2]:
            raise InputError(f"mask {np.shape(mask)} does not match the image {image.shape}")
        if self.compose is None:
            return image, uv.copy(), None if mask is None else np.asarray(mask, dtype=bool)
        absent = ~np.all(np.isfinite(uv), axis=1)
        outside = ~absent & ~inside_image(uv, image.shape[1], image.shape[0])
        data = {"image": image, "keypoints": np.where(absent[:, None], 0.0, uv)}
        if mask is not None:
            data["mask"] = np.asarray(mask, dtype=np.uint8)
        out = self.compose(**data)
        uv_out = np.asarray(out["keypoints"], dtype=float).reshape(-1, 2)
        uv_out[absent] = np.nan
        height, width = out["image"].shape[:2]
        uv_out[outside & inside_image(uv_out, width, height)] = np.nan
        mask_out = None if mask is None else out["mask"].astype(bool)
        return out["image"], uv_out, mask_out
