"""The D-optimal design and the path order: pure functions, checked against the Cramer-Rao
bound, brute force and Monte Carlo."""

from __future__ import annotations

import doctest
import itertools

import numpy as np
import pytest

import plan.design
import plan.ordering
from dream.calibration import Observations, calibrate_all
from dream.camera import CameraIntrinsics, project
from dream.crb import extrinsic_crb
from dream.errors import InputError
from dream.robot import load_robot
from dream.transforms import invert_T, look_at, transform_points
from plan.design import (
    information_table,
    mean_log_det,
    pose_information,
    predicted_sigmas,
    select_d_optimal,
)
from plan.ordering import order_poses, path_length

CAMERA = CameraIntrinsics(600.0, 600.0, 319.5, 239.5, 640, 480)
T_CAM_BASE = look_at(np.array([1.8, 0.4, 0.9]), np.array([0.0, 0.0, 0.4]))


@pytest.fixture(scope="module")
def panda_poses():
    """Keypoints (N, K, 3) of random Panda poses that the camera sees whole."""
    robot = load_robot("panda")
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.joint_lower, robot.joint_upper, (4000, robot.num_joints))
    P = robot.forward_kinematics(q)
    uv = project(CAMERA, transform_points(T_CAM_BASE, P))
    seen = np.all(CAMERA.in_image(uv), axis=1)
    return robot, q[seen][:200], P[seen][:200]


def test_docstring_examples():
    for module in (plan.design, plan.ordering):
        result = doctest.testmod(module)
        assert result.failed == 0 and result.attempted > 0


def test_information_is_the_inverse_of_the_cramer_rao_bound(panda_poses):
    _, _, P = panda_poses
    F = sum(pose_information(p, CAMERA, T_CAM_BASE, 2.0) for p in P[:5])
    crb = extrinsic_crb(P[:5].reshape(-1, 3), CAMERA, T_CAM_BASE, 2.0)
    assert np.allclose(np.linalg.inv(F), crb, rtol=1e-8, atol=1e-14)


def test_keypoints_behind_the_camera_or_outside_the_image_add_nothing():
    P = np.array([[0.0, 0.0, 0.4], [3.0, 1.0, 1.0], [0.0, 3.0, 0.4]])  # behind; outside
    assert transform_points(T_CAM_BASE, P[1:2])[0, 2] < 0
    assert not CAMERA.in_image(project(CAMERA, transform_points(T_CAM_BASE, P[2:])))[0]
    assert np.allclose(pose_information(P, CAMERA, T_CAM_BASE, 1.0),
                       pose_information(P[:1], CAMERA, T_CAM_BASE, 1.0))


def test_selection_finds_the_brute_force_optimum(panda_poses):
    _, _, P = panda_poses
    F = information_table(P[:10], CAMERA, T_CAM_BASE[None], 1.0)
    best = max(mean_log_det(F, list(c)) for c in itertools.combinations(range(10), 3))
    chosen = select_d_optimal(F, 3, rng=np.random.default_rng(1))
    assert mean_log_det(F, chosen) == pytest.approx(best, abs=1e-9)


def test_selection_beats_random_sets(panda_poses):
    _, _, P = panda_poses
    F = information_table(P, CAMERA, T_CAM_BASE[None], 1.0)
    chosen = select_d_optimal(F, 12, rng=np.random.default_rng(2))
    rng = np.random.default_rng(3)
    planned = predicted_sigmas(F[0, chosen].sum(0), T_CAM_BASE)["position_worst_m"]
    random = [predicted_sigmas(F[0, rng.choice(len(P), 12, replace=False)].sum(0),
                               T_CAM_BASE)["position_worst_m"] for _ in range(50)]
    assert len(set(chosen.tolist())) == 12
    assert planned < np.min(random)
    assert np.median(random) / planned > 1.5


