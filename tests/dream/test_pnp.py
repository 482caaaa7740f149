"""Random pose -> project -> solve -> compare, single and multi-frame, with noise and outliers."""

import numpy as np
import pytest
from scenes import CAMERA, random_scene

from dream.calibration import Observations, calibrate_all, calibrate_each
from dream.crb import extrinsic_crb
from dream.errors import CalibrationError, InputError
from dream.pnp import (
    NoSolution,
    PoseFit,
    SolverSettings,
    fit_pose,
    increment_between,
    refine_pose,
    solve_pnp,
    solve_pnp_batch,
)

DISTORTED = CAMERA.with_distortion((0.12, -0.2, 0.001, -0.002, 0.05))


def xi_error(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """xi = (rot, trans) such that T_true = (exp(rot) R_est, t_est + trans)."""
    return increment_between(T_est, T_true)


@pytest.mark.parametrize("camera", [CAMERA, DISTORTED])
def test_single_frame_exact_without_noise(camera, rng):
    for _ in range(20):
        obs, T, _ = random_scene(rng, 1, keypoints=7, camera=camera)
        fit = solve_pnp(obs.P_base[0], obs.uv[0], camera)
        assert isinstance(fit, PoseFit)
        assert np.abs(xi_error(fit.T_cam_base, T)).max() < 1e-9
        assert fit.rmse_px < 1e-8


@pytest.mark.parametrize("camera", [CAMERA, DISTORTED])
def test_multi_frame_exact_without_noise(camera, rng):
    for _ in range(5):
        obs, T, _ = random_scene(rng, 10, camera=camera)
        result = calibrate_all(obs, camera)
        assert np.abs(xi_error(result.fit.T_cam_base, T)).max() < 1e-9
        assert result.fit.num_inliers == 70


def test_noisy_errors_are_within_the_cramer_rao_bound(rng):
    # Mahalanobis distance of the error under the CRB: E[e^T CRB^-1 e] = 6 for an efficient
    # estimator; allow sampling spread of 40 trials.
    for frames in (1, 20):
        d2 = []
        for _ in range(40):
            obs, T, _ = random_scene(rng, frames, noise_px=1.0)
            result = calibrate_all(obs, CAMERA, SolverSettings(ransac_hypotheses=20))
            crb = extrinsic_crb(obs.P_base.reshape(-1, 3), CAMERA, T, 1.0)
            e = xi_error(result.fit.T_cam_base, T)
            d2.append(e @ np.linalg.solve(crb, e))
        ratio = np.mean(d2) / 6.0
        assert ratio < 1.5, (frames, ratio)


def test_thirty_percent_outliers_stay_within_twice_the_clean_error(rng):
    clean, dirty = [], []
    for trial in range(15):
        seed = 1000 + trial
        obs, T, _ = random_scene(np.random.default_rng(seed), 20, noise_px=1.0)
        obs_bad, T_bad, _ = random_scene(np.random.default_rng(seed), 20, noise_px=1.0,
                                         outlier_fraction=0.3)
        assert np.allclose(T, T_bad)
        clean.append(np.linalg.norm(xi_error(calibrate_all(obs, CAMERA).fit.T_cam_base, T)[3:]))
        bad = calibrate_all(obs_bad, CAMERA)
        dirty.append(np.linalg.norm(xi_error(bad.fit.T_cam_base, T)[3:]))
        # the random pixels are rejected, the true keypoints kept
        assert bad.fit.num_inliers <= 0.8 * 140
    assert np.sqrt(np.mean(np.square(dirty))) <= 2.0 * np.sqrt(np.mean(np.square(clean)))


def test_wrong_detection_in_a_single_frame_is_rejected(rng):
    obs, T, _ = random_scene(rng, 1, keypoints=7, noise_px=0.5)
    uv = obs.uv[0].copy()
    uv[3] += [80.0, -60.0]
    fit = solve_pnp(obs.P_base[0], uv, CAMERA)
    assert isinstance(fit, PoseFit)
    assert not fit.inlier[3] and fit.inlier.sum() == 6
    assert np.linalg.norm(fit.T_cam_base[:3, 3] - T[:3, 3]) < 0.05


def test_too_few_and_degenerate_keypoints_give_no_solution(rng):
    obs, _, _ = random_scene(rng, 1, keypoints=7)
    uv = obs.uv[0].copy()
    uv[3:] = np.nan
    result = solve_pnp(obs.P_base[0], uv, CAMERA)
    assert isinstance(result, NoSolution) and "3 usable keypoints" in result.reason
    line = np.outer(np.linspace(0, 1, 6), [0.1, 0.2, 0.3])
    result = solve_pnp(line, np.full((6, 2), 100.0), CAMERA)
    assert isinstance(result, NoSolution) and "collinear" in result.reason


def test_rejection_that_would_leave_too_few_keypoints_keeps_the_last_fit(rng):
    # One of five keypoints is wrong, but five are needed: rejecting it would leave a set that
    # cannot fix a pose, so the rejection stops and the (robust) fit of all five stands.
    obs, T, _ = random_scene(rng, 1, keypoints=5)
    uv = obs.uv[0].copy()
    uv[2] += [40.0, 30.0]
    settings = SolverSettings(min_keypoints=5)
    fit = fit_pose(obs.P_base[0], uv, CAMERA, T, settings=settings)
    assert isinstance(fit, PoseFit) and fit.inlier.all()
    others = np.delete(fit.residuals_px, 2, axis=0)
    assert np.linalg.norm(fit.residuals_px[2]) > 10 > np.linalg.norm(others, axis=1).max()
    # with four allowed, the wrong keypoint goes and the pose is exact again
    fit = fit_pose(obs.P_base[0], uv, CAMERA, T)
    assert isinstance(fit, PoseFit) and fit.inlier.sum() == 4 and not fit.inlier[2]
    assert np.abs(xi_error(fit.T_cam_base, T)).max() < 1e-9


@pytest.mark.parametrize("rounds", [0, 1, 3])
def test_the_pose_is_the_fit_of_the_keypoints_it_reports_as_inliers(rounds):
    """The last round of rejection has no refit after it, so it must not reject: the pose, the
    inliers, weights and RMSE all describe one fit (single-frame and batch solvers)."""
    settings = SolverSettings(outlier_rounds=rounds)
    P, uv, checked = [], [], 0
    for seed in range(30):
        obs, T, _ = random_scene(np.random.default_rng(seed), 1, keypoints=20, noise_px=1.0,
                                 outlier_fraction=0.3)
        P.append(obs.P_base[0])
        uv.append(obs.uv[0])
        from_truth = fit_pose(obs.P_base[0], obs.uv[0], CAMERA, T, settings=settings)
        assert isinstance(from_truth, PoseFit)
        solved = solve_pnp(obs.P_base[0], obs.uv[0], CAMERA, settings=settings)
        for fit in (from_truth, solved) if isinstance(solved, PoseFit) else (from_truth,):
            checked += 1
            k = fit.inlier
            refit, _, _ = refine_pose(obs.P_base[0][k], obs.uv[0][k], CAMERA,
                                      fit.T_cam_base, np.ones(k.sum()), settings)
            assert np.abs(increment_between(fit.T_cam_base, refit)).max() < 1e-9
    assert checked >= 50
    for fit, P_f, uv_f in zip(solve_pnp_batch(np.array(P), np.array(uv), [CAMERA] * len(P),
                                              settings=settings), P, uv, strict=True):
        _same_fit(solve_pnp(P_f, uv_f, CAMERA, settings=settings), fit)


def test_solver_settings_and_the_start_pose_are_checked(rng):
    for bad in ({"initial_damping": 0.0}, {"step_tolerance": float("nan")},
                {"max_condition": -1.0}, {"collinear_ratio": float("inf")},
                {"max_iterations": 0}, {"ransac_hypotheses": -1}, {"outlier_rounds": -1},
                {"seed": -5}):
        with pytest.raises(InputError, match=next(iter(bad))):
            SolverSettings(**bad)
    obs, T, _ = random_scene(rng, 1)
    for T_init in (np.full((4, 4), np.nan), T[:3, :3]):
        with pytest.raises(InputError, match="T_init must be a finite 4x4 transform"):
            fit_pose(obs.P_base[0], obs.uv[0], CAMERA, T_init)
        with pytest.raises(InputError, match="T_cam_base must be a finite 4x4 transform"):
            extrinsic_crb(obs.P_base[0], CAMERA, T_init, 1.0)


def test_multi_frame_with_three_keypoints_per_frame_still_solves(rng):
    # No frame can be solved alone, yet all frames together fix the pose.
    obs, T, _ = random_scene(rng, 10, keypoints=3, noise_px=0.0)
    result = calibrate_all(obs, CAMERA)
    assert all(isinstance(f.fit, NoSolution) for f in result.frames)
    assert np.abs(xi_error(result.fit.T_cam_base, T)).max() < 1e-9


def test_calibrate_with_nothing_usable_raises(rng):
    obs, _, _ = random_scene(rng, 3)
    empty = Observations(obs.P_base, np.full(obs.uv.shape, np.nan), obs.confidence,
                         obs.frame_names, obs.keypoint_names)
    with pytest.raises(CalibrationError, match="usable keypoints"):
        calibrate_all(empty, CAMERA)
    with pytest.raises(CalibrationError):
        calibrate_each(empty, CAMERA)


def test_each_mode_solves_every_frame(rng):
    obs, T, _ = random_scene(rng, 5, noise_px=0.0)
    result = calibrate_each(obs, CAMERA)
    for i in range(5):
        assert np.allclose(result.T_cam_base_of_frame(i), T, atol=1e-9)


def test_confidence_weights_downweight_bad_keypoints(rng):
    obs, T, _ = random_scene(rng, 10, noise_px=0.0)
    uv = obs.uv.copy()
    uv[:, 0] += 1.2  # a biased keypoint, inside the 2 px minimum inlier threshold
    conf = np.ones(obs.confidence.shape)
    conf[:, 0] = 1e-3
    biased = Observations(obs.P_base, uv, np.ones_like(conf), obs.frame_names,
                          obs.keypoint_names)
    weighted = Observations(obs.P_base, uv, conf, obs.frame_names, obs.keypoint_names)
    fit_biased = calibrate_all(biased, CAMERA).fit
    fit_weighted = calibrate_all(weighted, CAMERA).fit
    assert fit_biased.inlier.reshape(10, 7)[:, 0].sum() >= 8  # mostly kept: it drags the fit
    e_biased = np.linalg.norm(xi_error(fit_biased.T_cam_base, T))
    e_weighted = np.linalg.norm(xi_error(fit_weighted.T_cam_base, T))
    assert e_weighted < 0.5 * e_biased


@pytest.mark.parametrize("points", [9, 600])      # OpenCV's path, numpy's (many points)
@pytest.mark.parametrize("camera", [CAMERA, DISTORTED])
def test_pose_jacobian_matches_finite_differences(camera, points, rng):
    from scenes import random_extrinsic

    from dream.pnp import apply_increment, linearise

    T = random_extrinsic(rng)
    P_base = rng.uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (points, 3))
    uv = rng.uniform([0, 0], [camera.width, camera.height], (points, 2))
    e, J = linearise(P_base, uv, camera, T)
    eps = 1e-7
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        e_plus, _ = linearise(P_base, uv, camera, apply_increment(T, d))
        e_minus, _ = linearise(P_base, uv, camera, apply_increment(T, -d))
        assert np.allclose(J[:, :, k], (e_plus - e_minus) / (2 * eps), rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("camera", [CAMERA, DISTORTED])
def test_many_points_linearise_as_opencv_does(camera, rng, monkeypatch):
    """numpy's chain rule (many points) gives OpenCV's residuals and Jacobian (a few), and
    `reprojected` its pixels."""
    from scenes import random_extrinsic

    import dream.pnp.reprojection as reprojection

    T = random_extrinsic(rng)
    n = reprojection.COMPILED_BELOW_POINTS + 10
    P_base = rng.uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (n, 3))
    uv = rng.uniform([0, 0], [camera.width, camera.height], (n, 2))
    e_numpy, J_numpy = reprojection.linearise(P_base, uv, camera, T)
    monkeypatch.setattr(reprojection, "COMPILED_BELOW_POINTS", n + 1)
    e_cv, J_cv = reprojection.linearise(P_base, uv, camera, T)
    assert np.allclose(e_numpy, e_cv, rtol=0, atol=1e-9)
    assert np.allclose(J_numpy, J_cv, rtol=1e-12, atol=1e-9)
    assert np.allclose(reprojection.reprojected(P_base, camera, T), e_cv + uv, rtol=0,
                       atol=1e-9)
    behind = P_base.copy()
    behind[0] = T[:3, :3].T @ (np.array([0.0, 0.0, -1.0]) - T[:3, 3])
    assert reprojection.reprojected(behind, camera, T) is None


