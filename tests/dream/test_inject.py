"""Effect injection (`dream.inject`): nominal data calibrates back, each effect moves the labels
as predicted to first order, time offsets are recoverable, determinism, input checks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dream.calibration import calibrate_all
from dream.camera import project, project_with_jacobian
from dream.errors import InputError
from dream.extended import effective_joints
from dream.extension import CameraMove, ModelExtension
from dream.inject import (
    CAMERA_MOVE_FRAME_FRACTION,
    CAMERA_ROTATION_RANGE_RAD,
    CAMERA_TRANSLATION_RANGE_M,
    DISTORTION_K1_RANGE,
    EFFECT_RANGES,
    FOCAL_ERROR_RANGE,
    JOINT_OFFSET_RANGE_RAD,
    KEYPOINT_BIAS_RANGE_M,
    LINK_LENGTH_RANGE_M,
    TIME_OFFSET_RANGE_S,
    InjectionSettings,
    identifiable_joints,
    inject,
    make_injected_sequence,
    random_effect,
    random_effects,
    rigid_motion_residual,
    stretchable_joints,
)
from dream.io import read_sequence, write_dream
from dream.metrics import pose_errors
from dream.pipeline import observations_from_labels
from dream.transforms import transform_points

CALIBRATION_TRANSLATION_TOLERANCE_M = 0.003
CALIBRATION_ROTATION_TOLERANCE_RAD = math.radians(0.2)
FIRST_ORDER_TOLERANCE = 0.1       # |actual - linear prediction| / |prediction| over a sequence
EXACT_TOLERANCE_PX = 1e-6
INTERPOLATION_TOLERANCE_RAD = 2e-3  # PCHIP between 10 Hz readings of the smooth trajectory
END_FRAMES = 2                    # frames at each end where interpolation clamps
MIN_IN_IMAGE_FRACTION = 0.85
SMALL = InjectionSettings(num_frames=40, pixel_noise_px=0.0, seed=3)


def _nominal_uv(world) -> np.ndarray:
    """What the nominal model predicts from the written data with the first frame's extrinsic."""
    P = world.robot.forward_kinematics(world.readings)
    return project(world.camera_nominal, transform_points(world.T_cam_base[0], P))


def _linear_prediction(world, dP_cam: np.ndarray) -> np.ndarray:
    """(F, K, 2) first-order pixel change of camera-frame keypoint displacements (F, K, 3)."""
    P_cam = transform_points(world.T_cam_base[0], world.robot.forward_kinematics(world.readings))
    _, J = project_with_jacobian(world.camera_nominal, P_cam.reshape(-1, 3))
    return np.einsum("nij,nj->ni", J, dP_cam.reshape(-1, 3)).reshape(P_cam.shape[:-1] + (2,))


def _check_first_order(world, dP_base: np.ndarray | None = None,
                       dP_cam: np.ndarray | None = None) -> float:
    """Labels minus the nominal prediction agree with the linear prediction of the keypoint
    displacements; returns the median pixel change of the keypoints that moved."""
    if dP_cam is None:
        dP_cam = np.einsum("ij,fkj->fki", world.T_cam_base[0][:3, :3], dP_base)
    actual = world.uv_true - _nominal_uv(world)
    predicted = _linear_prediction(world, dP_cam)
    ok = np.all(np.isfinite(actual), -1)
    error = np.linalg.norm(actual[ok] - predicted[ok]) / np.linalg.norm(predicted[ok])
    assert error < FIRST_ORDER_TOLERANCE, error
    moved = np.linalg.norm(actual[ok], axis=-1)
    return float(np.median(moved[moved > EXACT_TOLERANCE_PX]))  # px, keypoints that moved


def test_nominal_sequence_calibrates_back(panda):
    spec = InjectionSettings(seed=1)
    seq = make_injected_sequence(spec, ModelExtension())
    truth = seq.frames[0].T_cam_base_true
    assert seq.T_cam_base_reference is None and seq.camera == spec.camera
    assert all(np.array_equal(f.T_cam_base_true, truth) for f in seq.frames)
    np.testing.assert_allclose([f.timestamp for f in seq.frames], spec.times_s)
    labels = seq.uv_labels()
    assert np.mean(np.isfinite(labels[..., 0])) > MIN_IN_IMAGE_FRACTION
    assert np.all(seq.camera.in_image(labels[np.isfinite(labels[..., 0])]))
    result = calibrate_all(observations_from_labels(seq, panda), seq.camera)
    t_err, r_err = pose_errors(result.fit.T_cam_base, truth)
    assert t_err < CALIBRATION_TRANSLATION_TOLERANCE_M
    assert r_err < CALIBRATION_ROTATION_TOLERANCE_RAD
    assert 1.0 < result.fit.rmse_px < 3.0   # about sqrt(2) x 1.5 px of label noise


