"""`dream batch calibrate`: the single runs' results on both engines, one row per fault, a
re-run that does only what is left, and a kill -9 that loses no finished result and leaves no
half-written one."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from batch.calibrate import CalibrateTask, calibrate_command, calibrate_one
from batch.cli import _calibrate_options as _options
from batch.lock import LOCK_NAME
from batch.summary import COLUMNS
from dream.cli import main
from dream.cli.calibrate import CalibrateRequest, run_calibrate
from dream.io import is_temporary
from tests.benchmark_scripts import load_benchmark

BENCH = load_benchmark("batch_calibrate")
BROKEN = {"missing_image": 3, "degrees": 4, "truncated_json": 5}
FAULTS = {"rec003": 'image "000002.png" not found', "rec004": "degrees",
          "rec005": "rec005/000002.json"}
OPTIONS = ["--use-labels", "--refine", "none"]
IDENTICAL = 1e-9
KILL_DEADLINE_S = 120
POLL_S = 0.05
ORPHAN_WAIT_S = 20.0
HEAD_PORT = 6391          # `ray start --head` of the test
STOP_DEADLINE_S = 30      # a stopped batch ends well within this
EXIT_INTERRUPTED = 130


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> list[Path]:
    """Six 4-frame recordings of three arms; the last three broken (`BROKEN`)."""
    root = tmp_path_factory.mktemp("recordings")
    return BENCH.make_recordings(root, 6, 4, 2.0, BROKEN)


@pytest.fixture(scope="module")
def single(recordings, tmp_path_factory) -> dict[str, np.ndarray]:
    """T_cam_base of one `dream calibrate` per good recording."""
    out = tmp_path_factory.mktemp("single")
    return {r.name: np.asarray(run_calibrate(CalibrateRequest(
        data=str(r), out=str(out / f"{r.name}.json"), use_labels=True, refine="none"),
        out=open(os.devnull, "w"))["T_cam_base"]) for r in recordings if r.name not in FAULTS}


def batch(recordings: list[Path], out: Path, *extra: str) -> int:
    return main(["batch", "calibrate", "--data", str(recordings[0].parent / "rec*"), "--out",
                 str(out), "--workers", "2", *OPTIONS, *extra])


def rows(out: Path) -> dict[str, dict]:
    return {r["name"]: r for r in json.loads((out / "summary.json").read_text())["rows"]}


def check_results(out: Path, single: dict[str, np.ndarray]) -> None:
    """Every good recording as its single run, every broken one a row naming its fault, every
    folder whole."""
    got = rows(out)
    assert set(got) == set(single) | set(FAULTS)
    for name, T in single.items():
        assert got[name]["status"] == "ok" and got[name]["verdict"]
        assert np.max(np.abs(np.asarray(got[name]["T_cam_base"]) - T)) <= IDENTICAL
        doc = json.loads((out / name / "RESULT.json").read_text())
        assert doc["settings"]["out"] == str(out / name / "RESULT.json")
        assert np.allclose(np.asarray(doc["T_base_cam"])[:3, 3],
                           [got[name][f"camera_{a}_m"] for a in "xyz"])
    for name, fault in FAULTS.items():
        assert got[name]["status"] == "failed" and fault in got[name]["error"], got[name]
        assert "\n" not in got[name]["error"]
        assert fault in (out / name / "calibrate.log").read_text()
    assert not [p for p in out.iterdir() if is_temporary(p)]


def test_batch_gives_the_single_runs_and_one_row_per_fault_and_resumes(recordings, single,
                                                                        tmp_path, capsys):
    out = tmp_path / "batch"
    assert batch(recordings, out) == 1          # some failed
    printed = capsys.readouterr()
    assert "3 calibrated, 3 failed" in printed.out
    assert "6 recordings, 0 done already (same inputs), 6 to run" in printed.err
    check_results(out, single)
    with (out / "summary.csv").open() as f:
        table = list(csv.DictReader(f))
    assert tuple(table[0]) == COLUMNS and len(table) == 6
    assert [r["name"] for r in table] == [f"rec{i:03d}" for i in range(6)]

    assert batch(recordings, out) == 1          # the failed ones again, the others kept
    assert "3 done already (same inputs), 3 to run" in capsys.readouterr().err
    frame = recordings[0] / "000000.json"
    frame.write_text(frame.read_text() + " ")   # a changed input is redone
    try:
        assert batch(recordings, out) == 1
        assert "2 done already (same inputs), 4 to run" in capsys.readouterr().err
    finally:
        frame.write_text(frame.read_text()[:-1])
    check_results(out, single)


def test_overlays_on_request_land_in_each_folder(recordings, tmp_path):
    out = tmp_path / "batch"
    assert main(["batch", "calibrate", "--data", str(recordings[1]), "--out", str(out),
                 "--workers", "1", "--overlays", *OPTIONS]) == 0
    assert list((out / "rec001" / "overlays").glob("*.png"))
    assert rows(out)["rec001"]["status"] == "ok"


def test_require_fails_the_batch_where_a_verdict_falls_below_it(recordings, tmp_path,
                                                               capsys):
    """The good recordings' verdicts against `--require`: exit 1 naming each below it, as
    where some failed; 0 where none is below."""
    good = [r for r in recordings if r.name not in FAULTS]
    out = tmp_path / "batch"
    argv = ["batch", "calibrate", "--data", str(good[0].parent / "rec00[012]"), "--out",
            str(out), "--workers", "2", *OPTIONS]
    assert main(argv) == 0
    verdicts = {name: row["verdict"] for name, row in rows(out).items()}
    assert {"check", "unreliable"} <= set(verdicts.values()), verdicts   # 4 frames each
    capsys.readouterr()
    for required in ("good", "check"):
        allowed = ("good",) if required == "good" else ("good", "check")
        below = sorted(name for name, v in verdicts.items() if v not in allowed)
        assert main([*argv, "--require", required]) == (1 if below else 0)
        printed = capsys.readouterr().out
        assert (f"calibrated below --require {required}" in printed) == bool(below)
        for name in below:
            assert f"  {name}: {verdicts[name]}" in printed


def test_a_recording_added_with_a_clashing_name_leaves_the_finished_one(recordings, tmp_path,
                                                                        capsys):
    """A finished recording keeps its folder when a later run adds one of the same name from
    elsewhere; before, both were renamed by their parents and the finished one redone."""
    import shutil

    other = tmp_path / "other" / recordings[1].name
    shutil.copytree(recordings[1], other)
    out, listed = tmp_path / "batch", tmp_path / "list.txt"
    listed.write_text(f"{recordings[1]}\n")
    assert main(["batch", "calibrate", "--data", str(listed), "--out", str(out), "--workers",
                 "1", *OPTIONS]) == 0
    listed.write_text(f"{recordings[1]}\n{other}\n")
    capsys.readouterr()
    assert main(["batch", "calibrate", "--data", str(listed), "--out", str(out), "--workers",
                 "1", *OPTIONS]) == 0
    assert "2 recordings, 1 done already (same inputs), 1 to run" in capsys.readouterr().err
    got = rows(out)
    assert got["rec001"]["recording"] == str(recordings[1])
    assert got["other-rec001"]["recording"] == str(other)
    assert {p.name for p in out.iterdir() if p.is_dir()} == {"rec001", "other-rec001"}
    listed.write_text(f"{tmp_path / 'third' / recordings[1].name}\n")   # alone: not over rec001
    shutil.copytree(recordings[1], tmp_path / "third" / recordings[1].name)
    before = (out / "rec001" / "batch.json").read_text()
    assert main(["batch", "calibrate", "--data", str(listed), "--out", str(out), "--workers",
                 "1", *OPTIONS]) == 0
    assert (out / "rec001" / "batch.json").read_text() == before
    assert rows(out)["rec001-2"]["recording"] == str(tmp_path / "third" / recordings[1].name)


def test_an_unquoted_pattern_is_named(recordings, tmp_path, capsys):
    """The shell's expansion of `--data runs/*` gave argparse's bare "unrecognized arguments"."""
    with pytest.raises(SystemExit) as stop:
        main(["batch", "calibrate", "--data", *map(str, recordings[:3]), "--out",
              str(tmp_path / "out"), *OPTIONS])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert f"unrecognized arguments: {recordings[1]} {recordings[2]}" in err
    assert "quote it, --data 'runs/*'" in err
    with pytest.raises(SystemExit):
        main(["info", "--no-such-option"])
    err = capsys.readouterr().err
    assert "quote it" not in err and "does not take: --no-such-option" in err
    assert not (tmp_path / "out").exists()


def test_a_crash_is_one_recording_failed(recordings, tmp_path, monkeypatch):
    import batch.calibrate

    def crashing(task, result, overlays):
        return [sys.executable, "-c", "raise ZeroDivisionError('a bug')"]

    monkeypatch.setattr(batch.calibrate, "calibrate_command", crashing)
    row = calibrate_one(CalibrateTask(str(recordings[0]), "rec000", str(tmp_path),
                                      {"use_labels": True}, "hash"))
    assert row["status"] == "failed"
    assert row["error"] == "internal error (exit code 1): ZeroDivisionError: a bug"
    assert "Traceback" in (tmp_path / "rec000" / "calibrate.log").read_text()
    record = json.loads((tmp_path / "rec000" / "batch.json").read_text())
    assert record["input_hash"] == "hash" and record["row"] == row


def test_a_calibration_killed_by_a_signal_says_which(tmp_path, monkeypatch):
    """The out-of-memory killer's SIGKILL: the row names the signal and what to do."""
    import batch.calibrate

    def killed(task, result, overlays):
        return [sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGKILL)"]

    monkeypatch.setattr(batch.calibrate, "calibrate_command", killed)
    row = calibrate_one(CalibrateTask(str(tmp_path), "rec000", str(tmp_path),
                                      {"use_labels": True}, "hash"))
    assert row["status"] == "failed"
    assert row["error"].startswith("dream calibrate was killed by signal 9 (SIGKILL: out of "
                                   "memory?). Fix: ")
    assert "--workers" in row["error"] and "no message" not in row["error"]


