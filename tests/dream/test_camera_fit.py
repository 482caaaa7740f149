"""The joint fit of the pose and camera parameters on the finish's contour points
(`dream.coarse.camera_fit`), which the focal-length fit and the principal-point check share: on
masks rendered through the camera, a camera given with fx, fy and cx, cy off at once is asked
back by one fit over all three, and its leave-out spread is small and positive."""

from __future__ import annotations

import numpy as np
import pytest

from dream.camera import CameraIntrinsics
from dream.coarse.camera_fit import (
    CameraFit,
    _Problem,
    finest_objective,
    frame_group_keeps,
    link_keeps,
    principal_turn,
)
from dream.coarse.focal import with_focal_scale
from dream.coarse.principal import with_principal_shift
from dream.coarse.scales import finish_scale
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.metrics import pose_errors
from dream.pnp.reprojection import linearise
from dream.silhouette import vertices_in_base
from dream.transforms import look_at
from tests.dream.test_coarse import rendered_masks
from tests.dream.test_edges import CAMERA
from tests.dream.test_principal import turned

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
    covariance = fit.jackknife_spreads(objective, contour, T, scales.params.initial_damping,
                                       [frame_group_keeps(contour, FRAMES, 5)])[0]
    assert covariance.shape == (3, 3) and np.allclose(covariance, covariance.T)
    sigma = np.sqrt(np.diag(covariance))
    assert np.all(sigma > 0)
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


def test_the_turn_a_shift_carries_changes_the_fit_s_speed_not_its_answer(meshes, scene):
    """On one set of contour points through cx, cy given off: the fit whose shift carries its
    turn reaches in 5 linearisations what the plain fit reaches in 60."""
    T_true, P, masks = scene
    given = with_principal_shift(CAMERA, GIVEN_SHIFT_PX)
    T_given = turned(T_true, GIVEN_SHIFT_PX, CAMERA)
    scales = finish_scale(P, meshes, masks, given, SearchSettings())
    objective, contour = finest_objective(scales), scales.contour(T_given)
    damping = scales.params.initial_damping
    T_plain, p_plain = CameraFit(with_principal_shift, 2, 1e-3, 60).fit(
        objective, contour, T_given, damping)
    T_turned, p_turned = CameraFit(with_principal_shift, 2, 1e-3, 5, principal_turn).fit(
        objective, contour, T_given, damping)
    to_image = CAMERA.width / objective.camera.width
    np.testing.assert_allclose(p_turned * to_image, p_plain * to_image, atol=0.3)
    assert np.rad2deg(pose_errors(T_turned, T_plain)[1]) < 0.05
    np.testing.assert_allclose(p_plain * to_image, -GIVEN_SHIFT_PX, atol=0.5)   # the way back


class _Reprojection:
    """An objective whose Jacobian is exact (`dream.pnp.reprojection.linearise`: points
    projected against fixed pixels), with `Objective`'s interface as `CameraFit` uses it."""

    def __init__(self, camera: CameraIntrinsics, P_base: np.ndarray, uv: np.ndarray):
        self.camera, self.P_base, self.uv = camera, P_base, uv

    def with_camera(self, camera: CameraIntrinsics) -> _Reprojection:
        return _Reprojection(camera, self.P_base, self.uv)

    def residuals(self, contour, T, jacobian):
        e, J = linearise(self.P_base, self.uv, self.camera, T)
        return e.reshape(-1), J.reshape(-1, 6) if jacobian else None

    def rho(self, r):
        return 0.5 * r ** 2

    def weight(self, r):
        return np.ones_like(r)


@pytest.mark.parametrize("turn_at", [None, principal_turn])
def test_the_fit_s_gradient_is_its_cost_s_derivative(turn_at):
    """The normal equations' gradient J^T W r against central differences of the cost along
    each of the eight coordinates (pose, du, dv), at a shift that turns the camera some 4 deg:
    the pose's columns turned with the shift where it carries its turn (the p columns are
    central differences themselves: the pose's are what this checks)."""
    rng = np.random.default_rng(0)
    T = look_at(np.array([1.2, 0.4, 0.9]), np.array([0.0, 0.0, 0.4]))
    P = rng.uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (40, 3))
    uv = rng.uniform([0, 0], [CAMERA.width, CAMERA.height], (40, 2))
    problem = _Problem(CameraFit(with_principal_shift, 2, 1e-4, 5, turn_at),
                       _Reprojection(CAMERA, P, uv), None, np.ones(2 * len(P)))
    x = (T, np.array([0.06 * CAMERA.fx, -0.04 * CAMERA.fy]))
    _, g = problem.normal_equations(x, None)
    steps = np.array([1e-7] * 6 + [1e-4] * 2)
    numeric = np.array([(problem.evaluate(problem.retract(x, h * e))[0]
                         - problem.evaluate(problem.retract(x, -h * e))[0]) / (2 * h)
                        for h, e in zip(steps, np.eye(8), strict=True)])
    np.testing.assert_allclose(g, numeric, rtol=1e-5)


def test_the_principal_turn_moves_the_image_centre_back():
    camera = CameraIntrinsics(300.0, 310.0, 160.0, 120.0, 320, 240)
    for p in (np.array([12.0, -8.0]), np.array([-30.0, 0.0]), np.zeros(2)):
        C = principal_turn(camera, p)
        np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-12)
        ray = C @ [0.0, 0.0, 1.0]
        np.testing.assert_allclose([camera.fx * ray[0] / ray[2], camera.fy * ray[1] / ray[2]],
                                   -p, atol=1e-9)


@pytest.mark.parametrize("size, step, iterations", [(0, 1e-3, 10), (1, 0.0, 10), (1, 1e-3, 0)])
def test_camera_fit_settings_are_checked(size, step, iterations):
    with pytest.raises(InputError, match="camera fit"):
        CameraFit(_scaled_and_shifted, size, step, iterations)


def test_link_keeps_leave_out_each_link_with_enough_contour_points(meshes):
    """One keep per link with at least `JACKKNIFE_MIN_CONTOUR_POINTS` contour points, False
    exactly on that link's points; None without vertices or with too few such links."""
    from dream.polish.objective import Contour
    from dream.polish.refine import JACKKNIFE_MIN_CONTOUR_POINTS as ENOUGH

    on_link = [np.flatnonzero(meshes.vertex_link == k) for k in range(len(meshes.links))]
    shown = [k for k, v in enumerate(on_link) if len(v)][:4]
    vertex = np.concatenate([on_link[k][:1].repeat(ENOUGH) for k in shown[:3]]
                            + [on_link[shown[3]][:1].repeat(ENOUGH - 1)])   # one link short
    contour = Contour(np.zeros((len(vertex), 3)), np.zeros(len(vertex), int),
                      np.zeros(len(vertex)), vertex)
    keeps = link_keeps(contour, meshes)
    assert len(keeps) == 3
    for keep, k in zip(keeps, shown[:3], strict=True):
        np.testing.assert_array_equal(keep, meshes.vertex_link[vertex] != k)
    assert link_keeps(Contour(contour.P_base, contour.frame, contour.s, None), meshes) is None
    assert link_keeps(Contour(contour.P_base[:2 * ENOUGH], contour.frame[:2 * ENOUGH],
                              contour.s[:2 * ENOUGH], vertex[:2 * ENOUGH]), meshes) is None
