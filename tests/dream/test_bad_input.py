"""Bad input through the command line: one error line naming the culprit and the fix, exit 2,
and nothing half-written (output paths under a file, corrupt images, malformed results and
model extensions, out-of-range options)."""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from dream.cli import BUNDLED_MODEL, main
from dream.errors import CalibrationError, InputError
from dream.extension import extension_from_effects, extension_yaml, read_extension
from dream.io import (
    check_output_file,
    check_output_folder,
    is_temporary,
    staged_directory,
    write_dream,
    write_files_atomic,
)
from dream.recipe import load_recipe
from dream.result import read_result
from dream.sample import SampleSettings, make_sample

FRAMES = 4
WIDTH, HEIGHT, FOCAL = 160, 120, 150.0  # the sample's field of view on small images


def run(argv: list, capsys) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(code: int, err: str) -> str:
    """The single stderr line of a refused command (exit 2, no traceback)."""
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def refused(argv: list, capsys) -> str:
    code, _, err = run(argv, capsys)
    return one_error_line(code, err)


def leftovers(folder: Path) -> list[str]:
    """Names in `folder`, temporaries of the atomic writers included."""
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture(scope="module")
def labels(tmp_path_factory) -> Path:
    """A keypoint-only sample (labels, truth, no images)."""
    out = tmp_path_factory.mktemp("labels") / "data"
    assert main(["sample", "--out", str(out), "--num", "6", "--seed", "5"]) == 0
    return out


@pytest.fixture(scope="module")
def imaged(tmp_path_factory) -> Path:
    """A small sample with (random) images, for the commands that draw on or detect in them."""
    root = tmp_path_factory.mktemp("imaged")
    seq = make_sample(SampleSettings(num_frames=FRAMES, seed=2, width=WIDTH, height=HEIGHT,
                                     fx=FOCAL, fy=FOCAL, pixel_noise_px=0.0))
    rng = np.random.default_rng(0)
    frames = []
    for frame in seq.frames:
        path = root / f"{frame.name}.png"
        cv2.imwrite(str(path), rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8))
        frames.append(replace(frame, image_path=path))
    return write_dream(replace(seq, frames=tuple(frames)), root / "data")


def copy_of(data: Path, dest: Path) -> Path:
    dest.mkdir()
    for f in data.iterdir():
        (dest / f.name).write_bytes(f.read_bytes())
    return dest


@pytest.fixture
def afile(tmp_path) -> Path:
    path = tmp_path / "afile"
    path.write_text("not a folder\n")
    return path


# ---------------------------------------------------------------- 1. output under a file


def test_output_folder_that_is_or_lies_under_a_file(imaged, afile, tmp_path, capsys,
                                                    monkeypatch):
    for out in (afile, afile / "ov"):
        line = refused(["overlay", imaged, "--out", out], capsys)
        assert str(out) in line and "Fix:" in line
    line = refused(["calibrate", "--data", imaged, "--use-labels", "--out", tmp_path / "r.json",
                    "--overlays", afile / "ov"], capsys)
    assert "afile" in line and "is a file" in line
    assert not (tmp_path / "r.json").exists()

    import dream.diagnosis.run as diagnose_run

    def must_not_run(*args, **kwargs):
        raise AssertionError("the diagnosis ran before its output folder was checked")

    monkeypatch.setattr(diagnose_run, "diagnose_sequence", must_not_run)
    line = refused(["diagnose", "--data", imaged, "--use-labels", "--out", afile / "d"], capsys)
    assert str(afile / "d") in line and "is a file" in line
    # the library call checks too, before the analysis
    with pytest.raises(InputError, match="is a file"):
        diagnose_run.run_diagnosis(None, None, None, afile / "d")