def test_the_options_travel_as_the_calibrate_command_line(recordings, tmp_path):
    from dream.cli.app import build_parser
    from dream.cli.options import request_from

    argv = ["--use-labels", "--frames", "each", "--loss", "cauchy", "--loss-scale-px", "2.5",
            "--seed", "3", "--threads", "1", "--keypoints", "a,b,c", "--exclude-links",
            "panda_hand", "--camera-frame", "cam_optical"]
    args = build_parser().parse_args(["batch", "calibrate", "--data", "x", "--out", "y", *argv])
    options = _options(args)
    command = calibrate_command(CalibrateTask("rec", "rec", str(tmp_path), options),
                                tmp_path / "R.json", tmp_path / "ov")
    assert command[1:6] == ["calibrate", "--data", "rec", "--out", str(tmp_path / "R.json")]
    again = build_parser().parse_args(command[1:])
    assert request_from(CalibrateRequest, again) == CalibrateRequest(
        **options, data="rec", out=str(tmp_path / "R.json"))


@pytest.mark.parametrize("argv, message", [
    (["--data", "{tmp}/nothing*"], "matches no recording"),
    (["--engine", "local", "--address", "ray://head:10001"], "--address joins a Ray"),
    (["--workers", "0"], "--workers must be 1 or more"),
    (["--motion-masks"], "--polish was not given"),
    (["--camera-info", "{tmp}/none.yaml"], "--camera-info {tmp}/none.yaml: no such file"),
])
def test_bad_options_fail_before_anything_is_written(recordings, tmp_path, capsys, argv,
                                                     message):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    data = [] if "--data" in argv else ["--data", str(recordings[0])]
    out = tmp_path / "out"
    assert main(["batch", "calibrate", *data, "--out", str(out), "--use-labels", *argv]) == 2
    assert message.replace("{tmp}", str(tmp_path)) in capsys.readouterr().err
    assert not out.exists()


