"""The quality verdict of a calibration (`dream.quality`)."""

from __future__ import annotations

import json

import pytest

from dream.cli import main
from dream.errors import InputError
from dream.quality import DOUBTFUL, MIN_KEPT_SHARE, OK, Quality, keypoint_quality


def test_a_fit_on_a_small_consensus_is_doubtful():
    q = keypoint_quality(70, 20)
    assert q.verdict == DOUBTFUL and q.kept_share == pytest.approx(20 / 70)
    assert "20 of 70" in q.warnings[0] and "--polish" in q.warnings[0]
    assert keypoint_quality(100, int(100 * MIN_KEPT_SHARE)).verdict == OK
    assert keypoint_quality(0, 0).verdict == DOUBTFUL


def test_a_kept_image_refinement_answers_the_doubt_but_the_warning_stays():
    q = keypoint_quality(70, 20, refined_by="the edge alignment")
    assert q.verdict == OK and "the edge alignment" in q.warnings[0]
    assert q.to_dict() == {"detections": 70, "kept": 20, "kept_share": 20 / 70, "verdict": OK,
                           "warnings": list(q.warnings)}


def test_quality_checks_its_input():
    with pytest.raises(InputError, match="kept"):
        Quality(10, 11, OK, ())
    with pytest.raises(InputError, match="verdict"):
        Quality(10, 5, "fine", ())
    with pytest.raises(InputError, match="min_kept_share"):
        keypoint_quality(10, 5, min_kept_share=0.0)


def test_calibrate_writes_the_verdict(tmp_path, capsys):
    from dream.robot import load_robot
    from dream.silhouette import load_robot_meshes
    from tests.dream.test_polish import masked_dataset

    panda = load_robot("panda")
    masked_dataset(panda, load_robot_meshes(panda), tmp_path)
    result = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--refine",
                 "none", "--out", str(result)])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(result.read_text())
    quality = doc["quality"]
    assert quality["verdict"] == OK
    assert quality["detections"] == sum(f["keypoints_found"] for f in doc["per_frame"])
    assert quality["kept"] == doc["keypoints_used"]
    assert "quality" not in out