def test_output_helpers(tmp_path, afile):
    with pytest.raises(InputError, match="is a file") as exc:
        check_output_folder(afile / "x" / "y")
    assert exc.value.path == afile / "x" / "y" and exc.value.fix
    with pytest.raises(InputError, match="expected a folder"):
        check_output_folder(afile)
    with pytest.raises(InputError, match="is a folder"):
        check_output_file(tmp_path)
    with pytest.raises(InputError, match="does not exist"):
        check_output_file(tmp_path / "missing" / "r.json")
    assert check_output_folder(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()  # checking creates nothing
    # a failure inside a staged folder leaves nothing, not even the parents it created
    with pytest.raises(RuntimeError), staged_directory(tmp_path / "a" / "b") as stage:
        (stage / "x.png").write_bytes(b"x")
        raise RuntimeError("drawing failed")
    assert leftovers(tmp_path) == ["afile"]
    # success into an existing folder: files join it, others are kept
    (tmp_path / "ov").mkdir()
    (tmp_path / "ov" / "keep.txt").write_text("k")
    with staged_directory(tmp_path / "ov") as stage:
        (stage / "new.png").write_bytes(b"n")
    assert leftovers(tmp_path / "ov") == ["keep.txt", "new.png"]
    # several files: all or none
    (tmp_path / "b.txt").mkdir()
    with pytest.raises(InputError, match="is a folder"):
        write_files_atomic({tmp_path / "a.txt": b"a", tmp_path / "b.txt": b"b"})
    assert not (tmp_path / "a.txt").exists()
    assert not [n for n in leftovers(tmp_path) if is_temporary(tmp_path / n)]


# ---------------------------------------------------------------- 2. seeds


def test_negative_seed_is_refused_naming_the_option(labels, tmp_path, capsys):
    line = refused(["sample", "--out", tmp_path / "s", "--num", "3", "--seed", "-1"], capsys)
    assert "--seed" in line and "Fix:" in line
    line = refused(["demo", "--keypoints-only", "--seed", "-1", "--out", tmp_path / "d"],
                   capsys)
    assert "--seed" in line
    line = refused(["calibrate", "--data", labels, "--use-labels", "--seed", "-5", "--out",
                    tmp_path / "r.json"], capsys)
    assert "--seed" in line
    assert leftovers(tmp_path) == []
    with pytest.raises(InputError, match="seed"):
        SampleSettings(seed=-1)


# ---------------------------------------------------------------- 3. malformed RESULT.json


@pytest.fixture(scope="module")
def each_result(labels, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("result") / "each.json"
    assert main(["calibrate", "--data", str(labels), "--use-labels", "--frames", "each",
                 "--out", str(path)]) == 0
    return path


@pytest.mark.parametrize("edit, named", [
    (lambda d: d["per_frame"][1].update(T_cam_base="abc"), "per_frame[1].T_cam_base"),
    (lambda d: d["per_frame"][1].update(T_cam_base=[[1, 2], [3, 4]]), "per_frame[1].T_cam_base"),
    (lambda d: d["per_frame"][1].update(T_cam_base=[[2.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                    [0, 0, 0, 1]]), "per_frame[1].T_cam_base"),
    (lambda d: d["per_frame"][1].update(keypoints="abc"), "per_frame[1].keypoints"),
    (lambda d: d["per_frame"][0].update(keypoints=[3]), "per_frame[0].keypoints[0]"),
    (lambda d: d["per_frame"][0]["keypoints"][0].update(uv=[1, "x"]), "uv[1]"),
    (lambda d: d["per_frame"][0].pop("frame"), "per_frame[0].frame"),
    (lambda d: d.update(frames_mode="zzz"), "frames_mode"),
    (lambda d: d.update(T_cam_base=None), "T_cam_base"),
    (lambda d: d.update(T_cam_base=d["T_cam_base"][:3]), "T_cam_base"),
    (lambda d: d.update(robot=["panda"]), "robot"),
])
def test_eval_refuses_a_malformed_result(labels, each_result, tmp_path, capsys, edit, named):
    doc = json.loads(each_result.read_text())
    edit(doc)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(InputError) as exc:
        read_result(bad)
    assert exc.value.path == bad and exc.value.fix and named in exc.value.problem
    line = refused(["eval", "--data", labels, "--result", bad, "--out", tmp_path / "m.json"],
                   capsys)
    assert str(bad) in line and "Fix:" in line
    assert not (tmp_path / "m.json").exists()


def test_unreadable_results_say_what_to_do(each_result, tmp_path):
    truncated = tmp_path / "t.json"
    truncated.write_bytes(each_result.read_bytes()[:500])
    for path in (truncated, tmp_path / "missing.json"):
        with pytest.raises(InputError) as exc:
            read_result(path)
        assert exc.value.path == path and exc.value.fix


def test_eval_names_the_result_for_its_robot_and_keypoints(labels, each_result, tmp_path,
                                                          capsys):
    doc = json.loads(each_result.read_text())
    doc["robot"] = "bogusbot"
    bad = tmp_path / "robot.json"
    bad.write_text(json.dumps(doc))
    line = refused(["eval", "--data", labels, "--result", bad, "--out", tmp_path / "m.json"],
                   capsys)
    assert str(bad) in line and "bogusbot" in line and "Fix:" in line


# ---------------------------------------------------------------- 4, 5. nothing half-written


def test_a_corrupt_image_leaves_no_overlays(imaged, tmp_path, capsys):
    data = copy_of(imaged, tmp_path / "data")
    png = data / "000002.rgb.png"
    png.write_bytes(png.read_bytes()[:-100])
    line = refused(["overlay", data, "--out", tmp_path / "ov"], capsys)
    assert "000002.rgb.png" in line
    line = refused(["calibrate", "--data", data, "--use-labels", "--overlays",
                    tmp_path / "n1" / "ovt", "--out", tmp_path / "r.json"], capsys)
    assert "000002.rgb.png" in line
    assert leftovers(tmp_path) == ["data"]
    # an existing overlay folder keeps what it had
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "000000.overlay.png").write_bytes(b"old")
    refused(["overlay", data, "--out", tmp_path / "old"], capsys)
    assert leftovers(tmp_path / "old") == ["000000.overlay.png"]
    assert (tmp_path / "old" / "000000.overlay.png").read_bytes() == b"old"


def test_calibrate_writes_its_files_and_overlays_all_or_none(imaged, afile, tmp_path, capsys):
    line = refused(["calibrate", "--data", imaged, "--use-labels", "--overlays",
                    tmp_path / "ovleft", "--out", afile / "r.json"], capsys)
    assert "afile" in line
    (tmp_path / "half.ros.txt").mkdir()
    line = refused(["calibrate", "--data", imaged, "--use-labels", "--overlays",
                    tmp_path / "ov", "--out", tmp_path / "half.json"], capsys)
    assert "half.ros.txt" in line and "Fix:" in line
    assert leftovers(tmp_path) == ["afile", "half.ros.txt"]
    code, _, err = run(["calibrate", "--data", imaged, "--use-labels", "--overlays",
                        tmp_path / "ov", "--out", tmp_path / "r.json"], capsys)
    assert code == 0, err
    assert leftovers(tmp_path) == ["afile", "half.ros.txt", "ov", "r.T_base_cam.txt",
                                   "r.handeye.yaml", "r.json", "r.launch.py", "r.ros.txt",
                                   "r.urdf.xml"]
    assert len(list((tmp_path / "ov").glob("*.result.png"))) == FRAMES
    assert (tmp_path / "ov" / "summary.png").is_file()


def test_a_failed_calibrate_keeps_the_previous_results(imaged, tmp_path, capsys):
    """A run that fails while drawing its overlays puts RESULT.json and its two text files
    back as an earlier run wrote them (not removed, not replaced)."""
    out = tmp_path / "r.json"
    code, _, err = run(["calibrate", "--data", imaged, "--use-labels", "--out", out], capsys)
    assert code == 0, err
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    data = copy_of(imaged, tmp_path / "data")
    png = data / "000002.rgb.png"
    png.write_bytes(png.read_bytes()[:-100])
    line = refused(["calibrate", "--data", data, "--use-labels", "--seed", "7", "--overlays",
                    tmp_path / "ov", "--out", out], capsys)
    assert "000002.rgb.png" in line
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.name != "data"}
    assert after == before


def test_replacing_files_restores_on_a_failed_rename_or_block(tmp_path, monkeypatch):
    import os

    from dream.io import replacing_files

    a, b, c = tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "c.txt"
    a.write_bytes(b"old a")
    b.write_bytes(b"old b")
    new = {a: b"new a", b: b"new b", c: b"new c"}
    with pytest.raises(RuntimeError), replacing_files(new):
        assert a.read_bytes() == b"new a" and c.read_bytes() == b"new c"
        raise RuntimeError("drawing the overlays failed")
    assert leftovers(tmp_path) == ["a.txt", "b.txt"]
    assert a.read_bytes() == b"old a" and b.read_bytes() == b"old b"
    real_replace, calls = os.replace, []

    def failing_third(src, dst):  # the third rename into place fails (disk full, say)
        calls.append(dst)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing_third)
    with pytest.raises(InputError, match="No space left") as info:
        write_files_atomic(new)
    monkeypatch.setattr(os, "replace", real_replace)
    assert info.value.path == c
    assert leftovers(tmp_path) == ["a.txt", "b.txt"]
    assert a.read_bytes() == b"old a" and b.read_bytes() == b"old b"
    assert write_files_atomic(new) == [a, b, c]
    assert [p.read_bytes() for p in (a, b, c)] == [b"new a", b"new b", b"new c"]
    assert leftovers(tmp_path) == ["a.txt", "b.txt", "c.txt"]