def _hard_frames(rng, frames: int, keypoints: int = 8):
    """Frames that take every path of the single-frame solver: noise, wrong detections (leave-
    one-out), missing keypoints, too few keypoints, collinear points, a start behind the camera,
    each frame with its own camera (a third distorted)."""
    P, uv, conf, cameras = [], [], [], []
    for f in range(frames):
        camera = CAMERA if f % 3 else DISTORTED
        camera = camera.with_distortion(camera.distortion) if f % 2 else \
            type(camera)(camera.fx * (1 + 0.1 * f / frames), camera.fy, camera.cx, camera.cy,
                         camera.width, camera.height, camera.distortion)
        obs, _, _ = random_scene(rng, 1, keypoints=keypoints, camera=camera,
                                 noise_px=float(rng.choice([0.3, 1.0, 3.0])),
                                 outlier_fraction=float(rng.choice([0.0, 0.15, 0.3])))
        P_f, uv_f = obs.P_base[0].copy(), obs.uv[0].copy()
        uv_f[rng.random(keypoints) < 0.1] = np.nan
        if f % 11 == 5:
            uv_f[3:] = np.nan                                  # too few keypoints
        if f % 11 == 7:
            P_f = np.outer(np.linspace(0, 1, keypoints), [0.1, 0.2, 0.3])   # collinear
        P.append(P_f), uv.append(uv_f), cameras.append(camera)
        conf.append(rng.uniform(0.1, 1.0, keypoints))
    return np.array(P), np.array(uv), np.array(conf), cameras


