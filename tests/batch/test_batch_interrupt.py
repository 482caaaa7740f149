"""SIGTERM stops a batch as Ctrl-C does (`batch.interrupt`): KeyboardInterrupt in its main
thread, once, while the batch runs; the handler before it restored after."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from batch.interrupt import sigterm_interrupts

WAIT_S = 5.0       # a signal to this process is handled well within this
SETTLE_S = 0.1     # time for a second signal to be handled (and ignored)


def own(signum, frame) -> None:
    """A handler the batch's caller had installed."""


def test_sigterm_interrupts_once_then_the_handler_before_is_back():
    previous = signal.signal(signal.SIGTERM, own)
    try:
        with sigterm_interrupts():
            with pytest.raises(KeyboardInterrupt):
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(WAIT_S)
            os.kill(os.getpid(), signal.SIGTERM)    # stopping already: not interrupted again
            time.sleep(SETTLE_S)
        assert signal.getsignal(signal.SIGTERM) is own
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def test_outside_the_main_thread_nothing_changes():
    seen = []

    def run() -> None:
        with sigterm_interrupts():
            seen.append(signal.getsignal(signal.SIGTERM))

    before = signal.getsignal(signal.SIGTERM)
    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    assert seen == [before]


def test_the_interrupt_doctests():
    import doctest

    import batch.interrupt

    assert doctest.testmod(batch.interrupt).failed == 0
