"""A local worker of a killed batch finishes its item and exits instead of waiting for ever."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from contextlib import nullcontext
from pathlib import Path

import pytest

from batch.parent_watch import ParentWatch

EXIT_WAIT_S = 20.0
POLL_S = 0.05


def _watch(alive: list[bool]) -> tuple[ParentWatch, list[str]]:
    exits: list[str] = []
    return ParentWatch(lambda: alive[0], lambda: exits.append("exit")), exits


def test_a_worker_stays_while_its_batch_runs():
    watch, exits = _watch([True])
    assert watch.check() is False
    with watch.item():
        pass
    assert exits == []


def test_an_idle_worker_exits_as_soon_as_its_batch_is_gone():
    alive = [True]
    watch, exits = _watch(alive)
    watch.check()
    alive[0] = False
    assert watch.check() is True and exits == ["exit"]


@pytest.mark.parametrize("fails", [False, True])
def test_a_busy_worker_finishes_its_item_first(fails):
    alive = [True]
    watch, exits = _watch(alive)
    with pytest.raises(RuntimeError) if fails else nullcontext():
        with watch.item():
            alive[0] = False
            assert watch.check() is True
            assert exits == []                  # the item runs on to its end
            if fails:
                raise RuntimeError("the item failed")
    assert exits == ["exit"]


CHILD = """
import sys, time
from batch.parent_watch import watch_parent
watch_parent(int(sys.argv[1]), poll_s=0.05)
time.sleep(600)
"""

PARENT = """
import subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c", sys.argv[1], str(__import__("os").getpid())])
print(child.pid, flush=True)
time.sleep(600)
"""


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    status = Path(f"/proc/{pid}/status")
    return not (status.is_file() and "\nState:\tZ" in status.read_text())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="kill -9 and /proc")
def test_a_process_whose_parent_is_killed_exits():
    repo = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([repo, os.environ.get("PYTHONPATH", "")])}
    parent = subprocess.Popen([sys.executable, "-c", PARENT, CHILD], stdout=subprocess.PIPE,
                              text=True, env=env)
    child = int(parent.stdout.readline())
    try:
        time.sleep(0.5)
        assert _running(child)                      # it waits while its parent runs
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + EXIT_WAIT_S
        while _running(child) and time.monotonic() < deadline:
            time.sleep(POLL_S)
        assert not _running(child)
    finally:
        if _running(child):
            os.kill(child, signal.SIGKILL)


def test_docstring_examples_run():
    import doctest

    import batch.parent_watch

    assert doctest.testmod(batch.parent_watch).failed == 0
