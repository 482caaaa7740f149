"""The public Python API: `help(dream)` lists it, the README's example runs as written, and
the docstring examples hold."""

from __future__ import annotations

import doctest
import importlib
import pydoc
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dream

REPO = Path(__file__).resolve().parents[2]

DOCTEST_MODULES = ("dream.api", "dream.arrays", "dream.readings", "dream.optim.lm",
                   "dream.optim.robust", "dream.edges.search", "dream.edges.background",
                   "dream.settings_checks", "dream.polish.frames", "dream.polish.objective",
                   "dream.quality", "dream.edges.motion", "dream.edges.frames",
                   "dream.edges.refine", "dream.refined_uncertainty",
                   "dream.coarse.hypotheses", "dream.coarse.evidence", "dream.coarse.search",
                   "dream.coarse.verdict", "dream.coarse.mark", "dream.coarse.challenge",
                   "dream.cli.calibrate_start", "dream.rasterize", "dream.overlay",
                   "dream.coarse.away", "dream.coarse.crosscheck", "dream.steadiness",
                   "dream.cli.options", "export.card", "dream.robot.identity",
                   "dream.refinement_document", "batch.recordings", "dream.cli.app",
                   "dream.io.marks", "dream.focal_check", "dream.readings_check",
                   "dream.io.npz", "dream.coarse.checks",
                   "dream.coarse.timing", "dream.coarse.intrinsics", "dream.principal_check",
                   "dream.keypoint_camera_fit", "dream.result", "dream.cli.keypoint_pass")
API = ("read_sequence", "load_robot", "load_keypoint_model", "detect", "labels", "calibrate",
       "polish_result", "refine_edges", "evaluate", "diagnose", "result_document", "read_result",
       "BUNDLED_MODEL")


def readme_python_example() -> str:
    text = (REPO / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert blocks, "README.md has no ```python example"
    return blocks[0]


def test_help_lists_the_api() -> None:
    text = pydoc.render_doc(dream, renderer=pydoc.plaintext)
    for name in API:
        assert name in text, name
    assert set(API) <= set(dir(dream))


def test_import_dream_is_cheap() -> None:
    """`import dream` loads no solver, reader or model runtime until a name is used."""
    code = ("import sys, dream; heavy = [m for m in ('cv2', 'onnxruntime', 'mujoco', 'torch', "
            "'scipy') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"


def test_api_names_are_the_functions_not_submodules() -> None:
    importlib.import_module("dream.pipeline")  # loads the solver modules first
    for name in API:
        assert not isinstance(getattr(dream, name), type(dream)), name


@pytest.mark.parametrize("module", DOCTEST_MODULES)
def test_docstring_examples(module: str) -> None:
    failed, tried = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS)
    assert failed == 0
    assert tried > 0


def test_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'calibrat'"):
        dream.calibrat  # noqa: B018


def test_readme_example_runs_as_written(tmp_path, monkeypatch, capsys) -> None:
    """`dream demo --out demo` writes demo/scene; the README's Python example then calibrates
    it (the bundled model, onnxruntime) to the demo's figures."""
    from dream.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--out", "demo"]) == 0
    capsys.readouterr()
    namespace: dict = {}
    exec(compile(readme_python_example(), "README.md", "exec"), namespace)
    printed = capsys.readouterr().out
    result = namespace["result"]
    assert result.T_cam_base.shape == (4, 4) and np.all(np.isfinite(result.T_cam_base))
    assert "translation_error_m" in printed
    metrics = dream.evaluate(namespace["sequence"], namespace["robot"], result,
                             namespace["observations"])
    assert metrics["translation_error_m"]["median"] < 0.02  # the demo: about 9 mm


def _labelled_scene(tmp_path: Path, frames: int = 30):
    """A labelled keypoint-only recording written as a DREAM folder, read back checked."""
    from dream.inject import InjectionSettings, make_injected_sequence
    from dream.io import write_dream

    write_dream(make_injected_sequence(InjectionSettings(num_frames=frames, seed=3)),
                tmp_path / "scene")
    sequence = dream.read_sequence(tmp_path / "scene")
    return tmp_path / "scene", sequence, dream.load_robot(sequence)


def test_the_api_refuses_what_the_commands_refuse(tmp_path) -> None:
    """Joints in degrees, intrinsics of another resolution, observations of other frames, a
    result of other data: each an `InputError`, as the commands give (they passed the API
    and calibrated 0.7-1.2 m off)."""
    import dataclasses

    from dream.camera import CameraIntrinsics

    folder, sequence, robot = _labelled_scene(tmp_path)
    in_degrees = dataclasses.replace(sequence, frames=tuple(
        dataclasses.replace(f, joints=np.degrees(f.joints))
        for f in sequence.frames))
    with pytest.raises(dream.InputError, match="degrees"):
        dream.labels(in_degrees, robot)
    c = sequence.camera
    with pytest.raises(dream.InputError, match="centre"):
        dream.read_sequence(folder, intrinsics=CameraIntrinsics(
            c.fx, c.fy, 2 * c.cx, 2 * c.cy, c.width, c.height))
    observations = dream.labels(sequence, robot)
    part = dataclasses.replace(sequence, frames=sequence.frames[:10])
    with pytest.raises(dream.InputError, match="observations are of 30 frames"):
        dream.calibrate(part, observations)
    with pytest.raises(dream.InputError, match="SolverSettings"):
        dream.calibrate(sequence, observations, settings={"seed": 1})
    with pytest.raises(dream.InputError, match="list of link names"):
        dream.load_robot("panda", keypoints="panda_link0")
    listed = dataclasses.replace(observations, frame_names=list(observations.frame_names))
    result = dream.calibrate(sequence, listed)       # the names as a list are the same frames
    document = dream.result_document(result, observations, robot)
    from pathlib import PurePosixPath

    from dream.provenance import data_record

    assert len(dream.read_sequence(PurePosixPath(folder))) == len(sequence)

    document["data"] = data_record(part, "part")
    with pytest.raises(dream.InputError, match="other data .* than the sequence"):
        dream.evaluate(sequence, robot, document)
    document = dream.result_document(result, observations, robot, sequence)
    assert document["data"] == data_record(sequence, str(folder))
    assert document["quality"]["verdict"] in ("good", "check")
    assert dream.evaluate(sequence, robot, document)["translation_error_m"]["median"] < 0.01


def test_the_camera_position_sigma_includes_the_rotation(tmp_path) -> None:
    """`sigma_camera_position_base_m` is RESULT.json's; the camera-axis translation sigma
    leaves the rotation's share out (5x smaller on the demo)."""
    _, sequence, robot = _labelled_scene(tmp_path)
    observations = dream.labels(sequence, robot)
    result = dream.calibrate(sequence, observations)
    document = dream.result_document(result, observations, robot)
    assert np.allclose(result.sigma_camera_position_base_m,
                       document["sigma_camera_position_base_m"])
    assert np.linalg.norm(result.sigma_camera_position_base_m) > np.linalg.norm(
        result.sigma_translation_m)


def test_detect_takes_the_model_file(tmp_path) -> None:
    from dream.cli import main

    assert main(["demo", "--out", str(tmp_path / "demo")]) == 0
    sequence = dream.read_sequence(tmp_path / "demo" / "scene")
    observations = dream.detect(sequence, dream.load_robot(sequence), dream.BUNDLED_MODEL)
    assert observations.found.any()
