"""The joint fit of the pose and camera parameters on the finish's contour points
(`dream.coarse.camera_fit`), which the focal-length fit and the principal-point check share: on
masks rendered through the camera, a camera given with fx, fy and cx, cy off at once is asked
back by one fit over all three, and its leave-out spread is small and positive."""

from __future__ import annotations

import numpy as np
import pytest

from dream.camera import CameraIntrinsics
from dream.coarse.camera_fit import CameraFit, finest_objective, frame_group_keeps
from dream.coarse.focal import with_focal_scale
from dream.coarse.principal import with_principal_shift
from dream.coarse.scales import finish_scale
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.metrics import pose_errors
from dream.silhouette import vertices_in_base
from tests.dream.test_coarse import rendered_masks
from tests.dream.test_edges import CAMERA

GIVEN_SCALE = 0.97                     # fx, fy given 3 % short of the rendering camera's
GIVEN_SHIFT_PX = np.array([6.0, -4.0])  # cx, cy given this far off
FRAMES = 10
ROUNDS = 6


def _scaled_and_shifted(camera: CameraIntrinsics, p: np.ndarray) -> CameraIntrinsics:
    """p = (log s, du, dv): fx, fy times exp(log s), cx, cy moved by du, dv."""
    return with_principal_shift(with_focal_scale(camera, float(np.exp(p[0]))), p[1:])


@pytest.fixture(scope="module")
def scene(panda, meshes):
    T_true, joints, masks = rendered_masks(panda, meshes, frames=FRAMES)
    return T_true, vertices_in_base(meshes, joints), masks


def test_the_fit_asks_back_the_focal_length_and_the_principal_point_at_once(meshes, scene):
    """Rounds of contour points through the current camera and a joint fit over (pose,
    log s, du, dv), as the focal and principal-point fits run them over fewer parameters."""
    T_true, P, masks = scene
    given = with_principal_shift(with_focal_scale(CAMERA, GIVEN_SCALE), GIVEN_SHIFT_PX)
    fit = CameraFit(_scaled_and_shifted, 3, derivative_step=1e-3, lm_iterations=30)
    camera, T = given, T_true
    for _ in range(ROUNDS):
        scales = finish_scale(P, meshes, masks, camera, SearchSettings())
        objective = finest_objective(scales)
        to_image = CAMERA.width / objective.camera.width
        T, p = fit.fit(objective, scales.contour(T), T, scales.params.initial_damping)
        camera = _scaled_and_shifted(camera, np.array([p[0], *(p[1:] * to_image)]))
    assert camera.fx == pytest.approx(CAMERA.fx, rel=0.005)
    assert abs(camera.cx - CAMERA.cx) < 1.0 and abs(camera.cy - CAMERA.cy) < 1.0, camera
    distance, angle = pose_errors(T, T_true)
    assert distance < 0.005 and np.rad2deg(angle) < 0.3, (distance, np.rad2deg(angle))
    contour = scales.contour(T)
    sigma = np.sqrt(fit.jackknife_variance(objective, contour, T,
                                           scales.params.initial_damping,
                                           frame_group_keeps(contour, FRAMES, 5)))
    assert sigma.shape == (3,) and np.all(sigma > 0)
    assert sigma[0] < 0.01 and np.all(sigma[1:] * to_image < 1.0), sigma


def test_a_fit_with_nothing_to_move_keeps_the_pose_it_starts_at(meshes, scene):
    """Through the right camera the fit leaves the truth where it is and asks for nothing."""
    T_true, P, masks = scene
    scales = finish_scale(P, meshes, masks, CAMERA, SearchSettings())
    fit = CameraFit(_scaled_and_shifted, 3, derivative_step=1e-3, lm_iterations=30)
    T, p = fit.fit(finest_objective(scales), scales.contour(T_true), T_true,
                   scales.params.initial_damping)
    assert abs(p[0]) < 0.003 and np.all(np.abs(p[1:]) < 0.5), p
    assert pose_errors(T, T_true)[0] < 0.002


@pytest.mark.parametrize("size, step, iterations", [(0, 1e-3, 10), (1, 0.0, 10), (1, 1e-3, 0)])
def test_camera_fit_settings_are_checked(size, step, iterations):
    with pytest.raises(InputError, match="camera fit"):
        CameraFit(_scaled_and_shifted, size, step, iterations)
