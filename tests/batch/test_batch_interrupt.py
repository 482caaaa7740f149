"""SIGTERM stops a batch as Ctrl-C does (`batch.interrupt`): KeyboardInterrupt in its main
thread, once, while the batch runs; the handler before it restored after."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from batch.interrupt import held_interrupts, interrupt, sigterm_interrupts

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


def test_an_interrupt_is_held_to_the_end_of_the_outermost_held_block():
    steps = []
    with pytest.raises(KeyboardInterrupt):
        with held_interrupts():
            with held_interrupts():
                interrupt()
                steps.append("inner")
            steps.append("outer")
    assert steps == ["inner", "outer"]
    with pytest.raises(KeyboardInterrupt):
        interrupt()                     # not held: at once


def test_a_held_blocks_own_exception_goes_on_and_drops_the_interrupt():
    with pytest.raises(ValueError):
        with held_interrupts():
            interrupt()
            raise ValueError("the step failed")
    with held_interrupts():             # nothing left over from the block before
        pass


def test_the_interrupt_doctests():
    import doctest

    import batch.interrupt

    assert doctest.testmod(batch.interrupt).failed == 0
