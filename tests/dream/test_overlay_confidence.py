"""Overlays write each detection's confidence next to it."""

import numpy as np
import pytest

from dream.errors import InputError
from dream.overlay import blank_image, draw_confidences


def test_confidence_text_is_drawn_next_to_found_keypoints_only():
    image = blank_image(320, 240, gray=0)
    uv = np.array([[100.0, 100.0], [np.nan, np.nan], [200.0, 150.0]])
    out = draw_confidences(image, uv, np.array([0.87, 0.5, 0.31]))
    near = lambda u, v: out[v - 15:v + 2, u:u + 40].any()  # noqa: E731
    assert near(100, 100) and near(200, 150)
    assert not out[:80].any()  # nothing drawn where no keypoint is
    with pytest.raises(InputError):
        draw_confidences(image, uv, np.array([0.1, 0.2]))
