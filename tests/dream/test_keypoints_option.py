"""`dream robots --urdf` and `--keypoints` on the commands that load a robot: a user URDF's
keypoint links on the command line, checked against the URDF and against the keypoints a
model, the labels or a result already fix."""

from __future__ import annotations

import json
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_keypoint_choice import lbr_urdf

from dream.cli import main
from dream.cli.options import parse_keypoints
from dream.errors import InputError
from dream.io import read_sequence, write_dream
from dream.pipeline import robot_for, robot_with_option_keypoints

LBR_KEYPOINTS = tuple(f"lbr_link_{i}" for i in range(8)) + ("lbr_link_ee",)
ON_THE_AXIS = "lbr_link_0,lbr_link_1,lbr_link_2"


def run(argv: list, capsys) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(code: int, err: str) -> str:
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def med7(tmp_path_factory) -> Path:
    return lbr_urdf(tmp_path_factory.mktemp("urdf"))


@pytest.fixture(scope="module")
def med7_data(med7, tmp_path_factory) -> Path:
    """Keypoint-only frames of the LBR-shaped arm, with blank images to draw overlays on."""
    import cv2

    folder = tmp_path_factory.mktemp("med7_data")
    labels = folder / "labels"
    assert main(["sample", "--robot", str(med7), "--keypoints", ",".join(LBR_KEYPOINTS),
                 "--num", "6", "--out", str(labels)]) == 0
    seq = read_sequence(labels)
    blank = folder / "blank.png"
    cv2.imwrite(str(blank), np.zeros((seq.camera.height, seq.camera.width, 3), np.uint8))
    write_dream(replace(seq, frames=tuple(replace(f, image_path=blank) for f in seq.frames)),
                folder / "data")
    return folder / "data"


def test_robots_lists_builtins_and_describes_one(capsys):
    code, out, _ = run(["robots"], capsys)
    assert code == 0 and out.count("  why: ") == 3
    code, out, _ = run(["robots", "--urdf", "panda"], capsys)
    assert code == 0
    assert "suggested keypoints (7): panda_link0, panda_link2, panda_link3, panda_link4," in out
    assert "built-in keypoints (the same)" in out
    assert "panda_link1 = panda_link2" in out and "panda_joint4" in out and "prismatic" in out
    code, same, _ = run(["robots", "--robot", "panda"], capsys)       # the other spelling
    assert code == 0 and same == out


def test_robots_warns_about_keypoints_on_the_base_axis(med7, capsys):
    code, out, _ = run(["robots", "--urdf", med7, "--keypoints", ON_THE_AXIS], capsys)
    assert code == 0
    flat = " ".join(out.split())
    assert f"--keypoints {','.join(LBR_KEYPOINTS)}" in flat
    assert ("warning: the suggested keypoints lbr_link_0, lbr_link_1, lbr_link_2 stay on one "
            "line, the same for every joint value") in flat
    assert ("warning: all the given keypoints stay on one line, the same for every joint value: "
            "PnP cannot solve the camera") in flat
    code, out, _ = run(["robots", "--urdf", med7, "--keypoints",
                        "lbr_link_0,lbr_link_2,lbr_link_3,camera_mount"], capsys)
    assert code == 0 and "no two coincide and no three stay on one line" in out


def test_robots_refuses_unknown_links(med7, capsys):
    code, _, err = run(["robots", "--urdf", med7, "--keypoints", "lbr_link_0,lbr_link_9"],
                       capsys)
    line = one_error_line(code, err)
    assert "'lbr_link_9', not a link of robot" in line and f"dream robots --urdf {med7}" in line
    code, _, err = run(["robots", "--keypoints", "a,b"], capsys)
    assert "add --urdf FILE" in one_error_line(code, err)


def test_overlay_takes_keypoints_for_a_user_urdf(med7, med7_data, tmp_path, capsys):
    # without --keypoints the outline alone is drawn (no keypoints are needed for it) ...
    boxed = tmp_path / "boxed.urdf"
    box = '<visual><geometry><box size="0.08 0.08 0.2"/></geometry></visual>'
    boxed.write_text(med7.read_text().replace('<link name="lbr_link_2"/>',
                                              f'<link name="lbr_link_2">{box}</link>'))
    code, out, err = run(["overlay", med7_data, "--robot", boxed, "--out", tmp_path / "a",
                          "--limit", "2"], capsys)
    assert code == 0, err
    assert "drawing the outline alone" in out and "wrote 2 overlay images" in out
    # ... so a URDF without geometry to outline has nothing to draw
    code, _, err = run(["overlay", med7_data, "--robot", med7, "--out", tmp_path / "none"],
                       capsys)
    assert "has no visual geometry" in one_error_line(code, err)
    assert not (tmp_path / "none").exists()
    code, _, err = run(["overlay", med7_data, "--robot", med7, "--keypoints",
                        "lbr_link_0,nope", "--out", tmp_path / "b"], capsys)
    line = one_error_line(code, err)
    assert "--keypoints names 'nope', not a link of robot" in line
    assert f"dream robots --urdf {med7}" in line
    code, out, err = run(["overlay", med7_data, "--robot", med7, "--keypoints",
                          ",".join(LBR_KEYPOINTS), "--out", tmp_path / "c", "--limit", "2"],
                         capsys)
    assert code == 0, err
    assert "wrote 2 overlay images" in out