# ---------------------------------------------------------------- 6. demo model


def test_demo_checks_the_model_before_rendering(tmp_path, capsys, monkeypatch):
    synth_demo = pytest.importorskip("synth.demo")

    def must_not_render(*args, **kwargs):
        raise AssertionError("rendered before the model was checked")

    monkeypatch.setattr(synth_demo, "render_demo_scene", must_not_render)
    model = tmp_path / "garbage.onnx"
    model.write_bytes(b"\x00not a model" * 50)
    line = refused(["demo", "--out", tmp_path / "demo", "--model", model], capsys)
    assert str(model) in line
    assert not (tmp_path / "demo").exists()


# ---------------------------------------------------------------- 7, 8, 10. option values


@pytest.mark.parametrize("option, value", [("--noise-px", "nan"), ("--noise-px", "inf"),
                                           ("--noise-px", "-1"), ("--outliers", "nan"),
                                           ("--num", "0")])
def test_sample_refuses_bad_numbers(tmp_path, capsys, option, value):
    line = refused(["sample", "--out", tmp_path / "s", "--num", "3", option, value], capsys)
    assert option in line and "Fix:" in line
    assert not (tmp_path / "s").exists()
    with pytest.raises(InputError):
        SampleSettings(pixel_noise_px=float("nan"))


