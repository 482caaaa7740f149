"""The progress line of `dream batch` on stderr: items done and failed, running, and an
estimate of the time left from this run's own pace (on a terminal one line rewritten in place,
to a file or pipe a whole line every `PIPED_PERIOD_S`)."""

from __future__ import annotations

import sys
import time
from typing import TextIO

TERMINAL_PERIOD_S = 1.0
PIPED_PERIOD_S = 10.0


class BatchProgress:
    """`update(n, failed)` after each finished item; `close()` ends the line."""

    def __init__(self, label: str, total: int, already: int, workers: int,
                 stream: TextIO | None = None, unit: str = "recordings") -> None:
        self.stream = stream or sys.stderr
        isatty = getattr(self.stream, "isatty", None)
        self.interactive = bool(isatty()) if callable(isatty) else False
        self.period_s = TERMINAL_PERIOD_S if self.interactive else PIPED_PERIOD_S
        self.label, self.unit, self.workers = label, unit, workers
        self.total, self.done, self.already, self.failed = total, already, already, 0
        self.start = self.last = time.perf_counter()
        self.open_line = False

    def text(self, now: float) -> str:
        finished = self.done - self.already
        left = self.total - self.done
        running = min(self.workers, left)
        eta = ""
        if finished and left:
            eta = f", about {(now - self.start) / finished * left:.0f} s left"
        failed = f", {self.failed} failed" if self.failed else ""
        return (f"{self.label}: {self.done}/{self.total} {self.unit} done{failed}, "
                f"{running} running{eta}")

    def update(self, n: int = 1, failed: bool = False) -> None:
        self.done += n
        self.failed += int(failed)
        now = time.perf_counter()
        if now - self.last < self.period_s and self.done < self.total:
            return
        self.last = now
        if self.interactive:
            print(f"\r{self.text(now)} ", end="", file=self.stream, flush=True)
            self.open_line = True
        else:
            print(self.text(now), file=self.stream, flush=True)
        if self.done >= self.total:
            self.close()

    def close(self) -> None:
        if self.open_line:
            print(file=self.stream, flush=True)
            self.open_line = False