def test_trajectory_sweeps_large_angles_at_realistic_speeds(panda):
    world = inject(InjectionSettings(seed=2))
    q = world.joints_at_images
    assert np.all(q >= panda.joint_lower) and np.all(q <= panda.joint_upper)
    assert np.median(q.max(0) - q.min(0)) > 1.0                   # rad swept per joint
    speed = np.abs(np.diff(q, axis=0)) / world.spec.frame_period_s
    assert 0.3 < np.median(speed.max(0)) < 1.6                    # rad/s
    assert np.all(speed.max(0) <= world.trajectory.peak_speed_bound + 1e-9)


def test_joint_offset_moves_labels_as_the_jacobian_predicts(panda):
    joint, offset = "panda_joint4", math.radians(2.0)
    world = inject(SMALL, ModelExtension(joint_offset_rad={joint: offset}))
    dP = panda.keypoint_jacobian(world.readings)[..., panda.joint_names.index(joint)] * offset
    assert _check_first_order(world, dP_base=dP) > 1.0
    np.testing.assert_array_equal(world.readings, inject(SMALL).readings)  # readings nominal


def test_link_length_moves_downstream_keypoints_along_the_offset(panda):
    joint, delta = "panda_joint5", 0.015
    world = inject(SMALL, ModelExtension(link_length_m={joint: delta}))
    jm = panda.tree.joints[panda.tree.joint_index[joint]]
    R_parent = panda.link_poses(world.readings, jm.parent)[:, 0, :3, :3]
    shift = R_parent @ (jm.origin[:3, 3] / np.linalg.norm(jm.origin[:3, 3])) * delta
    downstream = np.array([panda.tree.is_ancestor(jm.child, k) for k in panda.keypoint_names])
    dP = np.where(downstream[None, :, None], shift[:, None, :], 0.0)
    assert _check_first_order(world, dP_base=dP) > 1.0


def test_keypoint_bias_moves_only_its_keypoint(panda):
    keypoint, bias = "panda_link4", np.array([0.0, 0.02, -0.01])
    world = inject(SMALL, ModelExtension(keypoint_bias_m={keypoint: bias}))
    k = panda.keypoint_names.index(keypoint)
    R = panda.link_poses(world.readings, keypoint)[:, 0, :3, :3]
    dP = np.zeros(world.P_base.shape)
    dP[:, k] = R @ bias
    _check_first_order(world, dP_base=dP)
    others = np.delete(world.uv_true - _nominal_uv(world), k, axis=1)
    assert np.nanmax(np.abs(others)) < EXACT_TOLERANCE_PX


@pytest.mark.parametrize("move", [CameraMove("000020", translation_m=(0.01, -0.005, 0.004)),
                                  CameraMove("000020", rotation_rad=(0.0, 0.02, 0.01))])
def test_camera_move_changes_frames_from_the_move_on(move):
    world = inject(SMALL, ModelExtension(camera_moved=move))
    P_cam = transform_points(world.T_cam_base[0], world.P_base)
    dT = move.T_after_before
    dP = P_cam @ (dT[:3, :3] - np.eye(3)).T + dT[:3, 3]
    after = np.arange(SMALL.num_frames) >= 20
    dP[~after] = 0.0
    assert _check_first_order(world, dP_cam=dP) > 1.0
    assert np.all(world.T_cam_base[~after] == world.T_cam_base[0])
    assert not np.allclose(world.T_cam_base[after], world.T_cam_base[0])


def test_camera_effects_match_the_camera_model():
    nominal = inject(SMALL)
    c = SMALL.camera
    scale = 1.03
    world = inject(SMALL, ModelExtension(intrinsics=(c.fx * scale, c.fy * scale, c.cx, c.cy)))
    expected = (nominal.uv_true - [c.cx, c.cy]) * scale + [c.cx, c.cy]
    np.testing.assert_allclose(world.uv_true, expected, atol=EXACT_TOLERANCE_PX)
    k1 = -0.12
    world = inject(SMALL, ModelExtension(distortion=(k1, 0.0, 0.0, 0.0)))
    xy = (nominal.uv_true - [c.cx, c.cy]) / [c.fx, c.fy]
    r2 = np.sum(xy ** 2, -1, keepdims=True)
    expected = xy * (1 + k1 * r2) * [c.fx, c.fy] + [c.cx, c.cy]
    np.testing.assert_allclose(world.uv_true, expected, atol=EXACT_TOLERANCE_PX)
    assert world.camera_nominal.distortion is None and world.camera_true.distortion is not None