def test_overlay_limit(imaged, tmp_path, capsys):
    for limit in ("0", "-2"):
        line = refused(["overlay", imaged, "--out", tmp_path / "o", "--limit", limit], capsys)
        assert "--limit" in line
    assert leftovers(tmp_path) == []
    code, out, err = run(["overlay", imaged, "--out", tmp_path / "o", "--limit", "2"], capsys)
    assert code == 0, err
    assert "wrote 2 overlay images" in out
    assert len(list((tmp_path / "o").glob("*.overlay.png"))) == 2
    code, out, err = run(["overlay", imaged, "--out", tmp_path / "all", "--limit", "99"], capsys)
    assert code == 0 and f"wrote {FRAMES} overlay images" in out


def test_batch_zero_is_refused(imaged, tmp_path, capsys):
    for batch in ("0", "-4"):
        line = refused(["calibrate", "--data", imaged, "--model", BUNDLED_MODEL, "--batch", batch,
                        "--out", tmp_path / "r.json"], capsys)
        assert "--batch" in line
    assert leftovers(tmp_path) == []


# ---------------------------------------------------------------- 9. model extensions


@pytest.mark.parametrize("text, named", [
    ("format: something-else\nversion: 1\neffects: {}\n", "format"),
    ("format: dream-model-extension\nversion: 99\neffects: {}\n", "version 99"),
    ("effects:\n  lens_distortion: {k_1: 0.1}\n", "k_1"),
    ("effects:\n  time_offset: {seconds: 0.01, bogus: 3}\n", "bogus"),
    ("effects:\n  intrinsics_error: {fx: 1, fy: 1, cx: 1, cy: 1, skew: 0}\n", "skew"),
    ("effects:\n  camera_moved: {frame: '000001', rotation: [0, 0, 0]}\n", "rotation"),
    ("effects: {}\nextra: 1\n", "extra"),
    ("effects:\n  joint_offset: {panda_joint4: 2.0}\n", "(115 deg)"),
    ("effects:\n  lens_distortion: {k1: -10}\n", "lens_distortion k1 = -10 is beyond"),
    ("effects:\n  time_offset: {seconds: 80}\n", "time_offset seconds = 80 is beyond"),
])
def test_model_extension_refuses_wrong_format_and_unknown_keys(labels, tmp_path, capsys, text,
                                                              named):
    path = tmp_path / "ext.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=named) as exc:
        read_extension(path)
    assert exc.value.path == path and exc.value.fix
    line = refused(["calibrate", "--data", labels, "--use-labels", "--out", tmp_path / "r.json",
                    "--model-extension", path], capsys)
    assert str(path) in line and named in line
    assert not (tmp_path / "r.json").exists()


