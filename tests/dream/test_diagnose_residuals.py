"""Residual analysis (`dream.diagnosis.residuals`) on synthetic residual sets with known
patterns."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dream.camera import CameraIntrinsics
from dream.diagnosis.residuals import (
    ALPHA,
    ResidualSet,
    analyse,
    analyse_change_point,
    analyse_joints,
    analyse_keypoints,
    analyse_radial,
    analyse_velocity,
    image_velocity,
    per_frame_mean,
    per_frame_rms,
)
from dream.errors import InputError

CAMERA = CameraIntrinsics(fx=600.0, fy=600.0, cx=320.0, cy=240.0, width=640, height=480)
F, K, J = 60, 7, 3
NOISE_PX = 0.5
FPS = 30.0  # frame rate of the synthetic sequences


def _trajectories(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smooth predicted keypoints (F, K, 2) px inside the image, joints (F, J), times (F,)."""
    t = np.arange(F) / FPS
    centre = rng.uniform([100, 80], [540, 400], size=(K, 2))
    amp = rng.uniform(20, 60, size=(K, 2))
    freq = rng.uniform(0.5, 1.5, size=(K, 2))
    phase = rng.uniform(0, 2 * np.pi, size=(K, 2))
    uv = centre + amp * np.sin(2 * np.pi * freq * t[:, None, None] + phase)
    joints = 0.8 * np.sin(2 * np.pi * np.array([0.3, 0.5, 0.7]) * t[:, None]
                          + rng.uniform(0, 2 * np.pi, J))
    return uv, joints, t


def _set(uv_pred: np.ndarray, residual: np.ndarray, joints: np.ndarray,
         times: np.ndarray | None, used: np.ndarray | None = None) -> ResidualSet:
    n_frames, n_kp = uv_pred.shape[:2]
    return ResidualSet(
        frame_names=tuple(f"{i:06d}" for i in range(n_frames)),
        keypoint_names=tuple(f"kp{k}" for k in range(n_kp)),
        joint_names=tuple(f"j{j}" for j in range(joints.shape[1])),
        uv_observed=uv_pred + residual, uv_predicted=uv_pred,
        used=np.ones((n_frames, n_kp), bool) if used is None else used,
        joints=joints, times_s=times, camera=CAMERA)


def _null(seed: int) -> ResidualSet:
    rng = np.random.default_rng(seed)
    uv, q, t = _trajectories(rng)
    return _set(uv, rng.normal(0, NOISE_PX, uv.shape), q, t)


def test_keypoint_bias_flagged_only_for_that_keypoint():
    rng = np.random.default_rng(1)
    uv, q, t = _trajectories(rng)
    r = rng.normal(0, NOISE_PX, uv.shape)
    r[:, 3] += [0.6, -0.4]
    out = analyse_keypoints(_set(uv, r, q, t))
    assert [name for name, s in out.items() if s["significant"]] == ["kp3"]
    assert np.allclose(out["kp3"]["mean_px"], [0.6, -0.4], atol=0.25)
    assert out["kp3"]["n"] == F


def test_null_data_has_no_keypoint_bias_in_most_seeds():
    flagged = sum(any(s["significant"] for s in analyse_keypoints(_null(seed)).values())
                  for seed in range(20))
    assert flagged <= 2


def _radial_set(seed: int, k1: float) -> ResidualSet:
    rng = np.random.default_rng(seed)
    uv = rng.uniform([0, 0], [640, 480], size=(F, K, 2))
    xy = (uv - [CAMERA.cx, CAMERA.cy]) / CAMERA.fx
    r2 = np.sum(xy ** 2, -1, keepdims=True)
    pattern = CAMERA.fx * k1 * r2 * xy
    return _set(uv, pattern + rng.normal(0, NOISE_PX, uv.shape), np.zeros((F, J)), None)


def test_radial_r3_pattern_gives_positive_slope():
    k1 = 0.05
    out = analyse_radial(_radial_set(2, k1))
    assert out["significant_r3"]
    assert out["slope_r3"]["slope"] == pytest.approx(k1, rel=0.1)
    assert out["corr_r3"] > 0.5


def test_radial_null_gives_no_slope():
    for seed in range(5):
        out = analyse_radial(_radial_set(seed, 0.0))
        assert not out["significant_r3"]
        assert abs(out["slope_r3"]["slope"]) < 3 * out["slope_r3"]["se"] + 1e-3