@pytest.mark.parametrize("tau", [0.08, -0.05])
def test_time_offset_readings_lag_and_are_recoverable(tau, panda):
    world = inject(SMALL, ModelExtension(time_offset_s=tau))
    nominal = inject(SMALL)
    np.testing.assert_array_equal(world.uv_true, nominal.uv_true)   # the same true world
    recovered = effective_joints(world.readings, world.times_s, tau)
    inner = slice(END_FRAMES, -END_FRAMES)
    assert np.max(np.abs(recovered[inner] - world.joints_at_images[inner])) \
        < INTERPOLATION_TOLERANCE_RAD
    lag = world.joints_at_images - world.readings
    assert np.max(np.abs(lag)) > 10 * INTERPOLATION_TOLERANCE_RAD
    dP = np.einsum("fkij,fj->fki", panda.keypoint_jacobian(world.readings), lag)
    assert _check_first_order(world, dP_base=dP) > 0.5


def test_written_sequence_reads_back(tmp_path):
    spec = InjectionSettings(num_frames=6, seed=4)
    seq = make_injected_sequence(spec, ModelExtension(distortion=(0.1, 0, 0, 0)))
    back = read_sequence(write_dream(seq, tmp_path / "inj"))
    assert back.camera == spec.camera and not back.has_images
    np.testing.assert_allclose(back.uv_labels(), seq.uv_labels(), atol=1e-9)
    np.testing.assert_allclose(back.joints, seq.joints, atol=1e-12)
    np.testing.assert_allclose([f.timestamp for f in back.frames], spec.times_s)


def test_deterministic_in_the_seed():
    extension = ModelExtension(joint_offset_rad={"panda_joint2": 0.02}, time_offset_s=0.05)
    spec = InjectionSettings(num_frames=10, seed=9)
    a, b = make_injected_sequence(spec, extension), make_injected_sequence(spec, extension)
    np.testing.assert_array_equal(a.uv_labels(), b.uv_labels())
    np.testing.assert_array_equal(a.joints, b.joints)
    c = make_injected_sequence(InjectionSettings(num_frames=10, seed=10), extension)
    assert not np.array_equal(a.joints, c.joints)
    random = make_injected_sequence(InjectionSettings(num_frames=10, seed=9, motion="random"))
    assert random.frames[3].timestamp == pytest.approx(0.3)


def test_identifiability_probes(panda):
    joints = identifiable_joints(panda)
    assert panda.joint_names[0] not in joints          # absorbed by the extrinsic
    assert panda.joint_names[-1] not in joints         # moves no keypoint origin
    assert len(joints) >= 4
    assert "panda_joint2" not in stretchable_joints(panda)  # zero origin offset
    assert "panda_joint1" in stretchable_joints(panda)      # panda_link0 stays put
    P = np.random.default_rng(0).normal(size=(4, 5, 3))
    w, v = np.array([0.1, -0.2, 0.3]), np.array([0.01, 0.0, -0.02])
    assert rigid_motion_residual(np.cross(w, P) + v, P) < 1e-9


def _draws(name, panda, n=6):
    spec = InjectionSettings(num_frames=50)
    return [random_effect(name, np.random.default_rng(s), panda, spec) for s in range(n)], spec


