"""`dream adapt`: pseudo-labels from a calibrated result, the teacher refused where the verdict
is `unreliable`, the held-out split, and a short fine-tune of the bundled model end to end
(its ONNX file runs in `dream calibrate` unchanged)."""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import re

import numpy as np
import pytest

from dream.camera import project
from dream.cli import main
from dream.errors import InputError
from dream.extension import HeldReadings, ModelExtension
from dream.inject import InjectionSettings, make_injected_sequence
from dream.io import read_sequence, write_dream
from dream.models import BUNDLED_MODEL
from dream.provenance import check_same_data
from dream.transforms import transform_points
from tests.dream.test_edges import image_dataset
from train.adapt import (
    ZOOM_SHARE,
    AdaptRequest,
    holdout_range,
    pseudo_labels,
    teacher,
    training_config,
)
from train.adapt_report import keypoint_scores

TINY = ["--renders", "8", "--scene-renders", "6", "--set",
        "trainer.time_budget_minutes=null", "--set", "trainer.max_steps=2", "--set",
        "trainer.max_epochs=1", "--set", "data.batch_size=4"]


TEACHER_FRAMES = 20     # fewer leave the keypoints unable to tell fx, fy and cx, cy: `unreliable`


def calibrated(panda, meshes, folder):
    """A rendered recording (no masks) and its `--use-labels` RESULT.json (`check` or
    `good`: a teacher)."""
    T_true = image_dataset(panda, meshes, folder, frames=TEACHER_FRAMES)
    code = main(["calibrate", "--data", str(folder / "data"), "--use-labels", "--refine",
                 "none", "--out", str(folder / "r.json")])
    assert code == 0
    return T_true


def test_pseudo_labels_are_the_projections_at_the_extrinsic(panda, meshes, tmp_path):
    T_true = image_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    uv = pseudo_labels(seq, panda, T_true)
    expected = project(seq.camera, transform_points(T_true, panda.forward_kinematics(
        np.stack([f.joints for f in seq.frames]))))
    inside = seq.camera.in_image(expected)
    assert np.allclose(uv[inside], expected[inside]) and np.isnan(uv[~inside]).all()


def test_holdout_frames_default_to_the_last_third_and_are_checked():
    assert holdout_range(None, 275) == range(184, 275)
    assert holdout_range("92:183", 275) == range(92, 183)
    for text in ("183:92", "0:276", "a:b", "5"):
        with pytest.raises(Exception, match="holdout-frames"):
            holdout_range(text, 275)


def test_keypoint_scores_count_a_missed_keypoint_as_wrong():
    labels = np.array([[[10.0, 10.0], [np.nan, np.nan]], [[20.0, 20.0], [5.0, 5.0]]])
    found = np.array([[[11.0, 10.0], [1.0, 1.0]], [[np.nan, np.nan], [5.0, 9.0]]])
    s = keypoint_scores(found, labels, ("a", "b"))
    assert s["keypoints"]["a"] == {"labelled": 2, "median_px": 1.0, "pck": 0.5}
    assert s["keypoints"]["b"] == {"labelled": 1, "median_px": 4.0, "pck": 1.0}
    assert s["found_share"] == pytest.approx(2 / 3)


def test_an_unreliable_teacher_is_refused_in_one_line(panda, meshes, tmp_path, capsys):
    calibrated(panda, meshes, tmp_path)
    doc = json.loads((tmp_path / "r.json").read_text())
    doc["quality"]["verdict"] = "unreliable"
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    capsys.readouterr()
    code = main(["adapt", "--data", str(tmp_path / "data"), "--result", str(tmp_path / "bad.json"),
                 "--model", str(BUNDLED_MODEL), "--out", str(tmp_path / "a.onnx")])
    err = capsys.readouterr().err
    assert code == 2 and "cannot teach" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "a.onnx").exists()


