"""One batch at a time per `--out` (`batch.lock`): a second batch refuses to start and leaves
the first one's folders in progress alone; a lock whose batch is gone is taken over; the lock
goes with its batch, on an error too."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from batch.lock import LOCK_NAME, acquire, out_lock, read_holder, release
from dream.cli import main
from dream.errors import InputError

IN_PROGRESS = ".rec1.tmp-12345-abcdef12"     # a running batch's half-written folder
EXIT_ERROR = 2


@pytest.fixture
def running_pid():
    """The pid of a process that runs while the test does (another batch, as far as a lock
    can tell)."""
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    yield proc.pid
    proc.kill()
    proc.wait()


def gone_pid() -> int:
    """The pid of a process that has ended (a batch killed with kill -9)."""
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    return int(proc.stdout)


def write_lock(folder: Path, pid: int, host: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    lock = folder / LOCK_NAME
    lock.write_text(json.dumps({"pid": pid, "host": host or socket.gethostname()}))
    return lock


def test_a_second_batch_into_the_same_out_refuses_and_removes_nothing(tmp_path, capsys,
                                                                      running_pid):
    recording = tmp_path / "recs" / "rec1"
    recording.mkdir(parents=True)
    (recording / "000000.json").write_text("{}")
    out = tmp_path / "out"
    write_lock(out, running_pid)
    (out / IN_PROGRESS).mkdir()
    code = main(["batch", "calibrate", "--data", str(tmp_path / "recs" / "*"), "--out",
                 str(out), "--use-labels", "--workers", "1"])
    err = capsys.readouterr().err
    assert code == EXIT_ERROR, err
    assert len(err.strip().splitlines()) == 1
    assert f"another dream batch writes into this --out (pid {running_pid} on" in err
    assert f"delete {out / LOCK_NAME}" in err
    assert (out / IN_PROGRESS).is_dir()                      # the first batch's work
    assert read_holder(out / LOCK_NAME).pid == running_pid   # its lock kept


def test_a_lock_is_held_while_its_batch_runs_then_removed(tmp_path, running_pid):
    with out_lock(tmp_path) as lock:
        holder = read_holder(lock)
        assert (holder.pid, holder.host) == (os.getpid(), socket.gethostname())
        with pytest.raises(InputError, match=f"pid {os.getpid()} on"):
            acquire(tmp_path)                   # a second batch of this very process
    assert not lock.exists()
    with pytest.raises(RuntimeError), out_lock(tmp_path):
        raise RuntimeError("a batch that fails")
    assert not (tmp_path / LOCK_NAME).exists()


def test_a_stale_lock_is_taken_over_one_of_another_host_is_not(tmp_path, caplog):
    write_lock(tmp_path, gone_pid())
    with out_lock(tmp_path) as lock:
        assert read_holder(lock).pid == os.getpid()
    assert "taking over the lock of a batch that is gone" in caplog.text
    write_lock(tmp_path, os.getpid())             # a container started anew, its pid reused
    with out_lock(tmp_path) as lock:
        assert read_holder(lock).pid == os.getpid()
    write_lock(tmp_path, gone_pid(), host="elsewhere")
    with pytest.raises(InputError, match="on elsewhere"):
        acquire(tmp_path)
    (tmp_path / LOCK_NAME).write_text("")         # unreadable: not ours to remove
    with pytest.raises(InputError, match="another dream batch writes into this --out"):
        acquire(tmp_path)
    release(tmp_path / LOCK_NAME)                 # not this batch's: kept
    assert (tmp_path / LOCK_NAME).exists()


def test_the_lock_doctests():
    import doctest

    import batch.lock

    assert doctest.testmod(batch.lock).failed == 0


def test_two_batches_cannot_both_take_over_one_stale_lock(tmp_path):
    """The first batch to take over a stale lock holds it (flock) before it rewrites it; a
    second one starting at the same moment finds it held, whatever pid the file still names
    (both took it over, and the second removed the first one's work in progress)."""
    import fcntl

    lock = write_lock(tmp_path, gone_pid())
    fd = os.open(lock, os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)    # the first batch, taking it over
        with pytest.raises(InputError, match="another dream batch writes into this --out"):
            acquire(tmp_path)
    finally:
        os.close(fd)
    with out_lock(tmp_path) as taken:                      # let go: stale, taken over
        assert read_holder(taken).pid == os.getpid()
