"""Image <-> network input: exact inverse transforms, and pixels land where the transform says."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dream.errors import InputError
from dream.preprocess import LETTERBOX, RESIZE, InputTransform, Preprocess

SIZES = [(640, 480), (641, 479), (333, 517), (97, 61), (64, 48), (40, 30)]
INPUTS = [(64, 48), (65, 47), (96, 96), (320, 240)]
BLOB_SIGMA_INPUT_PX = 3.0


@pytest.mark.parametrize("mode", [LETTERBOX, RESIZE])
@pytest.mark.parametrize("image_size", SIZES)
@pytest.mark.parametrize("input_size", INPUTS)
def test_round_trip_is_exact(mode, image_size, input_size, rng):
    pre = Preprocess(*input_size, mode=mode)
    t = pre.transform_for(*image_size)
    uv = rng.uniform(-50, 700, (30, 2))
    np.testing.assert_allclose(t.input_to_image(t.image_to_input(uv)), uv, atol=1e-9)
    np.testing.assert_allclose(t.image_to_input(t.input_to_image(uv)), uv, atol=1e-9)
    # the image corners land on the resized area's corners, inside the input
    corners = t.image_to_input(np.array([[-0.5, -0.5], [image_size[0] - 0.5,
                                                        image_size[1] - 0.5]]))
    assert corners[0].min() >= -0.5 - 1e-9
    assert corners[1][0] <= input_size[0] - 0.5 + 1e-9
    assert corners[1][1] <= input_size[1] - 0.5 + 1e-9
    if mode == LETTERBOX:  # aspect ratio kept within one pixel of rounding
        assert abs(t.scale_u - t.scale_v) <= max(1 / image_size[0], 1 / image_size[1]) + 1e-12


def _blob(width: int, height: int, uv: np.ndarray, sigma: float) -> np.ndarray:
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    g = np.exp(-((u - uv[0]) ** 2 + (v - uv[1]) ** 2) / (2 * sigma ** 2))
    return np.repeat((g * 255).round().astype(np.uint8)[..., None], 3, axis=2)


def _centroid(gray: np.ndarray) -> np.ndarray:
    gray = gray - np.median(gray)
    gray = np.clip(gray, 0, None)
    v, u = np.mgrid[:gray.shape[0], :gray.shape[1]]
    return np.array([(gray * u).sum(), (gray * v).sum()]) / gray.sum()


@pytest.mark.parametrize("mode", [LETTERBOX, RESIZE])
@pytest.mark.parametrize(("image_size", "input_size"), [((640, 480), (128, 96)),
                                                         ((333, 517), (96, 96)),
                                                         ((97, 61), (160, 120)),
                                                         ((100, 80), (64, 64))])
def test_drawn_pixel_lands_at_image_to_input(mode, image_size, input_size, rng):
    pre = Preprocess(*input_size, mode=mode, mean=(0, 0, 0), std=(1, 1, 1))
    t = pre.transform_for(*image_size)
    scale = min(t.scale_u, t.scale_v)
    for _ in range(5):
        uv = rng.uniform(0.35, 0.65, 2) * np.array(image_size)
        image = _blob(*image_size, uv, BLOB_SIGMA_INPUT_PX / scale)
        x, t2 = pre.apply(image)
        assert t2 == t and x.shape == (3, input_size[1], input_size[0]) and x.dtype == np.float32
        got = _centroid(x[0])
        np.testing.assert_allclose(got, t.image_to_input(uv), atol=0.05)


def test_letterbox_pads_and_mask_follows():
    pre = Preprocess(64, 64, mode=LETTERBOX, pad_value=7, mean=(0, 0, 0), std=(1, 1, 1))
    image = np.full((30, 60, 3), 200, np.uint8)
    x, t = pre.apply(image)
    assert (t.offset_u, t.offset_v) == (0.0, 16.0) and t.scale_u == pytest.approx(64 / 60)
    assert x[0, 0, 0] == pytest.approx(7 / 255) and x[0, 32, 32] == pytest.approx(200 / 255)
    mask = np.zeros((30, 60), bool)
    mask[10:20, 30:40] = True
    m = pre.apply_mask(mask)
    assert m.shape == (64, 64) and m[:16].max() == 0 and m.max() == pytest.approx(1.0)
    centre = t.image_to_input(np.array([34.5, 14.5]))
    np.testing.assert_allclose(_centroid(m), centre, atol=0.05)


def test_json_round_trip_and_validation():
    pre = Preprocess(65, 47, mode=RESIZE)
    doc = json.loads(json.dumps(pre.to_dict()))
    assert Preprocess.from_dict(doc) == pre
    t = pre.transform_for(640, 480)
    assert InputTransform.from_dict(json.loads(json.dumps(t.to_dict()))) == t
    for bad in (dict(input_width=0, input_height=4), dict(input_width=4, input_height=4,
                                                          mode="crop"),
                dict(input_width=4, input_height=4, std=(1, 0, 1)),
                dict(input_width=4, input_height=4, mean=(1, 2))):
        with pytest.raises(InputError):
            Preprocess(**bad)
    with pytest.raises(InputError):
        pre.apply(np.zeros((10, 10), np.uint8))
    with pytest.raises(InputError):
        t.image_to_input(np.zeros(3))
