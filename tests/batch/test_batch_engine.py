"""`batch.engine` and `batch.recordings`: both engines give every item's result once, an
exception stops the run, a worker that dies is retried then reported; recordings are listed,
named and hashed as the batch resumes them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from batch.calibrate import _recording_options, plan_batch
from batch.engine import (
    EngineSettings,
    LocalEngine,
    RayEngine,
    WorkerLost,
    make_engine,
)
from batch.options import line_options
from batch.recordings import (
    folder_names,
    input_hash,
    list_recordings,
    options_digest,
    recording_digest,
    recording_stat,
)
from dream.errors import InputError

DIE_ON = 3          # the item whose worker process dies (os._exit)
FAIL_ON = 2         # the item whose function raises
ITEM_S = 0.3


def square_with_offset(x: int) -> tuple[int, int, str]:
    """An item's value, the setup's offset and the worker's thread limits (OpenMP, ours; long
    enough for both workers to take items)."""
    time.sleep(ITEM_S)
    return x * x + int(os.environ.get("BATCH_TEST_OFFSET", "0")), os.getpid(), \
        os.environ.get("OMP_NUM_THREADS", "") + "," + os.environ.get("DREAM_THREADS", "")


def set_offset(offset: int) -> None:
    os.environ["BATCH_TEST_OFFSET"] = str(offset)


def die_on_one(x: int) -> int:
    if x == DIE_ON:
        os._exit(3)
    return x


def fail_setup() -> None:
    raise InputError("the scene cannot be loaded", fix="give a robot that exists")


def fail_on_one(x: int) -> int:
    if x == FAIL_ON:
        raise InputError(f"item {x} is bad", fix="leave it out")
    return x


@pytest.fixture(scope="module")
def ray_engine():
    ray = pytest.importorskip("ray")
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # Ray's workers lack tests/
    engine = RayEngine(workers=2)
    yield engine
    engine.close()


def engines(ray_engine):
    return [LocalEngine(workers=2), ray_engine]


@pytest.mark.slow
def test_both_engines_run_every_item_once_after_the_setup_on_one_thread(ray_engine):
    items = list(range(7))
    for engine in engines(ray_engine):
        got = dict(engine.run(square_with_offset, items, setup=set_offset, setup_args=(10,)))
        assert sorted(got) == items, engine.describe()
        assert [got[i][0] for i in items] == [i * i + 10 for i in items]
        assert len({pid for _, pid, _ in got.values()}) == 2       # two worker processes
        assert {threads for _, _, threads in got.values()} == {"1,1"}
        assert os.getpid() not in {pid for _, pid, _ in got.values()}


@pytest.mark.slow
def test_an_exception_stops_the_run_and_a_dead_worker_is_retried_then_reported(ray_engine):
    for engine in engines(ray_engine):
        with pytest.raises(InputError, match="item 2 is bad"):
            dict(engine.run(fail_on_one, list(range(5))))
        with pytest.raises(InputError, match="the scene cannot be loaded"):
            dict(engine.run(square_with_offset, list(range(3)), setup=fail_setup))
        got = dict(engine.run(die_on_one, list(range(6))))
        assert sorted(got) == list(range(6)), engine.describe()
        assert isinstance(got[DIE_ON], WorkerLost)
        assert "worker process died running it" in got[DIE_ON].message
        assert all(got[i] == i for i in got if i != DIE_ON)


# a batch whose items take long; Ctrl-C (SIGINT to it alone) must not wait for them
STOPPED_DRIVER = """
import sys, time
from pathlib import Path
from batch.engine import LocalEngine

def long_item(path):
    Path(path).write_text(str(__import__("os").getpid()))
    try:
        time.sleep(float(sys.argv[2]))
    finally:
        Path(path + ".stopped").write_text("")

if __name__ == "__main__":
    try:
        for _ in LocalEngine(2).run(long_item, [f"{sys.argv[1]}/{i}" for i in range(4)]):
            pass
    except KeyboardInterrupt:
        print("interrupted", flush=True)