def test_holding_out_every_frame_or_writing_over_the_model_is_refused(panda, meshes, tmp_path,
                                                                      capsys):
    """Each fails in one line before any work: nothing left to teach; an --out that would
    replace the model being adapted (the model file stays as it was)."""
    calibrated(panda, meshes, tmp_path)
    model = tmp_path / "m.onnx"
    model.write_bytes(BUNDLED_MODEL.read_bytes())
    base = ["adapt", "--data", str(tmp_path / "data"), "--result", str(tmp_path / "r.json"),
            "--model", str(model)]
    count = len(read_sequence(tmp_path / "data"))
    (tmp_path / "old.onnx").write_bytes(b"a model in use")
    (tmp_path / "new.md").write_text("notes")
    for extra, message in (
            (["--out", str(tmp_path / "a.onnx"), "--holdout-frames", f"0:{count}"],
             "none is left to teach"),
            (["--out", str(model)], "would replace"),
            (["--out", str(tmp_path / "old.onnx")], "--overwrite to replace it"),
            (["--out", str(tmp_path / "new.onnx")], "new.md: exists"),
            (["--out", str(tmp_path / "a.onnx"), "--holdout-frames", "5-10"], "e.g. 10:20"),
            (["--out", str(tmp_path / "a.onnx"), "--model", str(tmp_path / "none.onnx")],
             "no such model file")):
        capsys.readouterr()
        code = main(base + extra)
        err = capsys.readouterr().err
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "a.onnx").exists() and not (tmp_path / "new.onnx").exists()
    assert model.read_bytes() == BUNDLED_MODEL.read_bytes()
    assert (tmp_path / "old.onnx").read_bytes() == b"a model in use"
    assert (tmp_path / "new.md").read_text() == "notes"


def test_an_interrupted_adapt_leaves_no_folder_it_made(panda, meshes, tmp_path, capsys,
                                                       monkeypatch):
    """Ctrl-C once the work began: "interrupted", exit 130, and the folder made for --out
    removed (it was left empty)."""
    import train.adapt

    calibrated(panda, meshes, tmp_path)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train.adapt, "teaching_set", interrupted)
    capsys.readouterr()
    code = main(["adapt", "--data", str(tmp_path / "data"), "--result", str(tmp_path / "r.json"),
                 "--model", str(BUNDLED_MODEL), "--out", str(tmp_path / "new" / "a.onnx")])
    assert code == 130 and "dream adapt: interrupted" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_an_overwrite_stopped_while_scoring_keeps_the_old_model_and_card(panda, meshes,
                                                                        tmp_path, capsys,
                                                                        monkeypatch):
    """The model and its card are placed together after the scoring: before, the new model
    was already in place beside the old card."""
    import train.adapt_report

    calibrated(panda, meshes, tmp_path)
    out = tmp_path / "a.onnx"
    out.write_bytes(b"the model in use")
    out.with_suffix(".md").write_text("its card")

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train.adapt_report, "holdout_report", stopped)
    code = main(["adapt", "--data", str(tmp_path / "data"), "--result", str(tmp_path / "r.json"),
                 "--model", str(BUNDLED_MODEL), "--out", str(out), "--overwrite", *TINY])
    assert code == 130, capsys.readouterr().err
    assert out.read_bytes() == b"the model in use"
    assert out.with_suffix(".md").read_text() == "its card"
    assert not list(tmp_path.glob("dream-adapt-*"))


def test_the_peak_finder_change_is_named():
    from dream.peaks import PeakSettings
    from train.adapt import peak_change

    assert peak_change(PeakSettings(), PeakSettings()) == ""
    assert peak_change(None, PeakSettings()) == ""
    words = peak_change(PeakSettings(ambiguity_ratio=1.0), PeakSettings(ambiguity_ratio=0.5))
    assert "ambiguity_ratio 1 -> 0.5" in words


def test_a_result_of_another_robot_or_camera_or_shape_is_refused(panda, meshes, tmp_path,
                                                                  capsys):
    """Each in one line, nothing created: a result for another robot, through other
    intrinsics than the recording's (labels would be wrong), with a `quality` that is not an
    object; a budget with no time to train."""
    calibrated(panda, meshes, tmp_path)
    doc = json.loads((tmp_path / "r.json").read_text())
    cases = [({**doc, "robot": "ur5"}, "for the robot 'ur5'"),
             ({**doc, "data": {**doc["data"], "camera": {**doc["data"]["camera"],
                                                         "fx": 2 * doc["data"]["camera"]["fx"]}}},
              "through another camera"),
             ({**doc, "quality": "good"}, "'quality' is not an object"),
             ({key: value for key, value in doc.items() if key != "data"} | {
                 "data": {"num_frames": 500}}, "calibrated on 500 frames, more than the"),
             (doc, "recipe the model was trained with is not here")]
    out = tmp_path / "new" / "a.onnx"
    for bad, message in cases:
        (tmp_path / "bad.json").write_text(json.dumps(bad))
        capsys.readouterr()
        recipe = ([] if bad is not doc else ["--config", str(tmp_path / "no_recipe.yaml")])
        code = main(["adapt", "--data", str(tmp_path / "data"), "--result",
                     str(tmp_path / "bad.json"), "--model", str(BUNDLED_MODEL), "--out", str(out),
                     *recipe])
        err = capsys.readouterr().err
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    with pytest.raises(InputError, match="no time to train"):
        AdaptRequest(data="d", result="r.json", model="m.onnx", out="a.onnx", minutes=1.0)
    assert not out.parent.exists()


