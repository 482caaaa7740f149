"""The edge alignment of each frame's own pose (`dream.edges.frames`, `dream calibrate
--frames each`), on images of the project's own silhouettes over a cluttered scene
(`tests/dream/test_edges.py`'s scenes)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dream.camera import project
from dream.cli import main
from dream.edges import EdgeSettings
from dream.edges.frames import background_explains, decide_frame, refine_frames_with_edges
from dream.errors import InputError
from dream.io import read_sequence
from dream.metrics import add_per_frame
from dream.pipeline import (
    calibrate,
    joints_in_robot_order,
    observations_from_labels,
    robot_for,
)
from dream.transforms import transform_points
from tests.dream.test_edges import edge_scene, image_dataset


def test_calibrate_each_aligns_every_frame_by_default_without_masks(panda, meshes,
                                                                    tmp_path, capsys):
    T_true = image_dataset(panda, meshes, tmp_path)
    out = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--frames",
                 "each", "--out", str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "edge alignment of each frame (10 frames" in printed
    doc = json.loads(out.read_text())
    assert doc["edges"]["mode"] == "each" and doc["edges"]["background_model"]
    assert doc["edges"]["frames_kept"] >= 7
    seq = read_sequence(tmp_path / "data")
    P = panda.forward_kinematics(joints_in_robot_order(seq, robot_for(seq)))
    before = np.stack([f["edges"]["T_cam_base_keypoints"] for f in doc["per_frame"]])
    after = np.stack([f["T_cam_base"] for f in doc["per_frame"]])
    truth = np.broadcast_to(T_true, before.shape)
    add0, add1 = add_per_frame(P, before, truth), add_per_frame(P, after, truth)
    assert np.median(add1) < 0.5 * np.median(add0), (np.median(add0), np.median(add1))
    kept = np.array([f["edges"]["kept"] for f in doc["per_frame"]])
    assert np.allclose(after[~kept], before[~kept])
    for i in np.flatnonzero(kept):       # a kept frame's RMSE is its keypoints' at its pose
        uv = project(seq.camera, transform_points(after[i], P[i]))
        inlier = np.array([k["inlier"] for k in doc["per_frame"][i]["keypoints"]])
        detected = np.array([k["uv"] or [np.nan, np.nan]
                             for k in doc["per_frame"][i]["keypoints"]], float)
        expected = np.sqrt(np.mean(np.sum((uv - detected)[inlier] ** 2, 1)))
        assert doc["per_frame"][i]["rmse_px"] == pytest.approx(expected, rel=1e-6)
    reported = [f for f in doc["per_frame"] if f["frame"] == doc["reported_frame"]][0]
    if reported["edges"]["kept"]:     # the reported frame's 1-sigma is its aligned pose's
        assert doc["uncertainty"]["method"] == "jackknife of the edge alignment"
        assert not any(g.startswith("frames ") for g in doc["uncertainty"]["jackknife_left_out"])


def test_background_is_used_only_when_it_explains_the_frames(panda, meshes):
    settings = EdgeSettings()
    _, _, images, background = edge_scene(panda, meshes)
    assert background_explains(images, background, settings)
    # a panning camera over a textured scene: what lies behind the arm shifts every frame
    texture = np.random.default_rng(5).uniform(0.0, 0.8, background.shape)
    moving = np.stack([np.where(image == background, np.roll(texture, 25 * k, axis=1),
                                image) for k, image in enumerate(images)])
    median = np.median(moving, axis=0)
    assert not background_explains(moving, median, settings)


def test_frame_keep_rule():
    s = EdgeSettings()
    assert not decide_frame(0.5, 0.5, 2.0, 1.0, 6, s)[0]           # no gain
    assert decide_frame(0.4, 0.6, 2.0, 3.0, 6, s)[0]                 # within the margin
    kept, reason = decide_frame(0.4, 0.6, 2.0, 9.0, 6, s)            # leaves its keypoints
    assert not kept and "median distance would grow" in reason
    assert decide_frame(0.4, 0.6, float("nan"), float("nan"), 0, s)[0]   # no keypoints
    with pytest.raises(InputError, match="min_static_share"):
        EdgeSettings(min_static_share=1.5)


def test_frame_alignment_needs_an_each_mode_result(panda, meshes, tmp_path):
    image_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    robot = robot_for(seq)
    obs = observations_from_labels(seq, robot)
    with pytest.raises(InputError, match="each frame's own pose"):
        refine_frames_with_edges(seq, robot, calibrate(seq, obs, "all"), obs)