"""
LONG_ITEM_S = 60.0
STOP_DEADLINE_S = 20.0
START_DEADLINE_S = 60.0
POLL_S = 0.05


@pytest.mark.slow
def test_a_stopped_local_run_stops_its_workers_items(tmp_path):
    """The batch process interrupted alone (`kill -INT PID`; SIGTERM becomes the same): the
    items running are interrupted, their clean-up runs, the workers exit, no other item
    starts, and the batch does not wait for the items to end."""
    script, items = tmp_path / "driver.py", tmp_path / "items"
    script.write_text(STOPPED_DRIVER)
    items.mkdir()
    repo = str(Path(__file__).resolve().parents[2])
    proc = subprocess.Popen([sys.executable, str(script), str(items), str(LONG_ITEM_S)],
                            cwd=repo, env={**os.environ, "PYTHONPATH": repo},
                            stdout=subprocess.PIPE, text=True)
    deadline = time.monotonic() + START_DEADLINE_S
    while len(list(items.iterdir())) < 2 and time.monotonic() < deadline:
        time.sleep(POLL_S)
    os.kill(proc.pid, signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=STOP_DEADLINE_S)
    finally:
        proc.kill()
    assert "interrupted" in out
    started = sorted(p for p in items.iterdir() if p.suffix != ".stopped")
    assert [p.name for p in started] == ["0", "1"]
    assert all(p.with_suffix(".stopped").exists() for p in started)
    for pid in (int(p.read_text()) for p in started):
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


def pid_then_sleep(item: tuple[str, float]) -> None:
    path, seconds = item
    Path(path).write_text(str(os.getpid()))
    time.sleep(seconds)


@pytest.mark.slow
def test_a_run_interrupted_while_handing_out_an_item_stops_and_waits_for_that_item(
        tmp_path, monkeypatch):
    """Ctrl-C or SIGTERM can land in `submit`, after the item went to a worker and before the
    run holds its future: that item's worker is stopped and waited for too, not left running
    after the batch ends."""
    original = LocalEngine._pool

    def pool_interrupted_at_second_submit(self, setup, setup_args):
        pool, submitted = original(self, setup, setup_args), []
        submit = pool.submit

        def submit_then_interrupt(*args, **kwargs):
            submitted.append(submit(*args, **kwargs))
            if len(submitted) == 2:
                raise KeyboardInterrupt
            return submitted[-1]

        pool.submit = submit_then_interrupt
        return pool

    monkeypatch.setattr(LocalEngine, "_pool", pool_interrupted_at_second_submit)
    items = [(str(tmp_path / "quick"), 0.0), (str(tmp_path / "long"), LONG_ITEM_S)]
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        for _ in LocalEngine(1).run(pid_then_sleep, items):
            pass
    assert time.monotonic() - started < STOP_DEADLINE_S
    with pytest.raises(ProcessLookupError):         # stopped and reaped, not left running
        os.kill(int((tmp_path / "quick").read_text()), 0)


def test_the_engine_help_says_ray_opens_ports_for_a_trusted_network_only(capsys):
    from dream.cli import main

    with pytest.raises(SystemExit):
        main(["batch", "calibrate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "trusted network" in text and "docs/scaling.md, 'Ports and trust'" in text


def test_engine_settings_are_checked():
    with pytest.raises(InputError, match="unknown --engine"):
        EngineSettings("spark")
    with pytest.raises(InputError, match="--workers must be 1 or more"):
        EngineSettings(workers=0)
    with pytest.raises(InputError, match="--address joins a Ray cluster"):
        EngineSettings(address="ray://head:10001")
    assert isinstance(make_engine(EngineSettings("local", 3)), LocalEngine)
    assert make_engine(EngineSettings("local", 3)).workers == 3
    ray = make_engine(EngineSettings("ray", 2, "ray://head:10001"))
    assert isinstance(ray, RayEngine) and "ray://head:10001" in ray.describe()


def test_the_core_and_the_local_engine_do_not_import_ray():
    """Ray is an extra: `dream calibrate` and `dream batch --engine local` run without it."""
    code = ("import sys; from dream.cli.app import build_parser; build_parser(); "
            "import batch.calibrate, batch.engine, batch.synth, dream.cli.calibrate; "
            "assert 'ray' not in sys.modules, 'ray imported'")
    subprocess.run([sys.executable, "-c", code], check=True)
    pyproject = (Path(__file__).resolve().parents[2] / "pyproject.toml").read_text()
    dependencies = pyproject.split("[project.optional-dependencies]")[0]
    assert "ray" not in dependencies.split("dependencies")[1].lower()
    assert 'cluster = ["ray[client]' in pyproject


def dream_recording(folder: Path) -> Path:
    """A folder of the DREAM layout as `dream.io.detect` sees it (its frames, its settings)."""
    folder.mkdir(parents=True)
    for name in ("_camera_settings.json", "000000.json", "000000.rgb.png"):
        (folder / name).write_text("{}")
    return folder


def test_recordings_from_a_glob_or_a_list_file(tmp_path):
    for name in ("a/ep1", "b/ep1", "b/ep2"):
        dream_recording(tmp_path / name)
    (tmp_path / "b" / "ep3.npz").write_bytes(b"x")
    found = [e.path for e in list_recordings(str(tmp_path / "*" / "ep*"))]
    assert [p.relative_to(tmp_path).as_posix() for p in found] == \
        ["a/ep1", "b/ep1", "b/ep2", "b/ep3.npz"]
    assert folder_names(found) == ["a-ep1", "b-ep1", "ep2", "ep3"]
    listing = tmp_path / "list.txt"
    listing.write_text("# the lab's episodes\nb/ep2\n\na/ep1\nb/ep2\nmissing\n"
                       "b/ep2 --frame-range 0:50 --camera-guess 'my guess.json'\n"
                       "a/ep1  --frame-range 0:50\n")
    listed = list_recordings(str(listing))
    # each path and options once; a missing one fails alone
    assert [e.path.name for e in listed] == ["ep2", "ep1", "missing", "ep2", "ep1"]
    assert [e.argv for e in listed][3:] == [
        ("--frame-range", "0:50", "--camera-guess", "my guess.json"), ("--frame-range", "0:50")]
    assert [e.line for e in listed] == [2, 4, 6, 7, 8] and listed[3].where.startswith("line 7 of")
    assert folder_names([e.path for e in listed]) == \
        ["ep2-part1", "ep1-part1", "missing", "ep2-part2", "ep1-part2"]
    with pytest.raises(InputError, match="matches no recording"):
        list_recordings(str(tmp_path / "nothing*"))
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(InputError, match="list of recordings is empty"):
        list_recordings(str(tmp_path / "empty.txt"))


def test_a_glob_keeps_the_recordings_not_their_files_nor_stray_matches(tmp_path, caplog):
    """`nest/**` matches every file and folder: only the recordings are kept (a folder of a
    layout, an .npz), not what lies inside them, nor a folder that holds them (`lab` with
    its one .npz, `teleop/one` of one episode, matched itself); the stray matches are named
    in a warning."""
    nest = tmp_path / "nest"
    dream_recording(nest / "lab" / "rec1")
    dream_recording(nest / "lab" / "deeper" / "rec2")
    (nest / "lab" / "ep3.npz").write_bytes(b"x")
    for episode in ("teleop/one/ep", "teleop/two/ep_a", "teleop/two/ep_b"):
        (nest / episode).mkdir(parents=True)
        (nest / episode / "info.json").write_text("{}")
    (nest / "lab" / "NOTES.txt").write_text("calibrated on Monday")
    (nest / "empty").mkdir()
    with caplog.at_level("WARNING", logger="batch.recordings"):
        found = [e.path.relative_to(nest).as_posix() for e in list_recordings(f"{nest}/**")]
    assert found == ["lab/deeper/rec2", "lab/ep3.npz", "lab/rec1", "teleop/one/ep",
                     "teleop/two/ep_a", "teleop/two/ep_b"]
    assert "left out 2 match(es) that are not recordings" in caplog.text
    assert str(nest / "lab" / "NOTES.txt") in caplog.text and str(nest / "empty") in caplog.text
    assert [e.path.name for e in list_recordings(f"{nest}/lab/*")] == ["ep3.npz", "rec1"]
    assert [e.path.name for e in list_recordings(f"{nest}/teleop/*")] == ["one"]
    # a recording's layout file stands for its folder, as `dream calibrate --data` reads it
    assert [e.path.name for e in list_recordings(f"{nest}/teleop/*/*/info.json")] == [
        "ep", "ep_a", "ep_b"]
    assert [e.path.name for e in list_recordings(f"{nest}/lab/**/_camera_settings.json")
            ] == ["rec2", "rec1"]
    with pytest.raises(InputError, match=r"matches no recording \(1 match\(es\), none"):
        list_recordings(f"{nest}/lab/*.txt")


def test_a_list_line_takes_value_lists_that_start_with_a_minus_sign(tmp_path):
    """A camera behind the base: `--camera-guess -0.5,1.2,0.8` on a line, as on the command
    line (argparse alone takes the value for an option and stops at it)."""
    listing = tmp_path / "list.txt"
    listing.write_text("ep1 --camera-guess -0.5,1.2,0.8 --look-at -0.1,0,0.4 --seed -1\n")
    (entry,) = list_recordings(str(listing))
    assert line_options(entry) == {"camera_guess": "-0.5,1.2,0.8", "look_at": "-0.1,0,0.4",
                                   "seed": -1}
    assert entry.argv[:2] == ("--camera-guess", "-0.5,1.2,0.8")       # as written


def test_a_list_lines_files_come_from_its_folder_or_fail_naming_the_line(tmp_path,
                                                                          monkeypatch):
    """Files from the list's folder, never the working folder's; a missing one fails naming
    the line; a built-in robot's name stays a name beside a folder of that name; a line's
    --model replaces the batch's --use-labels."""
    lab, elsewhere = tmp_path / "lab", tmp_path / "elsewhere"
    (lab / "panda").mkdir(parents=True)
    elsewhere.mkdir()
    (lab / "guess.json").write_text("{}")
    (lab / "m.onnx").write_bytes(b"x")
    (elsewhere / "cwd.json").write_text("{}")
    monkeypatch.chdir(elsewhere)
    listing = lab / "list.txt"
    listing.write_text("ep1 --camera-guess guess.json --robot panda\n"
                       "ep1 --camera-guess cwd.json\n"
                       "ep1 --mark marks.csv --mark-link panda_hand\n"
                       "ep1 --model m.onnx --camera-guess 1,0,1 --look-at 0,0,0.4\n")
    first, cwd_only, no_marks, model = list_recordings(str(listing))
    assert line_options(first) == {"camera_guess": str(lab / "guess.json"), "robot": "panda"}
    for entry, flag in ((cwd_only, "--camera-guess cwd.json"), (no_marks, "--mark marks.csv")):
        with pytest.raises(InputError, match=f"line {entry.line} of .*: {flag}: no such file"):
            line_options(entry)
    own, _ = _recording_options(model, {"use_labels": True, "seed": 3}, overlays=False)
    assert own["model"] == str(lab / "m.onnx") and "use_labels" not in own and own["seed"] == 3


