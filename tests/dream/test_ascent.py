"""The masks' IoU climbed along the pose's own uncertainty (`dream.coarse.ascent`): the climb
follows a ridge along the covariance's axes, is not kept where the IoU still rises through its
ellipsoid's wall, never lowers the IoU, stops at its budget, and on rendered masks moves a pose
off along a weak axis back to the truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dream.coarse.ascent import Ascent, ascend, ascended, whitened_axes
from dream.coarse.calibration import DATA_MASKS, SearchMasks
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.metrics import pose_errors
from dream.pnp import apply_increment, increment_between
from tests.dream.test_coarse import SMALL, rendered_masks
from tests.dream.test_edges import CAMERA

T_START = np.eye(4)
T_START[:3, 3] = [0.05, -0.1, 1.2]


def ridge_covariance(seed: int = 0) -> np.ndarray:
    """A covariance whose axes mix rotation and translation (a camera turned about one axis and
    moved the other way: what the masks tell apart least), 1-sigma from 20 mm to 0.2 mm."""
    rng = np.random.default_rng(seed)
    axes, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    scale = np.repeat([0.01, 1.0], 3)          # rad, m
    sigma = np.array([20.0, 8.0, 3.0, 1.0, 0.5, 0.2]) * 1e-3
    A = scale[:, None] * axes * sigma
    return A @ A.T


def peak_score(xi_peak: np.ndarray, covariance: np.ndarray):
    """A stand-in for the masks' IoU: highest at the increment `xi_peak` from T_START, falling
    off as its Mahalanobis distance grows (a ridge along the covariance's largest axes)."""
    precision = np.linalg.inv(covariance)

    def score(T: np.ndarray) -> float:
        d = increment_between(T_START, T) - xi_peak
        return 1.0 / (1.0 + float(d @ precision @ d))
    return score


def test_the_climb_follows_a_ridge_along_the_covariance_axes():
    C = ridge_covariance()
    axes = whitened_axes(C)
    xi_peak = axes @ np.array([2.5, -1.5, 0.75, 0, 0, 0])     # 27 mm off along the weak axes
    ascent = ascend(peak_score(xi_peak, C), T_START, C)
    assert isinstance(ascent, Ascent)
    assert ascent.iou_after > 0.999 > 0.2 > ascent.iou_before and ascent.kept
    m, rad = pose_errors(ascent.T_cam_base, apply_increment(T_START, xi_peak))
    assert m < 1e-4 and rad < 1e-5, (m, rad)
    assert np.isclose(ascent.mahalanobis, np.linalg.norm([2.5, -1.5, 0.75]))
    assert ascent.moved_m == pytest.approx(pose_errors(ascent.T_cam_base, T_START)[0])


def test_a_peak_beyond_the_ellipsoid_is_not_climbed_to():
    """The IoU still rising through the 95 % ellipsoid's wall: the masks' optimum lies farther
    off than the pose's own spread allows, and the start stays."""
    C = ridge_covariance(1)
    settings = SearchSettings()
    wall = np.sqrt(settings.ascent_max_chi2)
    for peak_sigma, kept in ((wall - 0.5, True), (wall + 0.6, False), (10.0, False)):
        xi_peak = whitened_axes(C) @ np.array([peak_sigma, 0, 0, 0, 0, 0])
        ascent = ascend(peak_score(xi_peak, C), T_START, C)
        assert ascent.kept == kept, peak_sigma
        assert ascent.mahalanobis <= wall and ascent.iou_after > ascent.iou_before
        assert np.array_equal(ascent.T_cam_base, T_START) != kept
        assert ascent.moved_m > 0 and ascent.to_dict()["kept"] == kept


def test_the_climb_stops_at_its_budget():
    C = ridge_covariance(1)
    far = whitened_axes(C) @ np.array([10.0, 0, 0, 0, 0, 0])
    settings = replace(SearchSettings(), ascent_max_evaluations=5)
    assert ascend(peak_score(far, C), T_START, C, settings).evaluations == 5
    with pytest.raises(InputError, match="no lower than it starts"):
        Ascent(0.6, 0.5, 3, 0.0, 0.0, 0.0, True, T_START)


def test_a_pose_at_the_peak_does_not_move():
    C = ridge_covariance(2)
    ascent = ascend(peak_score(np.zeros(6), C), T_START, C)
    steps = len(SearchSettings().ascent_steps_sigma)
    assert ascent.iou_after == ascent.iou_before == 1.0 and ascent.kept
    assert np.array_equal(ascent.T_cam_base, T_START) and ascent.mahalanobis == 0.0
    assert ascent.evaluations == 1 + 12 * steps            # both ways along six axes per step


def test_whitened_axes_rebuild_the_covariance_and_skip_axes_without_variance():
    C = ridge_covariance(3)
    axes = whitened_axes(C)
    assert axes.shape == (6, 6) and np.allclose(axes @ axes.T, C, atol=1e-15)
    assert np.all(np.diff(np.linalg.norm(axes, axis=0)) <= 0)   # largest first
    flat = np.diag([1e-6, 0, 0, 4e-6, 0, 0])
    assert whitened_axes(flat).shape == (6, 2)
    with pytest.raises(InputError, match="expected a finite"):
        whitened_axes(np.eye(3))
    with pytest.raises(InputError, match="ascent_steps_sigma"):
        SearchSettings(ascent_steps_sigma=())


def test_a_pose_moved_along_a_weak_axis_climbs_back_on_rendered_masks(panda, meshes):
    T_true, joints, masks = rendered_masks(panda, meshes)
    inputs = SearchMasks(meshes, np.arange(len(joints)), joints, masks, DATA_MASKS, (),
                         np.arange(len(joints)))
    # the camera moved sideways 15 mm and turned back 0.6 deg: the robot's image barely shifts
    xi_weak = np.array([0.0, -0.0105, 0.0, 0.015, 0.0, 0.0])
    C = np.outer(xi_weak, xi_weak) + np.diag(np.repeat([1e-4 ** 2, 1e-3 ** 2], 3))
    T_off = apply_increment(T_true, xi_weak)
    lines: list[str] = []
    ascent = ascended(CAMERA, inputs, T_off, C, SMALL, lines.append)
    before = pose_errors(T_off, T_true)[0]
    after = pose_errors(ascent.T_cam_base, T_true)[0]
    assert ascent.kept and ascent.iou_after > ascent.iou_before
    assert after < before / 3, (before, after)
    assert "IoU climbed along the pose's 1-sigma axes" in lines[0]
