"""Masks from a network's mask head come back in image pixels through the inverse
preprocessing (letterbox), as the keypoints do; without masks in the data, --polish uses
them only when asked (--mask-head)."""

from __future__ import annotations

import numpy as np
import pytest

from dream.camera import CameraIntrinsics
from dream.detection import detect_keypoints, predict_masks
from dream.errors import InputError
from dream.peaks import PeakSettings
from dream.polish import check_polish_input
from dream.preprocess import Preprocess
from dream.sequence import Frame, Sequence

WIDTH, HEIGHT = 160, 100          # image: letterboxed into 128x96 with vertical padding
BOX = (40, 20, 100, 70)           # robot = this image rectangle (u0, v0, u1, v1)


class BoxMaskModel:
    """A fake keypoint model whose mask head marks BOX (known in image pixels)."""

    keypoint_names = ("panda_link0",)
    preprocess = Preprocess(128, 96)
    stride = 2

    def run(self, batch: np.ndarray) -> dict[str, np.ndarray]:
        n, _, h, w = batch.shape
        transform = self.preprocess.transform_for(WIDTH, HEIGHT)
        v, u = np.mgrid[0:h // self.stride, 0:w // self.stride].astype(float)
        uv_input = (np.stack([u, v], -1) + 0.5) * self.stride - 0.5
        uv_image = transform.input_to_image(uv_input)
        inside = ((uv_image[..., 0] >= BOX[0]) & (uv_image[..., 0] <= BOX[2])
                  & (uv_image[..., 1] >= BOX[1]) & (uv_image[..., 1] <= BOX[3]))
        logits = np.where(inside, 5.0, -5.0).astype(np.float32)
        return {"belief": np.zeros((n, 1, h // 2, w // 2), np.float32),
                "mask": np.broadcast_to(logits, (n, 1) + logits.shape).copy()}


def _sequence(tmp_path) -> Sequence:
    import cv2

    path = tmp_path / "000000.rgb.png"
    cv2.imwrite(str(path), np.zeros((HEIGHT, WIDTH, 3), np.uint8))
    camera = CameraIntrinsics(100.0, 100.0, WIDTH / 2 - 0.5, HEIGHT / 2 - 0.5, WIDTH, HEIGHT)
    return Sequence("panda", camera, tuple(f"panda_joint{i}" for i in range(1, 8)),
                    ("panda_link0",), (Frame("000000", np.zeros(7), image_path=path),))


def test_mask_head_is_mapped_back_to_image_pixels(tmp_path):
    seq = _sequence(tmp_path)
    (mask,) = predict_masks(seq, BoxMaskModel(), [0])
    assert mask.shape == (HEIGHT, WIDTH)
    truth = np.zeros_like(mask)
    truth[BOX[1]:BOX[3] + 1, BOX[0]:BOX[2] + 1] = True
    iou = (mask & truth).sum() / (mask | truth).sum()
    assert iou > 0.95  # the belief-map grid is 2.5 image px: the edges blur by about a pixel


def test_polish_without_masks_takes_the_mask_head_only_when_asked(tmp_path):
    seq = _sequence(tmp_path)
    with pytest.raises(InputError, match="--mask-head"):
        check_polish_input(seq, "all")
    check_polish_input(seq, "all", network_masks=True)
    with pytest.raises(InputError, match="too coarse"):
        check_polish_input(seq, "each", network_masks=True)


def test_model_without_mask_head_is_refused(tmp_path):
    class NoMask(BoxMaskModel):
        def run(self, batch):
            out = super().run(batch)
            del out["mask"]
            return out

    with pytest.raises(InputError, match="mask head"):
        predict_masks(_sequence(tmp_path), NoMask(), [0])


class WeakPeakModel(BoxMaskModel):
    """One weak belief peak (0.2): found under the default threshold (0.1), not under the
    model's own (0.3)."""

    peak_params = PeakSettings(threshold=0.3)

    def run(self, batch: np.ndarray) -> dict[str, np.ndarray]:
        out = super().run(batch)
        belief = np.zeros_like(out["belief"])
        belief[:, 0, 22:27, 30:35] = 0.2
        return {**out, "belief": belief}


def test_detection_takes_the_models_own_peak_constants(tmp_path):
    """`dream.detect` (the Python API) finds what `dream calibrate --model` finds: the peak
    finder runs with the model's constants unless others are given."""
    import dream

    seq = _sequence(tmp_path)
    robot = dream.load_robot("panda")
    assert not dream.detect(seq, robot, WeakPeakModel()).found.any()
    found = detect_keypoints(seq, robot, WeakPeakModel(), peak_params=PeakSettings())
    assert found.found.all()