def test_predicted_sigma_matches_the_calibration_scatter(panda_poses):
    """The worst-direction 1-sigma the plan predicts is what 60 noisy calibrations show."""
    robot, _, P = panda_poses
    noise_px = 2.0
    F = information_table(P[:8], CAMERA, T_CAM_BASE[None], noise_px)[0]
    predicted = predicted_sigmas(F.sum(0), T_CAM_BASE)
    uv_true = project(CAMERA, transform_points(T_CAM_BASE, P[:8]))
    rng = np.random.default_rng(4)
    names = tuple(str(i) for i in range(8))
    positions = []
    for _ in range(60):
        uv = uv_true + rng.normal(0, noise_px, uv_true.shape)
        obs = Observations(P[:8], uv, np.ones(uv.shape[:2]), names, robot.keypoint_names)
        positions.append(invert_T(calibrate_all(obs, CAMERA).fit.T_cam_base)[:3, 3])
    scatter = np.sqrt(np.linalg.eigvalsh(np.cov(np.array(positions).T))[-1])
    assert scatter == pytest.approx(predicted["position_worst_m"], rel=0.3)


def test_camera_samples_change_the_criterion(panda_poses):
    _, _, P = panda_poses
    from plan.camera_prior import CameraPrior

    prior = CameraPrior(CAMERA, T_CAM_BASE, 0.1, 0.05)
    samples = prior.samples(np.random.default_rng(5), 4)
    assert np.allclose(samples[0], T_CAM_BASE)
    moved = np.linalg.norm(invert_T(samples[1])[:3, 3] - invert_T(T_CAM_BASE)[:3, 3])
    assert 0.0 < moved < 0.6
    F = information_table(P[:20], CAMERA, samples, 1.0)
    assert F.shape == (4, 20, 6, 6)
    assert not np.allclose(F[0], F[1])


def test_selection_checks_its_input():
    with pytest.raises(InputError, match="cannot choose 5 of 3"):
        select_d_optimal(np.tile(np.eye(6), (1, 3, 1, 1)), 5)
    with pytest.raises(InputError, match="shape"):
        select_d_optimal(np.zeros((3, 6, 6)), 1)
    with pytest.raises(InputError, match="positive number of pixels"):
        pose_information(np.zeros((2, 3)), CAMERA, T_CAM_BASE, 0.0)


def test_singular_information_predicts_infinite_sigma():
    sigma = predicted_sigmas(np.zeros((6, 6)), T_CAM_BASE)
    assert sigma["position_worst_m"] == np.inf


def test_path_order_is_no_longer_than_nearest_neighbour_or_given_order():
    rng = np.random.default_rng(6)
    for _ in range(20):
        Q, start = rng.uniform(-2, 2, (10, 7)), rng.uniform(-2, 2, 7)
        order = order_poses(Q, start)
        assert sorted(order.tolist()) == list(range(10))
        assert path_length(Q, start, order) <= path_length(Q, start, np.arange(10)) + 1e-12


def test_a_colliding_move_is_avoided_when_another_order_exists():
    from plan.ordering import order_clear_moves

    Q, start = np.array([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]), np.zeros(2)
    blocked = {(1.0, 2.0), (2.0, 1.0)}   # the move between the first two poses collides

    def clearance(a, b):
        return -0.01 if (a[0], b[0]) in blocked else 0.1

    order, moves = order_clear_moves(Q, start, clearance, 0.01)
    assert order.tolist() != [0, 1, 2] and sorted(order.tolist()) == [0, 1, 2]
    assert np.all(moves >= 0.01)
    always, moves = order_clear_moves(Q, start, lambda a, b: -1.0, 0.01)
    assert sorted(always.tolist()) == [0, 1, 2] and np.all(moves < 0)


def test_path_order_matches_brute_force_on_small_sets():
    rng = np.random.default_rng(7)
    ratios = []
    for _ in range(10):
        Q, start = rng.uniform(-2, 2, (6, 3)), np.zeros(3)
        best = min(path_length(Q, start, np.array(p)) for p in itertools.permutations(range(6)))
        ratios.append(path_length(Q, start, order_poses(Q, start)) / best)
    assert max(ratios) < 1.1
    assert np.median(ratios) == pytest.approx(1.0)
