"""The moving pixels away from the robot at a pose found (pure).

Motion masks hold whatever moves in front of a fixed camera: the arm, what it carries, its
shadow, and also a second arm at work or a person walking past. The search's IoU counts such
pixels in every hypothesis' union, so they lower the IoU of the right pose as of every other
(not the ranking), and a verdict that reads the IoU as "the robot was found" would call a right
pose unreliable for them. At the pose found, a connected part of a frame's mask that comes no
nearer than a margin to the robot's silhouette lies away from the robot (`away_from_robot`):
the verdict's found test reads the IoU without those pixels, and where they are more than a
small share of the moving pixels the verdict is at most `check` and says so
(`dream.coarse.verdict.away_finding`): if the robot itself is among them, the pose is wrong.

    >>> masks = np.zeros((1, 6, 12), bool); masks[0, 1:4, 1:4] = True; masks[0, 1:4, 8:11] = True
    >>> silhouettes = np.zeros_like(masks); silhouettes[0, 1:4, 1:3] = True
    >>> away = away_from_robot(masks, silhouettes, margin_px=1.0)
    >>> away.share, round(away.iou_without(0.3), 3)   # here 1/3 -> 2/3
    (0.5, 0.6)
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from dream.camera import CameraIntrinsics
from dream.edges.motion import disk
from dream.errors import InputError
from dream.silhouette import RobotMeshes, render_frames, vertices_in_base

MARGIN_WIDTH_PX = 320.0   # `SearchSettings.away_margin_px` is given per this image width


@dataclass(frozen=True)
class AwayPixels:
    """Per frame (F,): the mask's pixels, those of its parts away from the robot, and the
    IoU of the silhouette with the mask with (`iou`) and without (`iou_near`) those parts."""

    moving: np.ndarray
    away: np.ndarray
    iou: np.ndarray
    iou_near: np.ndarray

    @property
    def share(self) -> float:
        """The share of all the frames' moving pixels that lies away from the robot."""
        return float(self.away.sum() / max(int(self.moving.sum()), 1))

    def iou_without(self, iou: float) -> float:
        """A mean IoU `iou` of the same silhouettes at another scale (the search's) with the
        away pixels out of each union, as the frames' mean IoU here moves without them (the
        pixels lie outside the silhouettes: only the unions shrink)."""
        here = float(self.iou.mean())
        return iou if here <= 0 else min(1.0, iou * float(self.iou_near.mean()) / here)

    def to_dict(self) -> dict:
        return {"share": self.share, "frames_with_away_pixels": int(np.count_nonzero(self.away)),
                "iou_here": float(self.iou.mean()), "iou_here_without": float(
                    self.iou_near.mean())}


def away_from_robot(masks: np.ndarray, silhouettes: np.ndarray, margin_px: float
                    ) -> AwayPixels:
    """The parts (8-connected) of each mask (F, H, W) that come no nearer than `margin_px` to
    that frame's silhouette (F, H, W) of the robot: pixel counts and IoUs (module doc)."""
    masks, silhouettes = _checked(masks, silhouettes)
    kernel = disk(margin_px)
    counts = np.zeros((4, len(masks)))
    for f, (mask, silhouette) in enumerate(zip(masks, silhouettes, strict=True)):
        kept = mask & ~_away(mask, silhouette, kernel)
        inter = np.count_nonzero(silhouette & mask)
        counts[:, f] = (mask.sum(), (mask & ~kept).sum(), _ratio(inter, (silhouette | mask)),
                        _ratio(inter, (silhouette | kept)))
    return AwayPixels(*counts)


def away_masks(masks: np.ndarray, silhouettes: np.ndarray, margin_px: float) -> np.ndarray:
    """(F, H, W) bool: the pixels of `away_from_robot`'s parts away from the robot, to draw.

    >>> masks = np.zeros((1, 6, 12), bool); masks[0, 1:4, 1:4] = True; masks[0, 1:4, 8:11] = True
    >>> silhouettes = np.zeros_like(masks); silhouettes[0, 1:4, 1:3] = True
    >>> np.flatnonzero(away_masks(masks, silhouettes, margin_px=1.0)[0].any(axis=0))
    array([ 8,  9, 10])
    """
    masks, silhouettes = _checked(masks, silhouettes)
    kernel = disk(margin_px)
    return np.stack([_away(m, s, kernel) for m, s in zip(masks, silhouettes, strict=True)])


def _checked(masks, silhouettes) -> tuple[np.ndarray, np.ndarray]:
    masks, silhouettes = np.asarray(masks, bool), np.asarray(silhouettes, bool)
    if masks.ndim != 3 or masks.shape != silhouettes.shape:
        raise InputError(f"masks {masks.shape} and silhouettes {silhouettes.shape} must both "
                         "be (F, H, W)")
    return masks, silhouettes


def _away(mask: np.ndarray, silhouette: np.ndarray, kernel: np.ndarray | None) -> np.ndarray:
    """(H, W) bool: the 8-connected parts of `mask` that do not touch `silhouette` widened by
    `kernel` (None: not widened)."""
    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    near = silhouette if kernel is None else \
        cv2.dilate(silhouette.astype(np.uint8), kernel).astype(bool)
    touched = np.unique(labels[near & mask])
    return mask & ~np.isin(labels, touched[touched > 0])


def _ratio(inter: int, union: np.ndarray) -> float:
    n = int(np.count_nonzero(union))
    return inter / n if n else 0.0


def away_at_pose(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
                 camera: CameraIntrinsics, T_cam_base: np.ndarray, margin_px: float
                 ) -> AwayPixels:
    """`away_from_robot` of `masks` (F, H, W; `camera`'s size) against the silhouettes of
    `meshes` at `joints` (F, J) seen from `T_cam_base`; `margin_px` per `MARGIN_WIDTH_PX` of
    width."""
    return away_from_robot(masks, *_silhouettes_and_margin(meshes, joints, camera, T_cam_base,
                                                           margin_px))


def away_masks_at_pose(meshes: RobotMeshes, joints: np.ndarray, masks: np.ndarray,
                       camera: CameraIntrinsics, T_cam_base: np.ndarray, margin_px: float
                       ) -> np.ndarray:
    """`away_masks` against the silhouettes of `away_at_pose` (the same arguments)."""
    return away_masks(masks, *_silhouettes_and_margin(meshes, joints, camera, T_cam_base,
                                                      margin_px))


def _silhouettes_and_margin(meshes: RobotMeshes, joints: np.ndarray, camera: CameraIntrinsics,
                            T_cam_base: np.ndarray, margin_px: float
                            ) -> tuple[np.ndarray, float]:
    """The silhouettes (F, H, W) of `meshes` at `joints` seen from `T_cam_base`, and
    `margin_px` (per `MARGIN_WIDTH_PX` of width) in `camera`'s pixels."""
    silhouettes = render_frames(vertices_in_base(meshes, joints), meshes.faces,
                                np.asarray(T_cam_base, float), camera)
    return silhouettes, margin_px * camera.width / MARGIN_WIDTH_PX