def test_step_located_at_frame_30():
    rng = np.random.default_rng(3)
    uv, q, t = _trajectories(rng)
    r = rng.normal(0, NOISE_PX, uv.shape)
    step = rng.normal(0, 1.0, size=(K, 2))       # the move shifts every keypoint differently
    r[30:] += step
    out = analyse_change_point(_set(uv, r, q, t))
    assert abs(out["index"] - 30) <= 1
    assert out["frame"] == f"{out['index']:06d}"
    assert out["significant"]
    assert out["step_px"] == pytest.approx(np.sqrt(np.mean(np.sum(step ** 2, -1))), rel=0.2)


@pytest.mark.parametrize("seed", range(5))
def test_a_misfit_that_follows_the_joints_is_no_step(seed):
    """A model error of a fixed camera leaves residuals that follow the pose (here: each
    keypoint's residual a random first-harmonic function of the joints, 4x the noise),
    autocorrelated along a smooth motion: the step test is against that, not against a
    constant (which called such sequences a step at p < 1e-60). A camera move on top of it
    still shows."""
    rng = np.random.default_rng(100 + seed)
    uv, q, t = _trajectories(rng)
    weights = rng.normal(0, 4 * NOISE_PX, size=(2 * J, K, 2))
    features = np.concatenate([np.sin(q), np.cos(q)], axis=1)     # (F, 2J)
    r = np.einsum("fj,jkc->fkc", features, weights) + rng.normal(0, NOISE_PX, uv.shape)
    smooth = analyse_change_point(_set(uv, r, q, t))
    assert smooth["null"] == "joints"
    assert not smooth["significant"], smooth["p_value"]
    r[40:] += rng.normal(0, 4 * NOISE_PX, size=(K, 2))    # the camera moves at frame 40
    moved = analyse_change_point(_set(uv, r, q, t))
    assert moved["significant"] and abs(moved["index"] - 40) <= 1


def test_too_few_frames_for_the_joints_test_against_a_constant():
    rng = np.random.default_rng(5)
    uv, q, t = _trajectories(rng)
    n = 12                                          # < 3 frames per regressor of 1 + 2J
    r = rng.normal(0, NOISE_PX, uv.shape)[:n]
    r[6:] += 3.0
    out = analyse_change_point(_set(uv[:n], r, q[:n], t[:n]))
    assert out["null"].startswith("constant: too few frames") and out["significant"]
    assert out["index"] == 6


def _lost_keypoints_set(step_frame: int | None) -> ResidualSet:
    """120 frames of 7 moving joints; six keypoints lost after frame 105 and the one left
    jumping 3 px from frame 112 (detections failing near the end, as on panda_teleop); with
    a camera move, every keypoint steps 1.5 px at `step_frame`."""
    rng = np.random.default_rng(1)
    frames, joints = 120, 7
    t = np.linspace(0, 1, frames)
    q = np.stack([0.5 * np.sin(2 * np.pi * t * (j + 1) / 3) for j in range(joints)], 1)
    r = rng.normal(0, 1, (frames, K, 2))
    used = np.ones((frames, K), bool)
    used[105:, 1:] = False
    if step_frame is not None:
        r[step_frame:] += 1.5
    r[112:, 0] += 3.0
    uv = np.full((frames, K, 2), 300.0)
    return _set(uv, r, q, None, used)


def test_the_step_reaching_every_keypoint_beats_a_late_one_on_fewer():
    """Splits reach different numbers of keypoint series: the split is ranked by its p-value,
    not by its F statistic (of other degrees of freedom), which chose the lone keypoint's
    jump at frame 112 (p 0.085) over the camera's move at 60 (p 0.0002)."""
    out = analyse_change_point(_lost_keypoints_set(60))
    assert abs(out["index"] - 60) <= 1 and out["significant"], out["p_value"]


def test_keypoints_seen_in_few_frames_are_tested_against_their_constant():
    """A keypoint seen in fewer frames than the joints' null needs keeps its step test against
    its own constant (it was left out, and with every keypoint sparse nothing was tested)."""
    rng = np.random.default_rng(2)
    uv, q, t = _trajectories(rng)
    r = rng.normal(0, NOISE_PX, uv.shape)
    r[30:] += 5 * NOISE_PX
    used = np.zeros((F, K), bool)
    for k in range(K):               # each keypoint in 5 frames either side of the move
        used[rng.choice(30, 5, replace=False), k] = True
        used[30 + rng.choice(30, 5, replace=False), k] = True
    out = analyse_change_point(_set(uv, r, q, t, used))
    assert out["against_constant"] == [f"kp{k}" for k in range(K)]
    assert out["significant"] and out["index"] <= 30


def test_null_has_no_significant_step_in_most_seeds():
    flagged = sum(analyse_change_point(_null(seed))["significant"] for seed in range(10))
    assert flagged <= 1