def test_random_effects_lie_in_their_ranges(panda):
    assert set(EFFECT_RANGES) == {"joint_offset", "lens_distortion", "intrinsics_error",
                                  "time_offset", "link_length", "camera_moved", "keypoint_bias",
                                  "held_readings"}
    for x in _draws("held_readings", panda)[0]:
        assert 0.1 <= x.held_readings.period_s <= 0.3 and x.held_readings.joints == ()
    eps = 1e-12
    draws, spec = _draws("joint_offset", panda)
    for x in draws:
        (joint, value), = x.joint_offset_rad.items()
        assert joint in identifiable_joints(panda)
        assert JOINT_OFFSET_RANGE_RAD[0] - eps <= abs(value) <= JOINT_OFFSET_RANGE_RAD[1] + eps
    assert x.effects == ("joint_offset",) and x.robot == "panda"
    for x in _draws("lens_distortion", panda)[0]:
        assert DISTORTION_K1_RANGE[0] <= abs(x.distortion[0]) <= DISTORTION_K1_RANGE[1]
        assert x.distortion[1:] == (0.0, 0.0, 0.0)
    for x in _draws("intrinsics_error", panda)[0]:
        fx, fy, cx, cy = x.intrinsics
        assert fx / spec.fx == pytest.approx(fy / spec.fy)
        assert FOCAL_ERROR_RANGE[0] - eps <= abs(fx / spec.fx - 1) <= FOCAL_ERROR_RANGE[1] + eps
        assert (cx, cy) == (spec.camera.cx, spec.camera.cy)
    for x in _draws("time_offset", panda)[0]:
        assert TIME_OFFSET_RANGE_S[0] <= abs(x.time_offset_s) <= TIME_OFFSET_RANGE_S[1]
    for x in _draws("link_length", panda)[0]:
        (joint, value), = x.link_length_m.items()
        assert joint in stretchable_joints(panda)
        assert LINK_LENGTH_RANGE_M[0] <= abs(value) <= LINK_LENGTH_RANGE_M[1]
    kinds = set()
    for x in _draws("camera_moved", panda, 10)[0]:
        move = x.camera_moved
        lo, hi = (f * spec.num_frames for f in CAMERA_MOVE_FRAME_FRACTION)
        assert lo <= int(move.frame) <= hi
        if move.rotation_angle_rad > 0:
            kinds.add("rotation")
            assert CAMERA_ROTATION_RANGE_RAD[0] - eps <= move.rotation_angle_rad \
                <= CAMERA_ROTATION_RANGE_RAD[1] + eps
        else:
            kinds.add("translation")
            t = np.linalg.norm(move.translation_m)
            assert CAMERA_TRANSLATION_RANGE_M[0] - eps <= t <= CAMERA_TRANSLATION_RANGE_M[1] + eps
    assert kinds == {"rotation", "translation"}
    for x in _draws("keypoint_bias", panda)[0]:
        (keypoint, bias), = x.keypoint_bias_m.items()
        assert keypoint in panda.keypoint_names
        assert KEYPOINT_BIAS_RANGE_M[0] - eps <= np.linalg.norm(bias) \
            <= KEYPOINT_BIAS_RANGE_M[1] + eps
    merged = random_effects(["joint_offset", "camera_moved", "lens_distortion"],
                            np.random.default_rng(1), panda, spec)
    assert merged.effects == ("joint_offset", "lens_distortion", "camera_moved")
    seq = make_injected_sequence(spec, merged)
    assert len(seq) == spec.num_frames


@pytest.mark.parametrize("kwargs", [
    {"num_frames": 1}, {"num_frames": 2.5}, {"pixel_noise_px": -1.0}, {"motion": "spin"},
    {"distance_m": (2.0, 1.0)}, {"distance_m": (0.0, 1.0)}, {"fx": 0.0}, {"frame_period_s": 0},
    {"joint_range_fraction": 0.0}, {"elevation_rad": (0.0, 2.0)}, {"width": 0},
    {"peak_speed_rad_s": (1.0, float("nan"))}, {"robot": ""}, {"trajectory_components": 0},
])
def test_bad_spec_values_are_refused(kwargs):
    with pytest.raises(InputError):
        InjectionSettings(**kwargs)


def test_bad_requests_are_refused(panda):
    with pytest.raises(InputError, match="continuous motion"):
        inject(InjectionSettings(num_frames=5, motion="random"), ModelExtension(time_offset_s=0.05))
    with pytest.raises(InputError, match="robot"):
        inject(InjectionSettings(num_frames=5), ModelExtension(robot="ur5"))
    with pytest.raises(InputError, match="000099"):
        inject(InjectionSettings(num_frames=5), ModelExtension(camera_moved=CameraMove("000099")))
    with pytest.raises(InputError, match="unknown effect"):
        random_effect("gravity", np.random.default_rng(0), panda, SMALL)
    with pytest.raises(InputError, match="repeat"):
        random_effects(["joint_offset", "joint_offset"], np.random.default_rng(0), panda, SMALL)
    with pytest.raises(InputError, match="continuous motion"):
        random_effect("time_offset", np.random.default_rng(0), panda,
                      InjectionSettings(motion="random"))
