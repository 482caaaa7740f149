"""A batch stopped with SIGTERM (`kill PID`, `timeout`, a Slurm job's end) stops as on Ctrl-C:
the signal raises KeyboardInterrupt in the batch's main thread, so that the engine stops its
workers, the summary lists what is done, the lock of `--out` is removed and the command ends
with "interrupted" (exit 130), instead of the process dying at once with its workers left
running.

    >>> import os, time
    >>> with sigterm_interrupts():
    ...     try:
    ...         os.kill(os.getpid(), signal.SIGTERM)
    ...         time.sleep(1)
    ...     except KeyboardInterrupt:
    ...         print("interrupted")
    interrupted

A stop handler in a worker calls `interrupt()`: where a step must not be cut in two (a child
process started but not yet owned by its `Popen`, which would leave it running unowned), the
step runs in `held_interrupts()` and the interrupt comes when it ends.

    >>> steps = []
    >>> try:
    ...     with held_interrupts():
    ...         interrupt()             # held: the step goes on
    ...         steps.append("done")
    ... except KeyboardInterrupt:
    ...     steps.append("interrupted")
    >>> steps
    ['done', 'interrupted']
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt while the block runs (the first one: a batch already
    stopping is not interrupted in its clean-up by a second); the handler before it is
    restored after. Only the main thread can handle signals: elsewhere nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, interrupt_once())
    try:
        yield
    finally:
        # None: a handler not installed from Python (Ray's); the default is the closest
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


_HELD = {"depth": 0, "pending": False}   # open `held_interrupts` blocks; an interrupt held


def interrupt() -> None:
    """Raise KeyboardInterrupt now, or at the end of the `held_interrupts` block running."""
    if _HELD["depth"]:
        _HELD["pending"] = True
        return
    raise KeyboardInterrupt


@contextmanager
def held_interrupts() -> Iterator[None]:
    """An `interrupt()` while the block runs is raised as the block ends (not where the block
    has its own exception: that one goes on, the interrupt is dropped with it)."""
    _HELD["depth"] += 1
    try:
        yield
    finally:
        _HELD["depth"] -= 1
        stop = not _HELD["depth"] and _HELD["pending"]
        if not _HELD["depth"]:
            _HELD["pending"] = False
    if stop:
        raise KeyboardInterrupt


def interrupt_once() -> Callable[[int, Any], None]:
    """A signal handler that raises KeyboardInterrupt the first time and ignores the rest."""
    raised: list[int] = []

    def handler(signum: int, frame: Any) -> None:
        if not raised:
            raised.append(signum)
            raise KeyboardInterrupt

    return handler