def test_list_lines_give_their_recordings_options_of_their_own(recordings, tmp_path, capsys):
    """Two stretches of one recording and a plain one: each part as its own single run, the
    lines' options in their hashes (a changed line redoes only its recording)."""
    listing = tmp_path / "list.txt"
    first, second = recordings[0], recordings[1]
    lines = [f"{first} --frame-range 0:2", f"{first} --frame-range 2:4 --seed 1", str(second)]
    listing.write_text("\n".join(lines) + "\n")
    out = tmp_path / "batch"
    argv = ["batch", "calibrate", "--data", str(listing), "--out", str(out), "--workers", "2",
            *OPTIONS]
    assert main(argv) == 0
    got = rows(out)
    assert list(got) == ["rec000-part1", "rec000-part2", "rec001"]
    assert [r["options"] for r in got.values()] == [
        "--frame-range 0:2", "--frame-range 2:4 --seed 1", ""]
    for name, frames in (("rec000-part1", "0:2"), ("rec000-part2", "2:4")):
        alone = run_calibrate(CalibrateRequest(
            data=str(first), out=str(tmp_path / f"{name}.json"), use_labels=True, refine="none",
            frame_range=frames, seed=1 if frames == "2:4" else 0), out=open(os.devnull, "w"))
        assert got[name]["frames"] == 2
        assert np.max(np.abs(np.asarray(got[name]["T_cam_base"])
                             - np.asarray(alone["T_cam_base"]))) <= IDENTICAL
        assert json.loads((out / name / "RESULT.json").read_text())["settings"][
            "frame_range"] == frames
    assert got["rec001"]["frames"] == 4
    capsys.readouterr()
    listing.write_text("\n".join([lines[0], f"{first} --frame-range 1:4", lines[2]]) + "\n")
    assert main(argv) == 0
    assert "2 done already (same inputs), 1 to run" in capsys.readouterr().err
    assert rows(out)["rec000-part2"]["frames"] == 3


