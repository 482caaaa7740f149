"""Per-frame work spread over the machine's cores.

Rendering a frame's silhouette (a compiled loop, `dream.rasterize`), its distance transform
and the sampling of it are numpy, numba and OpenCV loops that release the GIL, so independent
frames run in parallel in threads.
`map_frames` returns the same list, in the same order, as a plain loop; work started from a
worker thread runs in that thread (no nested pools, no deadlock).

The number of threads is the number of cores this process may use, at most `MAX_THREADS`;
the environment variable `DREAM_THREADS` overrides it (1: everything in the calling thread).

Example:
    >>> map_frames(lambda x: x * x, [1, 2, 3])
    [1, 4, 9]
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from dream.errors import InputError

MAX_THREADS = 8                 # beyond this, per-frame numpy work gains little
THREADS_ENV = "DREAM_THREADS"   # the user's thread count; 1 runs everything in the caller

Item = TypeVar("Item")
Value = TypeVar("Value")

_worker = threading.local()
_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()


def thread_count() -> int:
    """Threads for per-frame work: `DREAM_THREADS` if set, else the usable cores (at most
    `MAX_THREADS`).

    Raises:
        InputError: `DREAM_THREADS` is not a whole number >= 1.
    """
    text = os.environ.get(THREADS_ENV, "").strip()
    if text:
        if not text.isdigit() or int(text) < 1:
            raise InputError(f"{THREADS_ENV}={text!r} is not a thread count",
                             fix=f"set {THREADS_ENV} to a whole number >= 1, or unset it")
        return int(text)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(MAX_THREADS, cores or 1))


def _mark_worker() -> None:
    _worker.active = True


def _pool(threads: int) -> ThreadPoolExecutor:
    with _pools_lock:
        if threads not in _pools:
            _pools[threads] = ThreadPoolExecutor(threads, thread_name_prefix="dream-frames",
                                                 initializer=_mark_worker)
        return _pools[threads]


def map_frames(fn: Callable[[Item], Value], items: Iterable[Item]) -> list[Value]:
    """`[fn(item) for item in items]`, the items shared out over `thread_count()` threads.

    `fn` must not depend on the order the items run in (each frame's work is independent).
    """
    items = list(items)
    threads = thread_count()
    if threads == 1 or len(items) < 2 or getattr(_worker, "active", False):
        return [fn(item) for item in items]
    return list(_pool(threads).map(fn, items))