def test_a_budget_the_renders_overran_still_trains_and_says_so(caplog):
    """Renders that eat the budget leave the least training, with a warning, not a failure
    after the work is done."""
    from train.adapt import MIN_TRAINING_MINUTES, SCORING_MINUTES, training_minutes

    with caplog.at_level(logging.WARNING, logger="train.adapt"):
        assert training_minutes(2.5, 10.0) == pytest.approx(2.5 - 10 / 60 - SCORING_MINUTES)
        assert not caplog.records
        assert training_minutes(2.5, 60.0) == MIN_TRAINING_MINUTES
    assert "beyond the budget" in caplog.text and "fewer --renders" in caplog.text


def test_the_labels_go_through_the_intrinsics_the_calibration_adopted(panda, meshes, tmp_path):
    """A focal length the search adopted, and a lens distortion the keypoint path adopted
    (RESULT.json's `start.focal`, `distortion`): the labels are projected through them."""
    calibrated(panda, meshes, tmp_path)
    doc = json.loads((tmp_path / "r.json").read_text())
    camera = doc["data"]["camera"]
    doc["start"] = {"focal": {"adopted": True, "used": {"fx": 1.04 * camera["fx"],
                                                        "fy": 1.04 * camera["fy"]}}}
    lens = [-0.1, 0.01, 0.0, 0.0, 0.0]
    for name, extra in (("f", {}), ("d", {"distortion": {"adopted": True,
                                                         "used": {"distortion": lens}}})):
        (tmp_path / f"{name}.json").write_text(json.dumps({**doc, **extra}))
        request = AdaptRequest(data=str(tmp_path / "data"), result=str(tmp_path / f"{name}.json"),
                               model=str(BUNDLED_MODEL), out=str(tmp_path / "a.onnx"))
        seq = teacher(request, io.StringIO())[0]
        assert seq.camera.fx == pytest.approx(1.04 * camera["fx"])
        assert (seq.camera.cx, seq.camera.width) == (camera["cx"], camera["width"])
        assert list(seq.camera.dist_coeffs) == (lens if extra else [0.0] * 5)


def test_a_teacher_calibrated_on_part_of_the_recording_is_accepted(panda, meshes, tmp_path):
    """A fixed camera calibrated on the first frames (a copy of them) labels the whole
    recording; a result of other content is still refused."""
    calibrated(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    write_dream(dataclasses.replace(seq, frames=seq.frames[:6]), tmp_path / "part")
    assert main(["calibrate", "--data", str(tmp_path / "part"), "--use-labels", "--refine",
                 "none", "--out", str(tmp_path / "part.json")]) == 0
    doc = json.loads((tmp_path / "part.json").read_text())
    check_same_data(doc, seq, "data", "part.json", part_ok=True)
    with pytest.raises(InputError, match="other data"):
        check_same_data(doc, seq, "data", "part.json")
    moved = dataclasses.replace(seq.frames[0], joints=seq.frames[0].joints + 0.1)
    changed = dataclasses.replace(seq, frames=(moved, *seq.frames[1:]))
    with pytest.raises(InputError, match="other data"):
        check_same_data(doc, changed, "data", "part.json", part_ok=True)


def test_frames_a_held_log_leaves_out_still_count_as_the_recordings(tmp_path):
    """Interpolating a held joint log leaves out the frames after its last update; the result
    was still calibrated on the whole recording, not on more frames than it has."""
    seq = make_injected_sequence(
        InjectionSettings(num_frames=40, frame_period_s=1 / 30, pixel_noise_px=1.0, seed=3),
        ModelExtension(held_readings=HeldReadings(0.2)))
    write_dream(seq, tmp_path / "data")
    assert main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--refine",
                 "none", "--out", str(tmp_path / "r.json")]) == 0
    request = AdaptRequest(data=str(tmp_path / "data"), result=str(tmp_path / "r.json"),
                           model=str(BUNDLED_MODEL), out=str(tmp_path / "a.onnx"))
    taught, _, _, doc, recorded = teacher(request, io.StringIO())
    assert recorded == doc["data"]["num_frames"] == 40
    assert 30 < len(taught) < recorded


