"""The keypoint path's principal-point check: given cx, cy 24, -16 px off (640x480, fx 600),
exact labels calibrated `good` 2.9 deg off; the right principal point passes without a word."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from dream.camera import CameraIntrinsics, project
from dream.cli import main
from dream.cli.intrinsics_records import intrinsics_checks, with_keypoint_intrinsics
from dream.coarse.focal import with_focal_scale
from dream.coarse.principal import with_principal_shift
from dream.focal_check import focal_fit
from dream.inject import InjectionSettings, make_injected_sequence
from dream.io import write_dream
from dream.keypoint_camera_fit import focal_columns, principal_columns
from dream.metrics import pose_errors
from dream.pipeline import calibrate, observations_from_labels, robot_for, truth_poses
from dream.pnp import increment_between
from dream.principal_check import keypoint_principal, keypoint_principal_finding, principal_fit
from dream.quality import result_quality
from dream.refinement_document import written_quality
from dream.result import result_to_dict
from dream.transforms import look_at, transform_points

CAMERA = CameraIntrinsics(600.0, 600.0, 319.5, 239.5, 640, 480)
CHI2_6DOF_95 = 12.592     # 95 % quantile of the chi-square distribution with 6 degrees of freedom
BIAS, NOISE = 2.0, 0.5    # px: each keypoint name's bias (1-sigma) and each detection's noise


def _scene(shift):
    seq = make_injected_sequence(InjectionSettings(num_frames=40, seed=12))
    return seq.with_fixed_camera(with_principal_shift(seq.camera, shift))


@pytest.mark.parametrize("seed", range(5))
def test_random_pose_project_and_fit_asks_for_the_shift_back(seed):
    """Random pose and shift -> project through the shifted camera -> fit from the given
    camera at a pose a little off -> the shift and the pose back."""
    rng = np.random.default_rng(seed)
    T = look_at(rng.uniform([1.0, -1.0, 0.3], [2.0, 1.0, 1.2]),
                rng.uniform([-0.1, -0.1, 0.2], [0.1, 0.1, 0.5]))
    P = rng.uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (80, 3))
    shift = rng.uniform(-30.0, 30.0, 2)
    uv = project(with_principal_shift(CAMERA, shift), transform_points(T, P))
    T_start = T.copy()
    T_start[:3, 3] += rng.normal(0.0, 0.02, 3)
    fitted, covariance, T_fit = principal_fit().fit(P, uv, CAMERA, T_start)
    assert fitted == pytest.approx(shift, abs=1e-6)
    assert np.all(np.diag(covariance) < 1e-12)
    m, rad = pose_errors(T_fit, T)
    # the fit stops at its step tolerance: 1e-7 rad turns a pixel by 6e-5 px at fx 600 (the
    # last steps' rounding differs between CPUs' vector units: 2.1e-8 rad on one of them)
    assert m < 1e-8 and rad < 1e-7


@pytest.mark.parametrize("fit, columns, p", [
    (principal_fit(), principal_columns, np.array([5.0, -3.0])),
    (focal_fit(), focal_columns, np.array([0.05])),
])
def test_the_parameter_columns_are_the_projections_derivatives(fit, columns, p):
    """The exact columns against central differences of the projection through camera_at."""
    rng = np.random.default_rng(3)
    P_cam = rng.uniform([-0.5, -0.4, 1.0], [0.5, 0.4, 2.5], (20, 3))
    step = 1e-5
    numeric = np.stack([(project(fit.camera_at(CAMERA, p + step * e), P_cam)
                         - project(fit.camera_at(CAMERA, p - step * e), P_cam)) / (2 * step)
                        for e in np.eye(len(p))], axis=-1)
    at = fit.camera_at(CAMERA, p)
    assert columns(project(at, P_cam), at) == pytest.approx(numeric, abs=1e-5)


def test_the_jackknife_needs_enough_names():
    rng = np.random.default_rng(0)
    T = look_at(np.array([1.5, 0.2, 0.8]), np.array([0.0, 0.0, 0.4]))
    P = rng.uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (60, 3))
    uv = project(CAMERA, transform_points(T, P)) + rng.normal(0.0, 1.0, (60, 2))
    names = np.arange(60) % 6
    fit = principal_fit()
    assert fit.jackknife(P, uv, names, CAMERA, T, min_groups=7) is None
    spread = fit.jackknife(P, uv, names, CAMERA, T, min_groups=3)
    assert spread.shape == (2, 2) and np.all(np.diag(spread) > 0)


def test_a_point_behind_the_camera_gives_no_answer():
    P = np.array([[0.0, 0.0, -1.0]] * 10)
    assert principal_fit().fit(P, np.zeros((10, 2)), CAMERA, np.eye(4)) is None


@pytest.mark.parametrize("shift", [(0.0, 0.0), (24.0, -16.0)])
def test_the_keypoints_ask_for_the_principal_point_they_were_seen_with(shift):
    seq = _scene(shift)
    robot = robot_for(seq, None)
    obs = observations_from_labels(seq, robot)
    result = calibrate(seq, obs, "all")
    principal = keypoint_principal(result, obs, seq.camera)
    assert principal.shift_px == pytest.approx(-np.array(shift), abs=3.0)
    assert principal.sigma_jackknife_px is not None
    assert np.all(principal.sigma_px >= principal.sigma_fit_px)
    finding = keypoint_principal_finding(principal, seq.camera)
    assert (finding is None) == (shift == (0.0, 0.0))
    if finding is not None:        # the fit alone: `good`, the camera turned about 2.9 deg
        assert result_quality(result, obs).verdict == "good"
        assert np.rad2deg(pose_errors(result.T_cam_base, truth_poses(seq)[0])[1]) > 2.0


def test_a_wrong_focal_length_is_not_read_as_a_wrong_principal_point():
    seq = make_injected_sequence(InjectionSettings(num_frames=40, seed=12))
    seq = seq.with_fixed_camera(with_focal_scale(seq.camera, 1.1))
    robot = robot_for(seq, None)
    obs = observations_from_labels(seq, robot)
    principal = keypoint_principal(calibrate(seq, obs, "all"), obs, seq.camera)
    assert keypoint_principal_finding(principal, seq.camera) is None


def test_calibrate_says_the_principal_point_is_off(tmp_path, capsys):
    for name, shift in (("right", (0.0, 0.0)), ("wrong", (24.0, -16.0))):
        write_dream(_scene(shift), tmp_path / name)
        out = tmp_path / f"{name}.json"
        assert main(["calibrate", "--data", str(tmp_path / name), "--use-labels", "--refine",
                     "none", "--out", str(out)]) == 0
        printed = capsys.readouterr().out
        doc = json.loads(out.read_text())
        assert doc["keypoint_principal"]["agrees"] == (name == "right")
        assert doc["quality"]["verdict"] == ("good" if name == "right" else "check")
        assert ("the principal point moved by" in printed) == (name == "wrong")


def test_detections_that_fix_nothing_beyond_the_pose_give_no_check(tmp_path):
    """Three distinct points seen again and again (a detector that finds the same few pixels
    in every frame, as on a rendered scene whose keypoint fit lay 1.6 m off) fix fewer
    unknowns than the fit has and leave no residual: no 1-sigma, so neither check answers
    (`dream calibrate` wrote an infinite focal 1-sigma into RESULT.json there and failed)."""
    rng = np.random.default_rng(1)
    T = look_at(np.array([1.5, 0.2, 0.8]), np.array([0.0, 0.0, 0.4]))
    P = np.repeat(rng.uniform([-0.4, -0.4, 0.0], [0.4, 0.4, 0.9], (3, 3)), 16, axis=0)
    uv = project(with_principal_shift(CAMERA, [4.0, -3.0]), transform_points(T, P))
    for detections in (uv, uv + rng.normal(0.0, 3.0, uv.shape)):    # exact, and scattered
        assert principal_fit().fit(P, detections, CAMERA, T) is None
        assert focal_fit().fit(P, detections, with_focal_scale(CAMERA, 1.05), T) is None


def _biased(seq, seed: int):
    """The labels with a bias of `BIAS` (1-sigma) on each keypoint name and `NOISE` on each
    detection: a detector whose errors hide a principal point 24, -16 px off."""
    robot = robot_for(seq, None)
    obs = observations_from_labels(seq, robot)
    rng = np.random.default_rng(seed)
    bias = rng.normal(0.0, BIAS, (obs.uv.shape[1], 2))
    return replace(obs, uv=obs.uv + bias[None] + rng.normal(0.0, NOISE, obs.uv.shape))


def test_a_principal_point_the_keypoints_cannot_tell_enters_the_one_sigma():
    """Given cx, cy 24, -16 px off and keypoints biased by a few pixels each, the keypoints
    ask for a turn beyond 1.5 deg within their noise: no finding of a wrong point, but the
    point is unresolved. The keypoint fit alone was `good` 2.6 deg off with the truth far
    outside its ellipsoid; with the move to the asked point and the turn of a point as far
    off in the covariance, `check`, the truth inside."""
    seq = _scene((24.0, -16.0))
    obs = _biased(seq, 0)
    result = calibrate(seq, obs, "all")
    doc = result_to_dict(result, obs, robot="panda")
    findings = intrinsics_checks(result, obs, seq, doc)
    record = doc["keypoint_principal"]
    assert record["beyond_limit"] and record["unresolved"] and record["agrees"]
    assert result_quality(result, obs, extra=findings).verdict == "good"
    T_true = truth_poses(seq)[0]
    xi = increment_between(result.T_cam_base, T_true)
    assert np.rad2deg(pose_errors(result.T_cam_base, T_true)[1]) > 2.0
    assert xi @ np.linalg.pinv(result.covariance) @ xi > CHI2_6DOF_95
    opened, unresolved = with_keypoint_intrinsics(doc, seq.camera)
    assert len(unresolved) == 1 and unresolved[0][0] == "check"
    assert "cannot tell whether cx, cy" in unresolved[0][1]
    covariance = np.asarray(opened["covariance_xi"])
    assert "principal point" in opened["uncertainty"]["keypoint_intrinsics_added"]
    assert xi @ np.linalg.pinv(covariance) @ xi < CHI2_6DOF_95
    assert written_quality(result, obs, opened, [*findings, *unresolved]).verdict == "check"
    assert doc["covariance_xi"] == result.covariance.tolist()     # the input is kept


def test_the_outlines_judge_the_intrinsics_where_they_ran():
    """Where the silhouettes' cross-check fitted the intrinsics, its own records speak for
    them, and the keypoints' are left as they are; a principal point within the limit adds
    nothing, a focal length within it its move."""
    seq = _scene((24.0, -16.0))
    obs = _biased(seq, 0)
    result = calibrate(seq, obs, "all")
    doc = result_to_dict(result, obs, robot="panda")
    intrinsics_checks(result, obs, seq, doc)
    judged = {**doc, "silhouette_check": {"ran": True, "focal": {"scale": 1.0}}}
    assert with_keypoint_intrinsics(judged, seq.camera) == (judged, [])
    within = {**doc, "keypoint_principal": {**doc["keypoint_principal"],
                                            "beyond_limit": False, "unresolved": False},
              "keypoint_focal": {**doc["keypoint_focal"], "beyond_limit": False}}
    opened, unresolved = with_keypoint_intrinsics(within, seq.camera)
    assert unresolved == []
    assert opened["uncertainty"]["keypoint_intrinsics_added"] == ["focal length"]
    xi = np.asarray(within["keypoint_focal"]["xi_asked"])
    assert np.allclose(np.asarray(opened["covariance_xi"]) - np.asarray(within["covariance_xi"]),
                       np.outer(xi, xi))