def test_velocity_coefficient_recovered():
    rng = np.random.default_rng(4)
    uv, q, t = _trajectories(rng)
    offset_s = 0.02
    velocity = image_velocity(_set(uv, np.zeros_like(uv), q, t))
    assert np.all(np.isfinite(velocity))
    out = analyse_velocity(_set(uv, offset_s * velocity + rng.normal(0, 0.2, uv.shape), q, t))
    assert out["coefficient_s"] == pytest.approx(offset_s, rel=0.1)
    assert out["significant"] and out["corr"] > 0.5


def test_image_velocity_is_the_derivative():
    t = np.linspace(0, 2, F)
    uv = np.stack([3.0 * t ** 2, 5.0 * t], -1)[:, None, :]   # (F, 1, 2)
    v = image_velocity(_set(uv, np.zeros_like(uv), np.zeros((F, 1)), t))
    np.testing.assert_allclose(v[1:-1, 0, 0], 6.0 * t[1:-1], rtol=1e-9)
    np.testing.assert_allclose(v[:, 0, 1], 5.0, rtol=1e-9)
    # without times there is no velocity
    assert np.all(np.isnan(image_velocity(_set(uv, np.zeros_like(uv), np.zeros((F, 1)), None))))


def test_joint_offset_like_pattern_lights_up_its_joint():
    rng = np.random.default_rng(5)
    uv, q, t = _trajectories(rng)
    r = rng.normal(0, NOISE_PX, uv.shape)
    r[:, 2, 0] += 2.0 * np.sin(q[:, 1] + 0.3)       # keypoint 2 moves with joint 1
    out = analyse_joints(_set(uv, r, q, t))
    assert out["j1"]["significant"]
    assert out["j1"]["harmonic_keypoint"] == "kp2" and out["j1"]["harmonic_component"] == "u"
    null = analyse_joints(_null(6))
    assert not any(s["significant"] for s in null.values())


def test_analyse_is_json_and_handles_unused_and_missing():
    res = _null(7)
    used = np.ones((F, K), bool)
    used[::7, 2] = False
    uv_obs = res.uv_observed.copy()
    uv_obs[::7, 2] = np.nan
    res = ResidualSet(res.frame_names, res.keypoint_names, res.joint_names, uv_obs,
                      res.uv_predicted, used, res.joints, res.times_s, CAMERA)
    out = analyse(res)
    json.dumps(out, allow_nan=False)
    assert out["alpha"] == ALPHA
    assert out["overall"]["n_used"] == int(used.sum())
    assert out["overall"]["rms_px"] == pytest.approx(NOISE_PX * np.sqrt(2), rel=0.15)
    assert out["time"]["velocity"]["n"] > 0
    assert len(out["time"]["rms_px"]) == F
    assert per_frame_rms(res).shape == (F,) and per_frame_mean(res).shape == (F, 2)
    # without times the time section is None; a frame without used keypoints gives NaN
    used[5] = False
    res = ResidualSet(res.frame_names, res.keypoint_names, res.joint_names, uv_obs,
                      res.uv_predicted, used, res.joints, None, CAMERA)
    out = analyse(res)
    json.dumps(out, allow_nan=False)
    assert out["time"] is None
    assert np.isnan(per_frame_rms(res)[5])
    assert out["change_point"]["per_frame_mean_px"][5] == [None, None]


def test_tiny_sets_do_not_crash():
    uv = np.full((2, 1, 2), 100.0)
    out = analyse(_set(uv, np.zeros_like(uv), np.zeros((2, 1)), np.array([0.0, 0.1])))
    json.dumps(out, allow_nan=False)
    assert out["change_point"]["index"] is None
    assert out["per_keypoint"]["kp0"]["significant"] is False


def test_shape_and_value_errors_raise_input_error():
    res = _null(8)
    base = dict(frame_names=res.frame_names, keypoint_names=res.keypoint_names,
                joint_names=res.joint_names, uv_observed=res.uv_observed,
                uv_predicted=res.uv_predicted, used=res.used, joints=res.joints,
                times_s=res.times_s, camera=CAMERA)
    bad = [dict(uv_observed=res.uv_observed[:, :3]),
           dict(uv_predicted=res.uv_predicted[..., :1]),
           dict(used=res.used[:-1]),
           dict(joints=res.joints[:, :2]),
           dict(times_s=res.times_s[:-1]),
           dict(times_s=np.full(F, np.nan)),
           dict(frame_names=()),
           dict(camera="not a camera")]
    pred = res.uv_predicted.copy()
    pred[0, 0] = np.nan
    bad.append(dict(uv_predicted=pred))
    for change in bad:
        with pytest.raises(InputError):
            ResidualSet(**{**base, **change})
    with pytest.raises(InputError):
        analyse("not a residual set")