def test_zoom_is_asked_for_and_a_set_override_still_wins(tmp_path):
    base = AdaptRequest(data="d", result="r.json", model="m.onnx", out="a.onnx")
    assert training_config(base, [str(tmp_path)], 1, 5.0).augment.zoom_p == 0.0
    zoomed = dataclasses.replace(base, zoom=True)
    assert training_config(zoomed, [str(tmp_path)], 1, 5.0).augment.zoom_p == ZOOM_SHARE
    mine = dataclasses.replace(zoomed, overrides=("augment.zoom_p=0.2",))
    assert training_config(mine, [str(tmp_path)], 1, 5.0).augment.zoom_p == 0.2


@pytest.mark.slow
@pytest.mark.parametrize("zoom", [False, True])
def test_adapt_writes_a_model_that_calibrate_runs_unchanged(panda, meshes, tmp_path, capsys,
                                                            monkeypatch, zoom):
    """Run from another folder than the repository's, without --config: the bundled model's
    recipe is found all the same. With --zoom the adapted model carries its zoom, and adapting
    it again keeps it unless `--set augment.zoom_p=0` says not to."""
    from export.runner import OnnxKeypointModel

    calibrated(panda, meshes, tmp_path)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "adapted.onnx"
    code = main(["adapt", "--data", str(tmp_path / "data"), "--result", str(tmp_path / "r.json"),
                 "--model", str(BUNDLED_MODEL), "--out", str(out), "--holdout-frames", "6:10",
                 *TINY, *(["--zoom"] if zoom else [])])
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "PCK@5" in printed and "each frame's keypoint extrinsic" in printed
    card = out.with_suffix(".md").read_text()
    assert "adapted to one recording" in card and "Frames 6-9 were held out" in card
    assert "and 6 of it in the recording's scene" in card
    assert f"`{(tmp_path / 'data').resolve()}`" in card
    assert re.search(r"\(\d+ steps, \d+\.\d minutes of training", card)
    assert "ambiguity_ratio 1 -> 0.5" in card and "ambiguity_ratio 1 -> 0.5" in err
    assert not list(tmp_path.glob("dream-adapt-*"))          # the work folder is gone
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--model", str(out),
                 "--refine", "none", "--out", str(tmp_path / "again.json")])
    _, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads((tmp_path / "again.json").read_text())
    assert doc["keypoints_used"] > 0
    assert (OnnxKeypointModel(out).zoom is not None) == zoom
    assert ("Zoom: trained on inputs cut around the keypoints" in card) == zoom
    if zoom:
        again = tmp_path / "again.onnx"
        code = main(["adapt", "--data", str(tmp_path / "data"), "--result",
                     str(tmp_path / "r.json"), "--model", str(out), "--out", str(again),
                     "--holdout-frames", "6:10", *TINY])
        _, err = capsys.readouterr()
        assert code == 0, err
        assert "the adapted model is trained to as well" in err
        assert OnnxKeypointModel(again).zoom is not None
        plain = tmp_path / "plain.onnx"             # unless the recipe is told otherwise
        code = main(["adapt", "--data", str(tmp_path / "data"), "--result",
                     str(tmp_path / "r.json"), "--model", str(out), "--out", str(plain),
                     "--holdout-frames", "6:10", *TINY, "--set", "augment.zoom_p=0"])
        _, err = capsys.readouterr()
        assert code == 0, err
        assert "the adapted model will not (augment.zoom_p is 0)" in err
        assert OnnxKeypointModel(plain).zoom is None
        assert "Zoom:" not in plain.with_suffix(".md").read_text()


def test_docstring_examples_run():
    import doctest

    import train.adapt
    import train.adapt_report

    for module in (train.adapt, train.adapt_report):
        assert doctest.testmod(module).failed == 0