def _same_fit(a, b) -> None:
    assert type(a) is type(b)
    if isinstance(a, NoSolution):
        assert a.reason == b.reason
        return
    assert np.array_equal(a.inlier, b.inlier) and a.iterations == b.iterations
    np.testing.assert_allclose(b.T_cam_base, a.T_cam_base, rtol=0, atol=1e-10)
    np.testing.assert_allclose(b.residuals_px, a.residuals_px, rtol=0, atol=1e-7)
    np.testing.assert_allclose(b.weights, a.weights, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-7,
                               atol=1e-9 * np.abs(a.covariance).max())
    assert b.rmse_px == pytest.approx(a.rmse_px, rel=1e-9, abs=1e-12)


def test_batch_solve_equals_solving_each_frame_alone(rng):
    P, uv, conf, cameras = _hard_frames(rng, 60)
    batch = solve_pnp_batch(P, uv, cameras, confidence=conf)
    alone = [solve_pnp(P[f], uv[f], cameras[f], confidence=conf[f]) for f in range(len(P))]
    assert sum(isinstance(a, NoSolution) for a in alone) >= 8        # the failure paths ran
    assert sum(isinstance(a, PoseFit) and not a.inlier[np.isfinite(uv[f, :, 0])].all()
               for f, a in enumerate(alone)) >= 5                    # and outlier rejection
    for a, b in zip(alone, batch, strict=True):
        _same_fit(a, b)
    # one camera for every frame, no confidences (dream calibrate's usual call)
    batch = solve_pnp_batch(P[:20], uv[:20], [CAMERA] * 20)
    for f, b in enumerate(batch):
        _same_fit(solve_pnp(P[f], uv[f], CAMERA), b)


