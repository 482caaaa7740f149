"""`benchmarks/outline_offsets.py`: where the masks put the robot's outline against the
silhouettes rendered at a known pose."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dream.camera import CameraIntrinsics
from dream.coarse.carried import voxel_hull
from dream.errors import InputError
from dream.silhouette import render_points
from tests.benchmark_scripts import load_benchmark

CAMERA = CameraIntrinsics(200.0, 200.0, 79.5, 59.5, 160, 120)
MAGNIFIED = 1.05      # a focal length 5 % longer than the camera's
BOX_M = np.array([0.3, 0.2, 0.1])     # the box's sides


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("outline_offsets")


def box() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A box's corners (8, 3), triangles (12, 3), and a pose 1 m in front of the camera."""
    corners, faces = voxel_hull(np.zeros((1, 3)), 1.0)
    T = np.eye(4)
    T[2, 3] = 1.0
    return corners * BOX_M, faces, T


def test_a_mask_wider_on_one_side_is_seen_on_that_side_only(bench):
    square = np.zeros((40, 40), bool)
    square[10:30, 10:30] = True
    wider = np.zeros((40, 40), bool)
    wider[10:30, 8:30] = True
    medians = {side: float(np.median(v)) for side, v in bench.outline_offsets(square,
                                                                               wider).items()}
    assert medians == {"left": 2.0, "right": 0.0, "up": 0.0, "down": 0.0}
    excluded = np.zeros((40, 40), bool)
    excluded[:, :20] = True
    assert not len(bench.outline_offsets(square, wider, excluded)["left"])


def test_a_longer_focal_length_puts_the_outline_outside_on_every_side(bench):
    corners, faces, T = box()
    rendered = render_points(corners, faces, T, CAMERA)
    same = bench.outline_offsets(rendered, rendered)
    assert all(np.all(v == 0) for v in same.values())
    magnified = render_points(corners, faces, T, replace(CAMERA, fx=CAMERA.fx * MAGNIFIED,
                                                        fy=CAMERA.fy * MAGNIFIED))
    offsets = bench.outline_offsets(rendered, magnified)
    assert all(np.median(offsets[side]) >= 1.0 for side in bench.SIDES), offsets


def test_shapes_must_agree(bench):
    with pytest.raises(InputError, match="must be one"):
        bench.outline_offsets(np.zeros((4, 4), bool), np.zeros((4, 5), bool))
