"""`benchmarks/camera_moves.py`: its knocked camera moves the image as it says."""

from __future__ import annotations

import numpy as np
import pytest

from tests.benchmark_scripts import load_benchmark

WIDTH, HEIGHT = 640, 480


def spot(x: int, y: int) -> np.ndarray:
    image = np.zeros((HEIGHT, WIDTH), np.float32)
    image[y, x] = 1.0
    return image


def where(image: np.ndarray) -> np.ndarray:
    """The intensity-weighted centre of an image, (x, y)."""
    ys, xs = np.mgrid[:HEIGHT, :WIDTH]
    return np.array([(xs * image).sum(), (ys * image).sum()]) / image.sum()


def test_a_knock_shifts_rolls_or_zooms_the_image_by_the_amount_given():
    bench = load_benchmark("camera_moves")
    shifted = bench.knock(spot(300, 200), "shift", 1.5, np.pi / 2)   # 1.5 px per 320: 3 px down
    assert where(shifted) == pytest.approx([300, 203], abs=0.05)
    centre = ((WIDTH - 1) / 2, (HEIGHT - 1) / 2)
    rolled = where(bench.knock(spot(600, 240), "roll", 1.0, 0.0))
    angle = np.degrees(np.arctan2(-(rolled[1] - 240), rolled[0] - centre[0]))
    assert angle == pytest.approx(1.0, abs=0.05)       # counter-clockwise as OpenCV rolls
    zoomed = where(bench.knock(spot(600, 240), "zoom", 1.01, 0.0))
    assert zoomed[0] - WIDTH / 2 == pytest.approx(1.01 * (600 - WIDTH / 2), abs=0.1)
