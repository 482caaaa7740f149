"""A local worker process must not outlive its batch.

A `dream batch` killed hard (`kill -9`, the machine's OOM killer) leaves its pool's worker
processes behind: each waits for its next item on a pipe that never closes (a spawned worker
holds both ends of its task queue), for ever. `ParentWatch` ends such a worker: at once where it
is idle, else as soon as the item it runs is done (that item's outputs are written whole or not
at all by the item itself, so finishing it loses nothing a rerun would not redo).

    >>> exits = []
    >>> watch = ParentWatch(parent_alive=lambda: False, exit_=lambda: exits.append("exit"))
    >>> with watch.item():
    ...     watch.check()       # the batch is gone while an item runs: it runs to its end
    True
    >>> exits
    ['exit']
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

POLL_S = 1.0            # how often a worker looks for its batch process
ORPHAN_EXIT_STATUS = 0  # nobody waits for it: its batch is gone


class ParentWatch:
    """Whether a worker's batch process still runs, and what the worker does when not.

    Args:
        parent_alive: True while the batch process runs.
        exit_: ends this worker process (`os._exit` in a worker; tests pass their own).
    """

    def __init__(self, parent_alive: Callable[[], bool], exit_: Callable[[], None]) -> None:
        self._alive, self._exit = parent_alive, exit_
        self._lock = threading.Lock()
        self._busy = self._orphaned = False

    def check(self) -> bool:
        """One look at the batch process: where it is gone, exit now if idle (else at the end
        of the item running). Returns whether it is gone (the watch can stop)."""
        if self._alive():
            return False
        with self._lock:
            self._orphaned = True
            if not self._busy:
                self._exit()
        return True

    @contextmanager
    def item(self) -> Iterator[None]:
        """Around one item: the worker is busy, and exits after it where the batch is gone."""
        with self._lock:
            self._busy = True
        try:
            yield
        finally:
            with self._lock:
                self._busy = False
                if self._orphaned:
                    self._exit()


def watch_parent(parent_pid: int, poll_s: float = POLL_S) -> ParentWatch:
    """A `ParentWatch` of this process's batch (`parent_pid`, the process that spawned it),
    checked every `poll_s` seconds by a daemon thread."""
    watch = ParentWatch(lambda: os.getppid() == parent_pid,
                        lambda: os._exit(ORPHAN_EXIT_STATUS))

    def loop() -> None:
        while True:
            time.sleep(poll_s)
            if watch.check():
                return

    threading.Thread(target=loop, name="batch-parent-watch", daemon=True).start()
    return watch
