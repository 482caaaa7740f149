"""Training targets: one Gaussian belief map per keypoint, and the robot-mask map (numpy only).

Coordinate spaces (pixels, u right, v down, the centre of the top-left pixel at (0, 0)): input
(the network input) and map (the belief map, `stride` times smaller):
`u_map = (u_input + 0.5) / stride - 0.5` (`dream.peaks.input_to_map`).
"""

from __future__ import annotations

import cv2
import numpy as np

from dream.errors import InputError
from dream.peaks import input_to_map


def map_size(input_width: int, input_height: int, stride: int) -> tuple[int, int]:
    """(map_width, map_height) of an input of this size; the input must be a multiple of stride."""
    if input_width % stride or input_height % stride:
        raise InputError(f"input size {input_width}x{input_height} is not a multiple of the "
                         f"output stride {stride}")
    return input_width // stride, input_height // stride


def belief_maps(uv_input: np.ndarray, input_width: int, input_height: int, stride: int,
                sigma: float) -> np.ndarray:
    """Gaussian belief maps of K keypoints.

    Args:
        uv_input: (K, 2) keypoints in input pixels; NaN rows are absent keypoints.
        input_width, input_height: network input size, px (multiples of `stride`).
        stride: input pixels per map pixel (1, 2 or 4).
        sigma: the Gaussian's standard deviation, map pixels.

    Returns:
        (K, input_height / stride, input_width / stride) float32: `exp(-d^2 / (2 sigma^2))`,
        d the distance in map pixels to the keypoint's sub-pixel map position (peak value 1
        there). A keypoint near or beyond the border keeps the visible part of its Gaussian;
        an absent keypoint gives an all-zero map.
    """
    uv_input = np.asarray(uv_input, dtype=float)
    if uv_input.ndim != 2 or uv_input.shape[1] != 2:
        raise InputError(f"keypoints have shape {uv_input.shape}, expected (K, 2)")
    if not np.isfinite(sigma) or sigma <= 0:
        raise InputError(f"belief sigma must be positive, got {sigma}")
    w, h = map_size(input_width, input_height, stride)
    uv_map = input_to_map(uv_input, stride)
    present = np.all(np.isfinite(uv_map), axis=1)
    center = np.where(present[:, None], uv_map, 0.0)
    gu = np.exp(-(np.arange(w)[None, :] - center[:, :1]) ** 2 / (2 * sigma ** 2))  # (K, w)
    gv = np.exp(-(np.arange(h)[None, :] - center[:, 1:]) ** 2 / (2 * sigma ** 2))  # (K, h)
    maps = gv[:, :, None] * gu[:, None, :] * present[:, None, None]
    return maps.astype(np.float32)


def mask_map(mask_input: np.ndarray, stride: int) -> np.ndarray:
    """(input_height, input_width) robot fraction in [0, 1] -> (1, h, w) float32 at the map's
    stride (area average, so a map pixel holds the robot fraction of its input pixels)."""
    mask_input = np.asarray(mask_input, dtype=np.float32)
    if mask_input.ndim != 2:
        raise InputError(f"mask has shape {mask_input.shape}, expected (H, W)")
    w, h = map_size(mask_input.shape[1], mask_input.shape[0], stride)
    if stride > 1:
        mask_input = cv2.resize(mask_input, (w, h), interpolation=cv2.INTER_AREA)
    return np.clip(mask_input, 0.0, 1.0)[None].astype(np.float32)
