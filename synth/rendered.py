"""One rendered synthetic frame: its pixels and labels, as the renderer hands them to the writer."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics


@dataclass(frozen=True)
class RenderedFrame:
    """One frame's pixels and labels, ready to write."""

    index: int
    rgb: np.ndarray                   # (H, W, 3) uint8
    link_ids: np.ndarray              # (H, W) uint16, 0 background, link index + 1
    depth: np.ndarray | None          # (H, W) float32 m, inf background
    camera: CameraIntrinsics
    T_cam_base: np.ndarray
    joints: np.ndarray
    P_cam: np.ndarray
    uv: np.ndarray
    in_frame: np.ndarray
    occlusion: tuple[str, ...]
    timestamp: float | None