def test_batch_start_behind_the_camera_matches_single(rng):
    # frame 1: one keypoint moved behind the camera (its detection kept): no pose can explain
    # it, and every hypothesis leaves it behind the camera
    obs, T, _ = random_scene(rng, 2, keypoints=7)
    P = obs.P_base.copy()
    P_cam = P[1, 0] @ T[:3, :3].T + T[:3, 3]
    P[1, 0] = (-P_cam - T[:3, 3]) @ T[:3, :3]
    fits = solve_pnp_batch(P, obs.uv, [CAMERA, CAMERA])
    assert isinstance(fits[0], PoseFit)
    assert isinstance(fits[1], NoSolution) and "behind the camera" in fits[1].reason
    for f in range(2):
        _same_fit(solve_pnp(P[f], obs.uv[f], CAMERA), fits[f])


def test_batch_solve_checks_its_shapes(rng):
    obs, _, _ = random_scene(rng, 2, keypoints=6)
    with pytest.raises(InputError, match="1 cameras for 2 frames"):
        solve_pnp_batch(obs.P_base, obs.uv, [CAMERA])
    with pytest.raises(InputError, match="expected \\(2, 6, 2\\)"):
        solve_pnp_batch(obs.P_base, obs.uv[:, :5], [CAMERA] * 2)
    with pytest.raises(InputError, match="confidence"):
        solve_pnp_batch(obs.P_base, obs.uv, [CAMERA] * 2, confidence=np.ones(6))
    assert solve_pnp_batch(np.zeros((0, 6, 3)), np.zeros((0, 6, 2)), []) == []