def test_labels_and_results_fix_the_keypoints(med7, med7_data, tmp_path, capsys):
    result = tmp_path / "r.json"
    code, _, err = run(["calibrate", "--data", med7_data, "--robot", med7, "--use-labels",
                        "--keypoints", ON_THE_AXIS, "--refine", "none", "--out", result],
                       capsys)
    line = one_error_line(code, err)
    assert "--keypoints lbr_link_0,lbr_link_1,lbr_link_2 contradicts the keypoints of the " \
           "labels" in line and "drop --keypoints" in line
    # the same links in another order agree with the labels
    code, out, err = run(["calibrate", "--data", med7_data, "--robot", med7, "--use-labels",
                          "--keypoints", ",".join(reversed(LBR_KEYPOINTS)), "--refine", "none",
                          "--out", result], capsys)
    assert code == 0, err
    assert [k["name"] for k in json.loads(result.read_text())["per_frame"][0]["keypoints"]] \
        == list(LBR_KEYPOINTS)
    code, _, err = run(["eval", "--data", med7_data, "--robot", med7, "--result", result,
                        "--keypoints", "lbr_link_0,lbr_link_3,lbr_link_5,lbr_link_ee", "--out",
                        tmp_path / "m.json"], capsys)
    assert "contradicts the keypoints of" in one_error_line(code, err)
    code, _, err = run(["eval", "--data", med7_data, "--robot", med7, "--result", result,
                        "--out", tmp_path / "m.json"], capsys)
    assert code == 0, err


def test_keypoints_on_one_line_are_a_warning(med7, med7_data, caplog):
    seq = read_sequence(med7_data)
    with caplog.at_level(logging.WARNING, logger="dream"):
        robot = robot_for(seq, str(med7), option_keypoints=tuple(ON_THE_AXIS.split(",")))
    assert robot.keypoint_names == tuple(ON_THE_AXIS.split(","))
    assert "stay on one line (the same for every joint value)" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="dream"):
        robot_with_option_keypoints(str(med7), LBR_KEYPOINTS)
    assert caplog.text == ""


def test_parse_keypoints_refuses_empty_and_repeated_names():
    assert parse_keypoints(None) is None
    assert parse_keypoints(" a, b ,c") == ("a", "b", "c")
    with pytest.raises(InputError, match="empty link name"):
        parse_keypoints("a,,b")
    with pytest.raises(InputError, match="names a twice"):
        parse_keypoints("a,b,a")


def test_plan_takes_keypoints(med7):
    from plan.cli import PlanRequest, _robot

    request = PlanRequest(robot=str(med7), camera="1,0,1", out="unused",
                          keypoints="lbr_link_0,lbr_link_3,lbr_link_5,lbr_link_ee")
    assert _robot(request).keypoint_names == ("lbr_link_0", "lbr_link_3", "lbr_link_5",
                                              "lbr_link_ee")
    with pytest.raises(InputError, match="'nope', not a link"):
        _robot(replace(request, keypoints="lbr_link_0,nope"))


def test_the_search_refuses_keypoints_the_urdf_lacks(med7, med7_data, tmp_path, capsys):
    """Without a model the search needs no keypoints, but links named that the URDF lacks
    are a mistake all the same (the suggested ones were taken in their place); dream synth
    names them as the other commands do."""
    code, _, err = run(["calibrate", "--data", med7_data, "--robot", med7, "--keypoints",
                        "lbr_link_0,nope", "--camera-guess", "1.5,0.5,1", "--look-at",
                        "0,0,0.4", "--out", tmp_path / "r.json"], capsys)
    assert "'nope', not a link of robot" in one_error_line(code, err)
    assert not (tmp_path / "r.json").exists()
    code, _, err = run(["synth", "--robot", med7, "--keypoints", "lbr_link_0,nope", "--num", "2",
                        "--out", tmp_path / "renders"], capsys)
    line = one_error_line(code, err)
    assert "'nope', not a link of robot" in line and f"dream robots --urdf {med7}" in line
    assert not (tmp_path / "renders").exists()


def test_eval_of_a_result_without_keypoints_scores_the_labels_links(med7, med7_data, tmp_path,
                                                                      capsys):
    """A result of the image search has no keypoints: its ADD is over the labels' links, and
    it has no keypoint error or PCK to report (null, not 0)."""
    result = tmp_path / "r.json"
    code, _, err = run(["calibrate", "--data", med7_data, "--robot", med7, "--use-labels",
                        "--refine", "none", "--out", result], capsys)
    assert code == 0, err
    doc = json.loads(result.read_text())
    for entry in doc["per_frame"]:
        entry.pop("keypoints", None)
    result.write_text(json.dumps(doc))
    code, out, err = run(["eval", "--data", med7_data, "--robot", med7, "--result", result,
                          "--out", tmp_path / "m.json"], capsys)
    assert code == 0, err
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["pck_auc"] is None and metrics["keypoint_l2_px"] is None
    assert metrics["add_m"]["median"] < 0.01 and "none in the result" in out