def test_an_extensions_camera_for_other_images_is_refused(labels, tmp_path, capsys):
    """Absolute intrinsics of a camera of another size: refused naming the extension."""
    path = tmp_path / "ext.yaml"
    path.write_text("effects:\n  intrinsics_error: {fx: 600, fy: 600, cx: 5000, cy: 3000}\n")
    line = refused(["calibrate", "--data", labels, "--use-labels", "--out", tmp_path / "r.json",
                    "--model-extension", path], capsys)
    assert str(path) in line and "cx = 5000 px lies outside" in line
    assert not (tmp_path / "r.json").exists()


def test_written_extensions_still_load(tmp_path):
    ext = extension_from_effects({
        "lens_distortion": {"k1": 0.1}, "time_offset": {"seconds": 0.02},
        "camera_moved": {"frame": "000003", "rotation_rad": [0, 0.01, 0]}}, "panda")
    path = tmp_path / "ext.yaml"
    path.write_text(extension_yaml(ext))
    assert read_extension(path) == ext
    path.write_text("effects:\n  joint_offset: {panda_joint2: 0.01}\n")  # hand-written, short
    assert read_extension(path).joint_offset_rad == {"panda_joint2": 0.01}


# ---------------------------------------------------------------- 11, 12. data problems


def _edit_frames(data: Path, edit) -> None:
    for path in sorted(data.glob("0*.json")):
        doc = json.loads(path.read_text())
        edit(doc)
        path.write_text(json.dumps(doc))


def test_data_problems_name_the_data_and_the_fix(labels, tmp_path, capsys):
    unknown_kp = copy_of(labels, tmp_path / "unknown_kp")
    _edit_frames(unknown_kp, lambda d: d["objects"][0]["keypoints"][1].update(name="panda_bogus"))
    line = refused(["calibrate", "--data", unknown_kp, "--use-labels", "--out",
                    tmp_path / "r.json"], capsys)
    assert str(unknown_kp) in line and "panda_bogus" in line and "Fix:" in line

    bogus_class = copy_of(labels, tmp_path / "bogus_class")
    _edit_frames(bogus_class, lambda d: d["objects"][0].update({"class": "bogusbot"}))
    line = refused(["calibrate", "--data", bogus_class, "--use-labels", "--out",
                    tmp_path / "r.json"], capsys)
    assert str(bogus_class) in line and "bogusbot" in line and "Fix:" in line

    three = copy_of(labels, tmp_path / "three")
    _edit_frames(three, lambda d: d["objects"][0].update(keypoints=d["objects"][0]["keypoints"]
                                                         [:3]))
    line = refused(["calibrate", "--data", three, "--use-labels", "--frames", "each", "--out",
                    tmp_path / "r.json"], capsys)
    assert str(three) in line and "solved alone" in line and "--frames all" in line
    assert not (tmp_path / "r.json").exists()