def test_damped_step_matches_numpy_also_where_cholesky_fails(rng):
    """The single-frame LM step (OpenCV's Cholesky, numpy's LU where that fails) solves
    (H + diag(d)) xi = -g as numpy does, for a positive definite and an indefinite matrix."""
    from dream.optim import solve_damped

    J = rng.normal(size=(14, 6))
    g = rng.normal(size=6)
    for H in (J.T @ J, np.diag([1.0, -2.0, 3.0, 1.0, 1.0, 1.0])):
        d = np.full(6, 1e-3)
        np.testing.assert_allclose(solve_damped(H, d, g), np.linalg.solve(H + np.diag(d), -g),
                                   rtol=1e-10)


def test_degeneracy_matches_the_singular_value_ratio(rng):
    """The collinearity test (eigenvalues of the 3 x 3 scatter) agrees with the ratio of the
    centred points' singular values on both sides of the threshold."""
    from dream.pnp import SolverSettings, degeneracy

    settings = SolverSettings()
    direction = rng.normal(size=3)
    outcomes = set()
    for spread in (1e-5, 5e-4, 2e-3, 1e-1):
        P = np.outer(np.linspace(-0.5, 0.5, 6), direction) + spread * rng.normal(size=(6, 3))
        s = np.linalg.svd(P - P.mean(0), compute_uv=False)
        expected = bool(s[1] / s[0] < settings.collinear_ratio)
        assert (degeneracy(P, settings) is not None) == expected
        outcomes.add(expected)
    assert outcomes == {True, False}
    assert degeneracy(np.zeros((6, 3)), settings) is not None              # coincident


def test_single_frame_covariance_matches_the_batch_one(rng):
    """The single-frame covariance (OpenCV's eigensolver, scalar bookkeeping) equals the batch
    one (numpy's), also without redundancy (3 keypoints: NaN); a singular J^T W J is beyond
    `max_condition` in both."""
    from dream.pnp.batch import _covariance
    from dream.pnp.single import _covariance_one

    J = rng.normal(size=(7, 2, 6))
    for e, J_, w in ((rng.normal(size=(7, 2)), J, rng.uniform(0.2, 1, 7)),
                     (rng.normal(size=(3, 2)), J[:3], np.ones(3))):
        cov_one, cond_one = _covariance_one(e, J_, w)
        cov, cond = _covariance(e[None], J_[None], w[None])
        np.testing.assert_allclose(cov_one, cov[0], rtol=1e-9, equal_nan=True,
                                   atol=1e-12 * np.nanmax(np.abs(cov[0]), initial=0.0))
        assert cond_one == pytest.approx(float(cond[0]), rel=1e-9)
    assert np.isnan(cov_one).all()
    J[..., 5] = J[..., 4]                                    # two equal columns: singular
    e = rng.normal(size=(7, 2))
    limit = SolverSettings().max_condition
    assert _covariance_one(e, J, np.ones(7))[1] > limit
    assert _covariance(e[None], J[None], np.ones((1, 7)))[1][0] > limit
