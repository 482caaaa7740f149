"""Test helpers for training: a tiny drawn DREAM dataset (no rendering).

`dream.sample.make_sample` gives Panda keypoints seen by random cameras; each frame is drawn as
coloured discs at the projected keypoints and grey skeleton lines on a random-noise background,
with a robot mask (the drawn pixels), then written in the DREAM layout with `dream.io.write_dream`.
`StopAtEpoch` kills a training run, for the resume tests (its users skip without lightning).
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from lightning.pytorch.callbacks import Callback

from dream.io import write_dream
from dream.sample import SampleSettings, make_sample

# distinct RGB colours, one per keypoint (the network can tell the keypoints apart by colour)
KEYPOINT_COLOURS = ((255, 40, 40), (40, 255, 40), (60, 60, 255), (255, 255, 40), (255, 40, 255),
                    (40, 255, 255), (255, 150, 40), (150, 40, 255))
SKELETON_GREY = 170
NOISE_MEAN, NOISE_STD = 70, 25


def draw_frame(uv: np.ndarray, width: int, height: int, rng: np.random.Generator,
               disc_radius: int = 2, line_width: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) uint8 RGB image and (H, W) bool mask of keypoints (K, 2) in image pixels."""
    image = np.clip(rng.normal(NOISE_MEAN, NOISE_STD, (height, width, 3)), 0, 255)
    image = image.astype(np.uint8)
    mask = np.zeros((height, width), np.uint8)
    shift = 4  # cv2 sub-pixel drawing: coordinates in 1/16 pixel
    pts = [None if not np.all(np.isfinite(p)) else tuple(int(round(c * 2 ** shift)) for c in p)
           for p in uv]
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        if a is not None and b is not None:
            cv2.line(image, a, b, (SKELETON_GREY,) * 3, line_width, cv2.LINE_AA, shift)
            cv2.line(mask, a, b, 1, line_width + 2, cv2.LINE_8, shift)
    for k, p in enumerate(pts):
        if p is not None:
            colour = KEYPOINT_COLOURS[k % len(KEYPOINT_COLOURS)]
            cv2.circle(image, p, disc_radius * 2 ** shift, colour, -1, cv2.LINE_AA, shift)
            cv2.circle(mask, p, (disc_radius + 1) * 2 ** shift, 1, -1, cv2.LINE_8, shift)
    return image, mask.astype(bool)


def make_drawn_dataset(out_dir: Path, num_frames: int = 32, width: int = 128, height: int = 96,
                       seed: int = 0, focal_px: float = 150.0, cameras: int = 1,
                       disc_radius: int = 2, line_width: int = 1) -> Path:
    """Write a drawn Panda dataset (images, masks, labels, per-frame ground truth) to `out_dir`:
    `num_frames` frames split among `cameras` random camera poses."""
    sequences = [make_sample(SampleSettings(
        num_frames=len(chunk), pixel_noise_px=0.0, width=width, height=height, fx=focal_px,
        fy=focal_px, seed=seed + c, distance_m=(1.2, 1.6)))
        for c, chunk in enumerate(np.array_split(np.arange(num_frames), cameras)) if len(chunk)]
    seq = replace(sequences[0], T_cam_base_reference=None if cameras > 1 else
                  sequences[0].T_cam_base_reference,
                  frames=tuple(replace(f, name=f"{i:06d}") for i, f in enumerate(
                      f for s in sequences for f in s.frames)))
    rng = np.random.default_rng(seed)
    frames = []
    with tempfile.TemporaryDirectory() as tmp:
        for frame in seq.frames:
            image, mask = draw_frame(frame.uv_labels, width, height, rng, disc_radius, line_width)
            image_path = Path(tmp) / f"{frame.name}.rgb.png"
            mask_path = Path(tmp) / f"{frame.name}.seg.png"
            cv2.imwrite(str(image_path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            cv2.imwrite(str(mask_path), mask.astype(np.uint8) * 255)
            frames.append(replace(frame, image_path=image_path, mask_path=mask_path))
        write_dream(replace(seq, frames=tuple(frames)), out_dir, overwrite=True)
    return out_dir


class StopAtEpoch(Callback):
    """Kills a run (an exception, by default KeyError) when epoch `epoch` starts."""

    def __init__(self, epoch: int, error: type[BaseException] = KeyError):
        self.epoch = epoch
        self.error = error

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        if trainer.current_epoch == self.epoch:
            raise self.error("killed")