def test_a_missing_file_by_its_absolute_path_fails_before_any_work(tmp_path):
    """On a list line as by a relative name, and in the batch's own options."""
    dream_recording(tmp_path / "ep1")
    gone = tmp_path / "gone.onnx"
    listing = tmp_path / "list.txt"
    listing.write_text(f"ep1 --model {gone}\n")
    (entry,) = list_recordings(str(listing))
    with pytest.raises(InputError, match=f"line 1 of .*: --model {gone}: no such file"):
        line_options(entry)
    out = tmp_path / "out"
    for option in ("camera_info", "model_extension"):
        with pytest.raises(InputError, match=f"--{option.replace('_', '-')} {gone}: no such"):
            plan_batch(str(tmp_path / "ep*"), out, {"use_labels": True, option: str(gone)},
                       overlays=False)
    with pytest.raises(InputError, match=f"--model {gone}: no such file"):
        plan_batch(str(tmp_path / "ep*"), out, {"model": str(gone)}, overlays=False)
    assert not out.exists()


def content_hash(rec: Path, options: dict, files: list[Path]) -> str:
    return input_hash(options_digest(options, files), recording_digest(rec))


def test_content_hash_changes_with_the_files_and_the_options_only(tmp_path):
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "000000.json").write_text("{}")
    model = tmp_path / "model.onnx"
    model.write_bytes(b"weights")
    base = content_hash(rec, {"seed": 0}, [model])
    stat = recording_stat(rec)
    assert content_hash(rec, {"seed": 0}, [model]) == base
    assert recording_stat(rec) == stat
    assert content_hash(rec, {"seed": 1}, [model]) != base
    model.write_bytes(b"other weights")
    assert content_hash(rec, {"seed": 0}, [model]) != base
    model.write_bytes(b"weights")
    (rec / "000000.json").write_text("{ }")
    assert content_hash(rec, {"seed": 0}, [model]) != base
    assert recording_stat(rec) != stat                  # the size changed
    (rec / "000000.json").write_text("{}")
    os.utime(rec / "000000.json", ns=(1, 1))
    assert recording_stat(rec) != stat                  # the time changed, the content not
    assert content_hash(rec, {"seed": 0}, [model]) == base
    (rec / "000001.json").write_text("{}")
    assert content_hash(rec, {"seed": 0}, [model]) != base


def test_the_recordings_doctests():
    import doctest

    import batch.recordings

    assert doctest.testmod(batch.recordings).failed == 0
