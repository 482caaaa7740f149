import numpy as np
import pytest
from scenes import CAMERA, random_scene
from test_pnp import xi_error

from dream.calibration import (
    Observations,
    calibrate_all,
    calibrate_each,
    frame_leave_outs,
    keypoint_jackknife,
    with_keypoint_jackknife,
)
from dream.camera import project
from dream.crb import extrinsic_crb
from dream.errors import CalibrationError, InputError
from dream.metrics import add_per_frame, auc, keypoint_errors, pose_errors
from dream.pnp import PoseFit, SolverSettings, apply_increment, increment_between, solve_pnp
from dream.transforms import T_from_rotvec_t, camera_position_covariance, invert_T, transform_points

Z95 = 1.959964


def test_95_percent_intervals_cover_the_truth_90_to_98_percent_of_the_time():
    rng = np.random.default_rng(7)
    covered, coverage_c = [], []
    for _ in range(120):
        obs, T, _ = random_scene(rng, 5, noise_px=rng.uniform(0.5, 2.0))
        fit = calibrate_all(obs, CAMERA, SolverSettings(ransac_hypotheses=10)).fit
        e = xi_error(fit.T_cam_base, T)
        sigma = np.sqrt(np.diag(fit.covariance))
        covered.extend(np.abs(e) <= Z95 * sigma)
        # the camera position in the base frame, propagated
        c_err = invert_T(fit.T_cam_base)[:3, 3] - invert_T(T)[:3, 3]
        sigma_c = np.sqrt(np.diag(camera_position_covariance(fit.T_cam_base, fit.covariance)))
        coverage_c.extend(np.abs(c_err) <= Z95 * sigma_c)
    assert 0.90 <= np.mean(covered) <= 0.98, np.mean(covered)
    assert 0.90 <= np.mean(coverage_c) <= 0.98, np.mean(coverage_c)


def test_crb_matches_monte_carlo_covariance():
    rng = np.random.default_rng(3)
    obs, T, uv_true = random_scene(rng, 10, noise_px=0.0)
    crb = extrinsic_crb(obs.P_base.reshape(-1, 3), CAMERA, T, 1.0)
    errors = []
    for _ in range(150):
        noisy = type(obs)(obs.P_base, uv_true + rng.normal(0, 1.0, uv_true.shape),
                          obs.confidence, obs.frame_names, obs.keypoint_names)
        fit = calibrate_all(noisy, CAMERA, SolverSettings(ransac_hypotheses=0)).fit
        errors.append(xi_error(fit.T_cam_base, T))
    mc = np.cov(np.array(errors).T)
    ratio = np.diag(mc) / np.diag(crb)
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio


def test_crb_rejects_unidentifiable_scenes():
    P = np.outer(np.linspace(0.1, 1, 5), [1.0, 0.5, 0.2])
    with pytest.raises(CalibrationError):
        extrinsic_crb(P, CAMERA, T_from_rotvec_t(np.zeros(3), [0, 0, 3.0]), 1.0)
    with pytest.raises(InputError):
        extrinsic_crb(P, CAMERA, np.eye(4), 0.0)


def test_auc_follows_dreams_definition():
    # All values at 0: AUC 1. All at half the range: the curve is 0 then 1 -> about 0.5.
    assert auc(np.zeros(10), 0.1, 1e-5) == pytest.approx(1.0, abs=1e-4)
    assert auc(np.full(10, 0.05), 0.1, 1e-5) == pytest.approx(0.5, abs=1e-3)
    assert auc(np.array([np.inf] * 5), 0.1, 1e-5) == 0.0
    # Uniform values on [0, 0.1]: the accuracy curve is the identity -> 0.5
    assert auc(np.linspace(0, 0.1, 10001), 0.1, 1e-5) == pytest.approx(0.5, abs=1e-3)
    # a failure halves the curve
    assert auc(np.array([0.0, np.inf]), 0.1, 1e-5) == pytest.approx(0.5, abs=1e-4)
    with pytest.raises(InputError):
        auc(np.array([np.nan]), 0.1, 1e-5)


def test_add_and_pose_errors():
    P = np.array([[[0.0, 0, 0], [0.1, 0, 0], [0, 0.2, 0.3]]] * 2)
    T = T_from_rotvec_t(np.array([0.1, 0.2, 0.3]), np.array([0.1, 0, 1.5]))
    shifted = T.copy()
    shifted[:3, 3] += [0.003, 0.004, 0.0]  # 5 mm everywhere
    add = add_per_frame(P, np.stack([shifted, np.full((4, 4), np.nan)]), np.stack([T, T]))
    assert add[0] == pytest.approx(0.005) and add[1] == np.inf
    t_err, r_err = pose_errors(shifted, T)
    assert t_err == pytest.approx(0.005) and r_err == pytest.approx(0.0, abs=1e-7)
    rotated = T_from_rotvec_t(np.array([0, 0, 0.01]), np.zeros(3)) @ T
    assert pose_errors(rotated, T)[1] == pytest.approx(0.01)


