"""The README's new-robot walkthrough at tiny scale, for xArm7: synth -> train -> export ->
calibrate, through the command line only."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("lightning")

from dream.cli import main  # noqa: E402
from dream.io import read_sequence  # noqa: E402
from dream.metrics import pose_errors  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
# The panda_cpu recipe's loss. With the weighted MSE (loss.foreground_weight=100) this test
# passed on an AVX-512 machine and failed on an AVX2 one (150 mm): the tiny model's maps kept
# second peaks above half the best, so the peak finder called 87 % of the keypoints ambiguous.
# With the focal loss: 5-13 mm over three training and data seeds on the AVX2 machine.
FOCAL = ("--set", "model.belief_activation=sigmoid", "--set", "loss.belief=focal")


def test_new_robot_from_urdf_to_calibrated_camera(tmp_path, capsys):
    data, run, model = tmp_path / "xarm7", tmp_path / "run", tmp_path / "xarm7.onnx"
    assert main(["synth", "--robot", "xarm7", "--num", "48", "--out", str(data), "--config",
                 str(REPO / "configs/synth/walkthrough_easy.yaml"), "--seed", "3"]) == 0
    assert main(["train", "--config", str(REPO / "configs/train/tiny.yaml"),
                 "--set", f"data.train=[{data}]", "--set", "trainer.max_epochs=60",
                 *FOCAL, "--out", str(run)]) == 0
    assert main(["export", "--checkpoint", str(run / "best.ckpt"), "--out", str(model)]) == 0
    result = tmp_path / "result.json"
    code = main(["calibrate", "--data", str(data), "--model", str(model), "--out", str(result)])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(result.read_text())
    assert doc["robot"] == "xarm7" and (tmp_path / "result.ros.txt").is_file()
    truth = read_sequence(data).T_cam_base_reference
    if truth is None:
        truth = read_sequence(data).frames[0].T_cam_base_true
    t_err, r_err = pose_errors(np.array(doc["T_cam_base"]), truth)
    assert t_err < 0.05 and r_err < np.deg2rad(3.0), (t_err, r_err)