def test_calibration_error_carries_data_and_fix():
    exc = CalibrationError("no frame could be solved alone", "data", "use --frames all")
    assert str(exc) == "data: no frame could be solved alone. Fix: use --frames all"
    assert str(CalibrationError("plain")) == "plain"


# ---------------------------------------------------------------- 13. the right culprit


def test_the_right_culprit_is_named(labels, imaged, afile, tmp_path, capsys):
    line = refused(["calibrate", "--data", labels, "--use-labels", "--intrinsics",
                    "nan,600,320,240", "--out", tmp_path / "r.json"], capsys)
    assert "--intrinsics" in line and "_camera_settings.json" not in line
    line = refused(["calibrate", "--data", imaged, "--model", BUNDLED_MODEL, "--robot",
                    "bogusbot", "--out", tmp_path / "r.json"], capsys)
    assert "--robot" in line and BUNDLED_MODEL.name not in line
    line = refused(["overlay", imaged, "--robot", "bogusbot", "--out", tmp_path / "o"], capsys)
    assert "--robot" in line
    line = refused(["sample", "--out", afile / "s", "--num", "3"], capsys)
    assert "is a file" in line and "File exists" not in line


# ---------------------------------------------------------------- 14. one line for a bad PNG


def _corrupt_idat(path: Path) -> None:
    """Flip bytes in the middle of the first IDAT chunk's data (its CRC no longer matches)."""
    data = bytearray(path.read_bytes())
    pos = 8
    while True:
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if kind == b"IDAT":
            break
        pos += 12 + length
    middle = pos + 8 + length // 2
    data[middle:middle + 16] = bytes(b ^ 0xFF for b in data[middle:middle + 16])
    assert zlib.crc32(data[pos + 4:pos + 8 + length]) != \
        struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])[0]
    path.write_bytes(bytes(data))


def test_a_png_damaged_in_the_middle_gives_one_line(imaged, tmp_path, capfd):
    data = copy_of(imaged, tmp_path / "data")
    _corrupt_idat(data / "000001.rgb.png")
    code = main(["overlay", str(data), "--out", str(tmp_path / "o")])
    _, err = capfd.readouterr()  # the file descriptor: libpng writes there, not to sys.stderr
    line = one_error_line(code, err)
    assert "000001.rgb.png" in line and "corrupt" in line
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------- recipes


@dataclass(frozen=True)
class _Recipe:
    size: int = 1
    rate: float = 0.5


def test_an_exponent_without_a_decimal_point_is_a_number(tmp_path):
    """PyYAML reads 1e-3 as a string (YAML 1.1); a float field takes it as the number."""
    path = tmp_path / "r.yaml"
    path.write_text("rate: 1e-3\n")
    assert load_recipe(_Recipe, path).rate == 1e-3
    assert load_recipe(_Recipe, None, ["rate=-2E4"]).rate == -2e4
    for text in ("fast", "nan", "1e"):
        with pytest.raises(InputError, match="expected float"):
            load_recipe(_Recipe, None, [f"rate={text}"])


def test_invalid_recipe_yaml_says_what_to_do(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("model: [1, 2\n")
    with pytest.raises(InputError, match="not valid YAML") as exc:
        load_recipe(_Recipe, path)
    assert exc.value.path == path and exc.value.fix
    path.write_bytes(b"size: \xff\xfe\n")
    with pytest.raises(InputError, match="UTF-8"):
        load_recipe(_Recipe, path)