@pytest.mark.parametrize("line, message", [
    ("{rec} --frame-rang 0:2", "unrecognized arguments: --frame-rang"),
    ("{rec} --refine bogus", "argument --refine: invalid choice"),
    ("{rec} --data elsewhere", "--data is the batch's to set"),
    ("{rec} --out R.json", "unrecognized arguments: --out"),
    ("{rec} --require good", "the batch sets --data, --out, --overlays and --require"),
    ("{rec} --frame-range '0:2", "cannot split it"),
    ("{rec} --mask-head", "--polish was not given"),
    ("{rec} --model /nonexistent/model.onnx", "--model /nonexistent/model.onnx: no such file"),
])
def test_a_bad_list_line_is_named_before_anything_is_written(recordings, tmp_path, capsys,
                                                             line, message):
    listing = tmp_path / "list.txt"
    listing.write_text(f"{recordings[1]}\n" + line.replace("{rec}", str(recordings[0])) + "\n")
    out = tmp_path / "out"
    assert main(["batch", "calibrate", "--data", str(listing), "--out", str(out),
                 *OPTIONS]) == 2
    err = capsys.readouterr().err
    assert message in err and "line 2 of" in err
    assert not out.exists()


def _command(recordings: list[Path], out: Path, engine: str) -> list[str]:
    return [str(Path(sys.executable).parent / "dream"), "batch", "calibrate", "--data",
            str(recordings[0].parent / "rec*"), "--out", str(out), "--engine", engine,
            "--workers", "1", *OPTIONS]


def _wait_for_orphans(out: Path) -> None:
    """A worker whose batch was killed may still finish the recording it runs (the local
    pool's) or die with it (Ray's): wait until no temporary folder is left or they stay."""
    deadline = time.monotonic() + ORPHAN_WAIT_S
    while time.monotonic() < deadline and [p for p in out.iterdir() if is_temporary(p)]:
        time.sleep(POLL_S)


def _left_behind() -> list[int]:
    """Processes started under this test (its PYTEST_CURRENT_TEST in their environment), other
    than this one, that still run: on Linux, a killed batch's workers."""
    mine = f"PYTEST_CURRENT_TEST={os.environ['PYTEST_CURRENT_TEST']}".encode()
    pids = []
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            if int(proc.name) != os.getpid() and mine in (proc / "environ").read_bytes().split(
                    b"\0") and "\nState:\tZ" not in (proc / "status").read_text():
                pids.append(int(proc.name))
        except OSError:                         # gone meanwhile, or not ours to read
            continue
    return pids