def test_keypoint_errors_count_missing_detections_as_failures():
    uv_true = np.zeros((1, 3, 2))
    uv_det = np.array([[[3.0, 4.0], [np.nan, np.nan], [100.0, 0.0]]])
    d = keypoint_errors(uv_det, uv_true, np.array([[True, True, False]]))
    assert d.tolist() == [5.0, np.inf]


def _position_coverage(T_est, T_true, covariance):
    c_err = invert_T(T_est)[:3, 3] - invert_T(T_true)[:3, 3]
    C = camera_position_covariance(T_est, covariance)
    return float(c_err @ np.linalg.solve(C, c_err)) <= CHI2_3_95, np.sqrt(np.trace(C))


CHI2_3_95 = 7.8147   # 95 % quantile of chi-square with 3 degrees of freedom


def _biased_scene(rng, bias_m):
    """A random scene whose keypoint j is seen displaced by the same base-frame offset b_j in
    every frame (a detector's error that more frames do not average out), plus 1 px noise."""
    obs, T, _ = random_scene(rng, 10)
    b = rng.normal(0, bias_m, (1, obs.P_base.shape[1], 3))
    uv = project(CAMERA, transform_points(T, obs.P_base + b)) + rng.normal(0, 1.0, obs.uv.shape)
    return Observations(obs.P_base, uv, obs.confidence, obs.frame_names, obs.keypoint_names), T


def test_keypoint_jackknife_covers_errors_a_keypoint_repeats_across_frames():
    rng = np.random.default_rng(11)
    settings = SolverSettings(ransac_hypotheses=10)
    fit_covered, total_covered = [], []
    for _ in range(30):
        obs, T = _biased_scene(rng, 0.02)
        result = with_keypoint_jackknife(calibrate_all(obs, CAMERA, settings), obs, CAMERA,
                                         settings)
        assert result.jackknife is not None and len(result.jackknife.left_out) == 7
        np.testing.assert_allclose(result.covariance,
                                   result.fit.covariance + result.jackknife.covariance)
        fit_covered.append(_position_coverage(result.fit.T_cam_base, T, result.fit.covariance)[0])
        total_covered.append(_position_coverage(result.fit.T_cam_base, T, result.covariance)[0])
    # the fit's covariance assumes independent errors: far too small here
    assert np.mean(fit_covered) < 0.5, np.mean(fit_covered)
    assert np.mean(total_covered) >= 0.8, np.mean(total_covered)


def test_keypoint_jackknife_with_independent_errors_about_doubles_the_variance():
    # with independent errors the jackknife estimates the fit's own variance again, so the
    # sum's sigma is about sqrt(2) times the fit's (the safe side)
    rng = np.random.default_rng(12)
    settings = SolverSettings(ransac_hypotheses=10)
    ratios = []
    for _ in range(30):
        obs, T, _ = random_scene(rng, 10, noise_px=1.0)
        result = with_keypoint_jackknife(calibrate_all(obs, CAMERA, settings), obs, CAMERA,
                                         settings)
        ratios.append(_position_coverage(result.fit.T_cam_base, T, result.covariance)[1]
                      / _position_coverage(result.fit.T_cam_base, T, result.fit.covariance)[1])
    assert 1.2 <= np.median(ratios) <= 1.7, np.median(ratios)


def test_keypoint_jackknife_needs_three_keypoints_and_an_all_frames_result():
    rng = np.random.default_rng(13)
    obs, _, _ = random_scene(rng, 10, keypoints=7, noise_px=1.0)
    two = Observations(obs.P_base, obs.uv, np.where(np.arange(7) < 2, 1.0, 0.0)[None].repeat(10, 0),
                       obs.frame_names, obs.keypoint_names)
    result = calibrate_all(two, CAMERA, SolverSettings(ransac_hypotheses=10))
    assert keypoint_jackknife(result, two, CAMERA) is None
    assert with_keypoint_jackknife(result, two, CAMERA) is result
    assert result.covariance is result.fit.covariance
    each = calibrate_each(obs, CAMERA)
    with pytest.raises(InputError, match="all-frames"):
        keypoint_jackknife(each, obs, CAMERA)


