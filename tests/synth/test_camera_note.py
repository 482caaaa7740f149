"""The note on fixed intrinsics overriding a recipe's random field of view (no rendering)."""

import logging
import math
from pathlib import Path

import pytest

import synth.generate
from synth.camera_note import fixed_camera_note
from synth.cli import cmd_synth
from synth.config import load_config

CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "synth"
REAL_WORLD = CONFIGS / "real_world.yaml"
TELEOP = CONFIGS / "panda_teleop_like.yaml"
CAMERA = ["intrinsics.width=320", "intrinsics.height=180", "intrinsics.fx=200.0",
          "intrinsics.fy=200.0", "intrinsics.cx=159.5", "intrinsics.cy=89.5"]


def note(path, overrides):
    return fixed_camera_note(load_config(path, overrides), path, overrides)


@pytest.mark.parametrize("path, degrees", [(None, "52-74 deg"), (REAL_WORLD, "52-100 deg")])
def test_fixed_intrinsics_over_a_random_field_of_view_are_noted(path, degrees):
    text = note(path, CAMERA)
    hfov = 2 * math.atan(160 / 200.0)
    assert "\n" not in text
    assert f"intrinsics.hfov_rad {degrees}" in text and "is not used" in text
    assert f"{math.degrees(hfov):.1f} deg at width 320" in text
    assert f"intrinsics.hfov_rad=[{hfov * 0.9:.2f},{hfov * 1.1:.2f}]" in text


def test_the_suggested_range_loads_and_draws_lenses():
    text = note(None, CAMERA)
    suggestion = text.split("--set \"")[1].split("\"")[0]
    config = load_config(None, ["intrinsics.width=320", "intrinsics.height=180", suggestion])
    assert not config.intrinsics.fixed
    assert note(None, ["intrinsics.width=320", suggestion]) is None


@pytest.mark.parametrize("path, overrides", [
    (None, []),                                   # random field of view, nothing fixed
    (REAL_WORLD, ["intrinsics.width=640"]),
    (TELEOP, []),                                 # a fixed-camera recipe without hfov_rad
    (TELEOP, ["intrinsics.fx=160.0"]),
])
def test_no_note_without_an_overridden_random_field_of_view(path, overrides):
    assert note(path, overrides) is None


def test_a_recipe_giving_both_is_noted(tmp_path):
    recipe = tmp_path / "camera.yaml"
    recipe.write_text("intrinsics:\n  fx: 300.0\n  fy: 300.0\n  cx: 159.5\n  cy: 119.5\n"
                      "  hfov_rad: [0.9, 1.5]\n")
    assert "52-86 deg" in note(recipe, [])
    assert "52-57 deg" in note(TELEOP, ["intrinsics.hfov_rad=[0.9,1.0]"])


def test_dream_synth_logs_the_note_in_one_line(monkeypatch, caplog, tmp_path):
    def fake_generate(job, overwrite, on_progress, on_start):
        return {"rendered": 0, "skipped": 0, "frames_per_s": 0.0}

    monkeypatch.setattr(synth.generate, "generate", fake_generate)
    args = type("Args", (), dict(robot="panda", keypoints=None, model_extension=None,
                                 num=1, out=str(tmp_path / "out"), config=None, set=CAMERA,
                                 seed=0, workers=1, contact_sheet=None, overwrite=False))
    with caplog.at_level(logging.WARNING, logger="synth"):
        assert cmd_synth(args) == 0
    lines = [r.getMessage() for r in caplog.records if "hfov_rad" in r.getMessage()]
    assert len(lines) == 1 and "\n" not in lines[0]