def _finished_folders(out: Path) -> list[Path]:
    return [p for p in out.glob("rec*") if p.is_dir()] if out.is_dir() else []


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["local", "ray"])
def test_a_killed_batch_loses_nothing_finished_and_resumes(recordings, single, tmp_path,
                                                           engine):
    if engine == "ray":
        pytest.importorskip("ray")
    out = tmp_path / "batch"
    before = set(_left_behind())                # left by an earlier run of this test
    proc = subprocess.Popen(_command(recordings, out, engine), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + KILL_DEADLINE_S
    while not _finished_folders(out) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(POLL_S)
    os.kill(proc.pid, signal.SIGKILL)           # the driver only, as `kill -9 PID` does
    proc.wait()
    _wait_for_orphans(out)
    if engine == "local" and sys.platform.startswith("linux"):  # none waits for work for ever
        deadline = time.monotonic() + ORPHAN_WAIT_S
        while set(_left_behind()) - before and time.monotonic() < deadline:
            time.sleep(POLL_S)
        assert not set(_left_behind()) - before
    finished = _finished_folders(out)
    assert 1 <= len(finished) < 6, finished
    for folder in finished:                     # each whole: its record written last
        assert (folder / "batch.json").is_file() and (folder / "calibrate.log").is_file()
    rerun = subprocess.run(_command(recordings, out, engine), capture_output=True, text=True)
    assert rerun.returncode == 1, rerun.stderr
    done_already = sum(json.loads((f / "batch.json").read_text())["row"]["status"] == "ok"
                       for f in finished)
    assert (f"6 recordings, {done_already} done already (same inputs), {6 - done_already} to "
            "run") in rerun.stderr
    check_results(out, single)


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["local", "ray"])
def test_sigterm_stops_the_batch_as_ctrl_c_does(recordings, tmp_path, engine):
    """`kill PID` (SIGTERM to the batch alone; `timeout` and Slurm send it too): exit 130 with
    "interrupted", the recording running interrupted, the summary of what is done, and no
    temporary folder, lock or process left."""
    out = tmp_path / "batch"
    before = set(_left_behind())
    if engine == "ray":
        pytest.importorskip("ray")
    proc = subprocess.Popen(_command(recordings, out, engine), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + KILL_DEADLINE_S
    while not _finished_folders(out) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(POLL_S)
    os.kill(proc.pid, signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=STOP_DEADLINE_S)
    finally:
        proc.kill()
    assert proc.returncode == EXIT_INTERRUPTED, err
    assert "dream batch: interrupted" in err
    assert not set(_left_behind()) - before     # its worker and their dream calibrate
    finished = {folder.name for folder in _finished_folders(out)}
    assert 1 <= len(finished) < 6, finished
    assert set(rows(out)) <= finished
    assert not [p for p in out.iterdir() if is_temporary(p) or p.name == LOCK_NAME]


@pytest.mark.slow
def test_joins_a_running_ray_cluster_by_its_address(recordings, single, tmp_path):
    """`ray start --head` as an operator runs it, then `--address HOST:PORT` (and `--engine
    ray` without it still starts a Ray of its own beside that cluster)."""
    pytest.importorskip("ray")
    ray_cli = str(Path(sys.executable).parent / "ray")
    env = {**os.environ, "RAY_AUTH_MODE": "token"}
    subprocess.run([ray_cli, "start", "--head", f"--port={HEAD_PORT}", "--num-cpus=2",
                    "--include-dashboard=false", "--disable-usage-stats"], check=True,
                   capture_output=True, env=env)
    try:
        for address in (["--address", f"127.0.0.1:{HEAD_PORT}"], []):
            out = tmp_path / f"joined{len(address)}"
            command = [*_command(recordings, out, "ray")[:-len(OPTIONS)], *OPTIONS, *address]
            run = subprocess.run(command, capture_output=True, text=True, env=env)
            assert run.returncode == 1, run.stderr
            where = f"Ray cluster 127.0.0.1:{HEAD_PORT}" if address else "local Ray"
            assert f"6 to run on the {where}" in run.stderr
            check_results(out, single)
    finally:
        subprocess.run([ray_cli, "stop"], capture_output=True, env=env)