def _heavy_tailed_scene(rng, frames, share=0.3, extra_px=4.0):
    """A random scene with 0.5 px noise on every detection and `share` of them `extra_px`
    (per axis, Gaussian) further off: a network's occasional misplaced keypoint."""
    obs, T, _ = random_scene(rng, frames, noise_px=0.5)
    hit = rng.random(obs.uv.shape[:2]) < share
    uv = obs.uv + np.where(hit[..., None], rng.normal(0, extra_px, obs.uv.shape), 0.0)
    return Observations(obs.P_base, uv, obs.confidence, obs.frame_names, obs.keypoint_names), T


def test_each_frames_jackknife_covers_a_misplaced_keypoint():
    rng = np.random.default_rng(15)
    fit_covered, total_covered = [], []
    for _ in range(10):
        obs, T = _heavy_tailed_scene(rng, 20)
        result = calibrate_each(obs, CAMERA)
        for frame in result.frames:
            assert frame.jackknife is not None and len(frame.jackknife.left_out) == 7
            np.testing.assert_allclose(frame.covariance,
                                       frame.fit.covariance + frame.jackknife.covariance)
            fit_covered.append(_position_coverage(frame.fit.T_cam_base, T,
                                                  frame.fit.covariance)[0])
            total_covered.append(_position_coverage(frame.fit.T_cam_base, T,
                                                    frame.covariance)[0])
    # a frame's fit down-weights its misplaced keypoint and states too small a spread
    # (this seed: 0.76 of the 200 frames covered); with the jackknife 0.965
    assert np.mean(fit_covered) < 0.85, np.mean(fit_covered)
    assert np.mean(total_covered) >= 0.9, np.mean(total_covered)


def test_frame_jackknife_is_the_spread_of_the_leave_one_out_solutions():
    rng = np.random.default_rng(16)
    obs, _ = _heavy_tailed_scene(rng, 3)
    result = calibrate_each(obs, CAMERA)
    for f, frame in enumerate(result.frames):
        xis = []
        for k in range(7):
            confidence = obs.confidence[f].copy()
            confidence[k] = 0.0
            fit = solve_pnp(obs.P_base[f], obs.uv[f], CAMERA, confidence=confidence)
            xis.append(increment_between(frame.fit.T_cam_base, fit.T_cam_base))
        d = np.array(xis) - np.mean(xis, axis=0)
        np.testing.assert_allclose(frame.jackknife.covariance, 6 / 7 * d.T @ d, rtol=1e-6,
                                   atol=1e-15)
        assert frame.jackknife.left_out == obs.keypoint_names


def test_each_mode_reports_the_best_frame_with_a_jackknife():
    rng = np.random.default_rng(17)
    obs, _ = _heavy_tailed_scene(rng, 6)
    # frame 0: four exact keypoints, a fit of almost no spread but no jackknife (three left)
    uv = obs.uv.copy()
    uv[0] = project(CAMERA, transform_points(random_scene(rng, 1)[1], obs.P_base[0]))
    confidence = obs.confidence.copy()
    confidence[0, 4:] = 0.0
    sparse = Observations(obs.P_base, uv, confidence, obs.frame_names, obs.keypoint_names)
    result = calibrate_each(sparse, CAMERA)
    assert isinstance(result.frames[0].fit, PoseFit) and result.frames[0].jackknife is None
    traces = [np.trace(f.covariance) for f in result.frames]
    assert np.argmin(traces) == 0          # the fit alone would pick the sparse frame
    best = 1 + int(np.argmin(traces[1:]))
    assert result.fit is result.frames[best].fit
    assert result.jackknife is result.frames[best].jackknife
    np.testing.assert_allclose(result.covariance, result.frames[best].covariance)
    # no frame with a jackknife: the fit's covariance decides
    four = Observations(obs.P_base, obs.uv, np.where(np.arange(7) < 4, 1.0, 0.0)[None]
                        .repeat(6, 0), obs.frame_names, obs.keypoint_names)
    result = calibrate_each(four, CAMERA)
    assert result.jackknife is None
    assert all(f.jackknife is None for f in result.frames)
    assert result.fit is min((f.fit for f in result.frames), key=lambda f: np.trace(f.covariance))
    with pytest.raises(InputError, match="frame solutions"):
        frame_leave_outs(obs, result.frames[:2], [CAMERA] * 6)


def test_increment_between_inverts_the_solver_update():
    rng = np.random.default_rng(14)
    for _ in range(20):
        T = T_from_rotvec_t(rng.normal(0, 1, 3), rng.normal(0, 1, 3))
        xi = rng.normal(0, 0.3, 6)
        np.testing.assert_allclose(increment_between(T, apply_increment(T, xi)), xi, atol=1e-12)
