"""The all-frames polish with frames that disagree (`dream.polish.frames`) and its guard on
every keypoint detection (`KeypointGuard.ALL_MEDIAN`).

Masks are rendered by `render_silhouette` at a known pose; a frame "whose readings do not match
its image" is given joints other than those its mask was rendered with.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from dream.camera import CameraIntrinsics, project
from dream.cli import main
from dream.metrics import pose_errors
from dream.polish import KeypointGuard, KeypointSet, PolishSettings, polish
from dream.polish.frames import (
    FITS_WORSE,
    NO_POSE_FITS,
    PREFERS_ANOTHER_POSE,
    agreeing_frames,
    frame_violations,
)
from dream.polish.guard import decide
from dream.sample import random_joints
from dream.silhouette import render_silhouette
from dream.transforms import T_from_rotvec_t, look_at, transform_points

WIDTH, HEIGHT = 320, 240
CAMERA = CameraIntrinsics(250.0, 250.0, (WIDTH - 1) / 2, (HEIGHT - 1) / 2, WIDTH, HEIGHT)
TARGET = np.array([0.0, 0.0, 0.4])
NUM_FRAMES = 8
WRONG_READINGS = (2, 5)        # frames whose joints are not those of their mask
READING_ERROR_RAD = 0.35       # added to joints 2 and 4 of those frames


def moved(T: np.ndarray, rng: np.random.Generator, shift_m: float, angle_rad: float
          ) -> np.ndarray:
    axis, shift = rng.normal(size=3), rng.normal(size=3)
    out = T_from_rotvec_t(axis / np.linalg.norm(axis) * angle_rad, np.zeros(3)) @ T
    out[:3, 3] += shift / np.linalg.norm(shift) * shift_m
    return out


def scene(panda, meshes, seed: int, wrong=WRONG_READINGS):
    """(rng, true pose, the joints as logged, the masks of the true joints)."""
    rng = np.random.default_rng(seed)
    T_true = look_at(TARGET + np.array([1.1, -0.9, 0.6]), TARGET)
    joints = random_joints(rng, panda, NUM_FRAMES, 0.8)
    masks = np.stack([render_silhouette(meshes, q, T_true, CAMERA) for q in joints])
    logged = joints.copy()
    logged[list(wrong), 1] += READING_ERROR_RAD
    logged[list(wrong), 3] -= READING_ERROR_RAD
    return rng, T_true, logged, masks


def test_frames_whose_readings_do_not_match_are_left_out(panda, meshes):
    rng, T_true, logged, masks = scene(panda, meshes, seed=11)
    T0 = moved(T_true, rng, 0.02, np.deg2rad(1.0))
    checked = polish(meshes, logged, masks, CAMERA, T0, None)
    unchecked = polish(meshes, logged, masks, CAMERA, T0, None, check_frames=False)
    a = checked.agreement
    assert set(a.left_out.tolist()) == set(WRONG_READINGS), a.reasons
    assert all(a.reasons[i] for i in WRONG_READINGS)
    assert not any(a.reasons[i] for i in range(NUM_FRAMES) if i not in WRONG_READINGS)
    t_checked = pose_errors(checked.T_polished, T_true)[0]
    t_unchecked = pose_errors(unchecked.T_polished, T_true)[0]
    assert t_checked < 2e-3 < t_unchecked, (t_checked, t_unchecked)
    # the means are over the frames used; the per-frame IoUs cover every frame
    assert checked.iou_after_mean > 0.98 and checked.iou_after.shape == (NUM_FRAMES,)
    assert unchecked.agreement is None


def test_frames_that_agree_are_all_used(panda, meshes):
    rng, T_true, logged, masks = scene(panda, meshes, seed=12, wrong=())
    res = polish(meshes, logged, masks, CAMERA, moved(T_true, rng, 0.02, 0.01), None)
    assert res.agreement.used.all() and res.agreement.rounds == 0
    assert pose_errors(res.T_polished, T_true)[0] < 2e-3


def test_frame_violations_name_the_rule_broken():
    p = PolishSettings()
    common = np.array([0.95, 0.96, 0.94, 0.50, 0.70, 0.90])
    own = np.array([0.96, 0.96, 0.95, 0.52, 0.95, 0.91])
    reasons, by = frame_violations(common, own, np.ones(6, bool), p)
    assert reasons == ["", "", "", NO_POSE_FITS, PREFERS_ANOTHER_POSE, ""]
    reference = np.median(common)          # frame 3 breaks two rules: by the larger excess
    assert by[3] == pytest.approx(max(p.min_frame_iou - 0.52,
                                      reference - p.max_frame_iou_drop - 0.50))
    assert by[4] == pytest.approx(0.95 - 0.70 - p.max_frame_iou_loss)
    reasons, _ = frame_violations(np.array([0.95, 0.96, 0.94, 0.70]),
                                  np.array([0.96, 0.96, 0.95, 0.71]), np.ones(4, bool), p)
    assert reasons[3] == FITS_WORSE


def test_too_few_agreeing_frames_leave_none_out():
    """When dropping the worst would leave fewer than `min_agreeing_frames`, the frames stay:
    a pure check with stand-ins for the search and the IoUs."""
    p = PolishSettings()
    T = np.eye(4)
    quality = np.array([0.95, 0.96, 0.75, 0.74])

    def search(frames, T_start):
        return T_start

    def ious(frames, T_at):
        return quality[frames] - (0.2 if T_at is not T else 0.0)

    def search_alone(frame, T_start):
        return np.eye(4)                     # alone, every frame "prefers another pose"

    T_out, a = agreeing_frames(T, np.ones(4, bool), search, search_alone, ious, p)
    assert a.used.sum() >= p.min_agreeing_frames
    assert T_out is T


def test_all_median_guard_keeps_a_polish_that_leaves_a_biased_consensus(panda, meshes):
    """Every detection 15-30 px off the truth, as a real detector's are; the keypoint fit kept
    the few that agree with a wrong pose 3 cm away and fits them closely. The silhouettes lead
    back to the truth: the RMSE of those few refuses it, the median of all detections keeps it."""
    rng, T_true, joints, masks = scene(panda, meshes, seed=13, wrong=())
    P = panda.forward_kinematics(joints).reshape(-1, 3)
    direction = rng.normal(size=(len(P), 2))
    shift = direction / np.linalg.norm(direction, axis=1, keepdims=True) * rng.uniform(
        15, 30, (len(P), 1))
    detections = KeypointSet(P, project(CAMERA, transform_points(T_true, P)) + shift)
    T_wrong = moved(T_true, rng, 0.03, np.deg2rad(0.5))
    few = np.arange(0, len(P), 7)
    inliers = KeypointSet(P[few], project(CAMERA, transform_points(T_wrong, P[few])))
    every = polish(meshes, joints, masks, CAMERA, T_wrong, detections,
                   guard=KeypointGuard.ALL_MEDIAN)
    fit = polish(meshes, joints, masks, CAMERA, T_wrong, inliers, guard=KeypointGuard.RMSE)
    assert every.kept, every.reason
    assert "median distance of all" in every.reason
    assert pose_errors(every.T_after, T_true)[0] < 3e-3
    assert not fit.kept and "keypoint RMSE" in fit.reason


def test_calibrate_names_the_frames_left_out(panda, meshes, tmp_path, capsys):
    from tests.dream.test_polish import masked_dataset

    T_true = masked_dataset(panda, meshes, tmp_path, frames=8)
    data = tmp_path / "data"
    for name in ("000002", "000005"):                   # readings that do not match
        path = data / f"{name}.json"
        doc = json.loads(path.read_text())
        for entry in doc["sim_state"]["joints"]:
            if entry["name"] in ("panda_joint2", "panda_joint4"):
                entry["position"] += READING_ERROR_RAD
        path.write_text(json.dumps(doc))
    result = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(data), "--use-labels", "--polish", "--out",
                 str(result)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "frames left out" in out and "000002" in out and "000005" in out
    doc = json.loads(result.read_text())
    left = {f["frame"] for f in doc["polish"]["frames_left_out"]}
    assert left == {"000002", "000005"}
    assert doc["polish"]["keypoint_guard"] == KeypointGuard.NONE     # the data's own masks
    assert pose_errors(np.array(doc["T_cam_base"]), T_true)[0] < 0.01


def test_all_median_guard_holds_a_trusted_fit_to_its_inlier_rmse():
    """Where the keypoint fit kept most detections, the polish must not break its inliers
    either: the median of all detections alone is loose along the optical axis."""
    p = PolishSettings()
    kept, reason = decide(0.70, 0.75, 1.1, 1.5, 200, p, KeypointGuard.ALL_MEDIAN, (1.0, 2.5))
    assert not kept and "inlier RMSE" in reason
    kept, reason = decide(0.70, 0.75, 1.1, 1.5, 200, p, KeypointGuard.ALL_MEDIAN, (1.0, 1.4))
    assert kept and "inlier RMSE" in reason
    assert decide(0.70, 0.75, 1.1, 1.5, 200, p, KeypointGuard.ALL_MEDIAN)[0]   # not trusted


def test_most_frames_left_out_leave_none_out():
    """Leaving out more than `1 - min_agreeing_share` of the frames is refused: then the
    masks, not the frames, are the likelier fault."""
    p = PolishSettings()
    T = np.eye(4)
    n = 20
    quality = np.full(n, 0.5)
    quality[:4] = 0.95      # four good frames (more than min_agreeing_frames), 16 no pose fits

    def ious(frames, T_at):
        return quality[frames]

    T_out, a = agreeing_frames(T, np.ones(n, bool), lambda f, T0: T0, lambda f, T0: T0, ious,
                               p)
    assert a.used.all() and T_out is T
