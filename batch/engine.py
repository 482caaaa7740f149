"""Where the work of `dream batch` runs: a local process pool (`LocalEngine`, the default) or a
Ray cluster (`RayEngine`: a local Ray on this machine, or an existing cluster joined by its
address). Both take the same module-level functions and give the same results.

A worker first runs `setup(*setup_args)` once (a renderer's scene, say), then `fn(item)` for
one item at a time. Each worker is one process that uses one core: numerical libraries are
held to one thread (`worker_env`), so that N workers fill N cores. At most one item per worker
is in flight, so a batch that is killed abandons at most `workers` items. An item whose worker
process dies (a crash in a native library) is reported as `WorkerLost`, the others are not: the
local pool runs the items that were in flight when it broke again one at a time; a Ray actor's
death names its item, which is tried `MAX_ATTEMPTS` times. A local worker whose batch is killed
finishes the item it runs and exits (`batch.parent_watch`); Ray's actors die with their driver.
A local run that stops early (Ctrl-C, SIGTERM turned into KeyboardInterrupt by
`batch.interrupt`, an item's exception) stops its workers: each interrupts the item it runs
(which cleans up after itself) and exits, and the run waits for them.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from batch.interrupt import interrupt
from batch.parent_watch import ParentWatch, watch_parent
from dream.errors import InputError
from dream.threads import THREADS_ENV

log = logging.getLogger(__name__)

LOCAL, RAY = "local", "ray"
ENGINES = (LOCAL, RAY)
MAX_ATTEMPTS = 2          # tries of an item whose Ray worker died
WORKER_DIED = ("its worker process died running it (a crash in a native library, or the "
               "memory ran out)")
# one thread per worker process; MuJoCo renders offscreen with Mesa's software EGL
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", THREADS_ENV)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)   # a local worker stops on either
STOPPED_EXIT_STATUS = 130                         # a worker stopped with its batch
CLUSTER_EXTRA = "pip install 'dream-calib[cluster]' (Ray)"
JOIN_FIX = ("check that `ray start --head` runs there and this machine reaches its port; with "
            "Ray's token authentication set RAY_AUTH_MODE=token and give this machine the "
            "cluster's token (docs/scaling.md)")


def worker_env() -> dict[str, str]:
    """The environment variables every worker process starts with."""
    env = dict.fromkeys(THREAD_VARIABLES, "1")
    env["MUJOCO_GL"] = os.environ.get("MUJOCO_GL", "egl")
    return env


@dataclass(frozen=True)
class WorkerLost:
    """The outcome of an item whose worker process died running it (the local pool: running
    it alone; Ray: `MAX_ATTEMPTS` times)."""

    message: str


@dataclass(frozen=True)
class EngineSettings:
    """`--engine`, `--workers` and `--address` of `dream batch`. `workers` None: one per core
    of this machine (of the cluster, when joining one)."""

    engine: str = LOCAL
    workers: int | None = None
    address: str | None = None

    def __post_init__(self) -> None:
        if self.engine not in ENGINES:
            raise InputError(f"unknown --engine {self.engine!r}",
                             fix=f"use one of {', '.join(ENGINES)}")
        if self.workers is not None and self.workers < 1:
            raise InputError(f"--workers must be 1 or more, got {self.workers}",
                             fix="give --workers N with N >= 1, or leave it out (one per core)")
        if self.address and self.engine != RAY:
            raise InputError("--address joins a Ray cluster, and --engine is local",
                             fix="add --engine ray, or drop --address")


_SETUP_FAILED: list[Exception] = []   # what a local worker's setup raised, raised per item


def _init_worker(setup: Callable[..., None] | None, setup_args: tuple) -> Exception | None:
    """One thread for OpenCV, then the setup; what the setup raises is returned, so that each
    item raises it as `fn` would (not a worker that seems to have died)."""
    import cv2

    cv2.setNumThreads(1)
    if setup is None:
        return None
    try:
        setup(*setup_args)
    except Exception as exc:  # handed to the driver with the first item
        return exc
    return None


_WATCH: list[ParentWatch] = []       # a local worker's watch of its batch (set up first)


_STOP = {"requested": False, "in_item": False}   # a local worker's stop (`_stop_worker`)


def _init_local_worker(setup: Callable[..., None] | None, setup_args: tuple,
                       batch_pid: int) -> None:
    _WATCH.append(watch_parent(batch_pid))
    for signum in STOP_SIGNALS:
        signal.signal(signum, _stop_worker)
    failed = _init_worker(setup, setup_args)
    if failed is not None:
        _SETUP_FAILED.append(failed)


def _stop_worker(signum: int, frame: Any) -> None:
    """A local worker told to stop (its batch stops: Ctrl-C, SIGTERM): where no item runs it
    exits at once; else the item is interrupted (KeyboardInterrupt, once; `calibrate_one`
    then kills its `dream calibrate`, a stop while it starts one held until it has it, and
    removes its temporary folder) and the worker exits after it (`_call`), taking no other
    item."""
    first = not _STOP["requested"]
    _STOP["requested"] = True
    if not _STOP["in_item"]:
        os._exit(STOPPED_EXIT_STATUS)
    if first:
        interrupt()


def _call(fn: Callable[[Any], Any], item: Any) -> Any:
    if _SETUP_FAILED:
        raise _SETUP_FAILED[0]
    try:
        with _WATCH[0].item():
            return _run_item(fn, item)
    finally:
        if _STOP["requested"]:
            os._exit(STOPPED_EXIT_STATUS)


def _run_item(fn: Callable[[Any], Any], item: Any) -> Any:
    _STOP["in_item"] = True
    try:
        return fn(item)
    finally:
        _STOP["in_item"] = False


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Tell each worker process of `pool` to stop (`_stop_worker`). The pool's processes are
    its `_processes` (pid: process), the only way to reach them."""
    for pid in list(getattr(pool, "_processes", None) or {}):
        try:
            os.kill(pid, signal.SIGTERM)
        except ProcessLookupError:      # gone already
            continue


@contextmanager
def _environment(env: dict[str, str]) -> Iterator[None]:
    """`env` set in this process while the pool's workers are spawned (they inherit it)."""
    before = {name: os.environ.get(name) for name in env}
    os.environ.update(env)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


class LocalEngine:
    """A pool of `workers` spawned processes on this machine (no Ray)."""

    def __init__(self, workers: int | None = None) -> None:
        self.workers = workers or os.cpu_count() or 1

    def describe(self) -> str:
        return f"local engine, {self.workers} worker process{'es' * (self.workers > 1)}"

    def start(self) -> None:
        """Nothing to start: the workers are spawned as `run` needs them."""

    def close(self) -> None:
        """Nothing to stop: `run` stops its workers when it ends."""

    def _pool(self, setup, setup_args) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"),
                                   initializer=_init_local_worker,
                                   initargs=(setup, setup_args, os.getpid()))

    def run(self, fn: Callable[[Any], Any], items: Sequence[Any],
            setup: Callable[..., None] | None = None, setup_args: tuple = ()
            ) -> Iterator[tuple[int, Any]]:
        """(index into `items`, `fn(item)` or `WorkerLost`) as each finishes. An exception
        that `fn` raises stops the run and is raised here. The workers are spawned as they
        are needed, so this process holds `worker_env()` while it runs."""
        with _environment(worker_env()):
            yield from self._run(fn, items, setup, setup_args)

    def _run(self, fn, items, setup, setup_args) -> Iterator[tuple[int, Any]]:
        """When a worker dies, the pool breaks and every item in flight with it; those are
        suspects, run again one at a time, so that only the item that kills its worker alone
        is lost."""
        pending, suspects = deque(range(len(items))), deque()
        pool = self._pool(setup, setup_args)
        in_flight: dict[Future, tuple[int, bool]] = {}     # future -> (item, run alone)
        try:
            while pending or suspects or in_flight:
                source, window = (suspects, 1) if suspects else (pending, self.workers)
                while source and len(in_flight) < window:
                    i = source.popleft()
                    in_flight[pool.submit(_call, fn, items[i])] = (i, source is suspects)
                done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                broken = False
                for future in done:
                    i, alone = in_flight.pop(future)
                    try:
                        yield i, future.result()
                    except BrokenProcessPool:
                        broken = True
                        if alone:
                            yield i, WorkerLost(WORKER_DIED)
                        else:
                            suspects.append(i)
                if broken:
                    suspects.extend(i for i, _ in in_flight.values())
                    in_flight.clear()
                    pool.shutdown(wait=False, cancel_futures=True)
                    pool = self._pool(setup, setup_args)
        except BaseException:
            # stopped early (Ctrl-C, SIGTERM, an item's exception, the run closed): an item may
            # be running that `in_flight` does not hold yet (interrupted in `submit`), so every
            # worker is told to stop
            _stop_workers(pool)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _lost_or_retry(index: int, tries: int, pending: deque) -> WorkerLost | None:
    """Put the item back in the queue, or give it up after `MAX_ATTEMPTS` tries."""
    if tries < MAX_ATTEMPTS:
        log.warning("a worker process died; item %d is tried again", index)
        pending.append((index, tries))
        return None
    return WorkerLost(f"{WORKER_DIED} ({tries} tries)")


class RayEngine:
    """Ray actors, one per worker: on a local Ray started here (`address` None and no
    `RAY_ADDRESS`; a new one even where `ray start` runs a cluster) or on an existing cluster
    (docs/scaling.md: the ports Ray opens). Items and results travel as small Python objects
    (paths, not images): the workers read and write the files themselves, so on a cluster
    they must see the same storage."""

    def __init__(self, workers: int | None = None, address: str | None = None) -> None:
        self.address = address or os.environ.get("RAY_ADDRESS") or None
        self.asked = workers
        self.workers = workers or os.cpu_count() or 1
        self.owned = False
        self._ray = None

    def describe(self) -> str:
        where = f"Ray cluster {self.address}" if self.address else "local Ray"
        return f"{where}, {self.workers} worker{'s' * (self.workers > 1)}"

    def start(self):
        """Start or join Ray (once; `run` calls it); returns the `ray` module."""
        if self._ray is not None:
            return self._ray
        try:
            import ray
        except ImportError:
            raise InputError("--engine ray needs Ray, which is not installed",
                             fix=CLUSTER_EXTRA) from None
        self.owned = not ray.is_initialized()   # a Ray this process joined already is kept
        self._ray = ray
        if not self.owned:
            return ray
        runtime_env = {"env_vars": worker_env()}
        quiet = {"log_to_driver": False, "logging_level": logging.WARNING,
                 "configure_logging": False}
        if self.address:
            try:
                ray.init(address=self.address, runtime_env=runtime_env, **quiet)
            except (ConnectionError, RuntimeError, ray.exceptions.RayError) as exc:
                self._ray = None
                reason = (str(exc).strip().splitlines() or [type(exc).__name__])[-1]
                raise InputError(f"cannot join the Ray cluster at {self.address} ({reason})",
                                 fix=JOIN_FIX) from None
            if self.asked is None:
                self.workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
        else:
            ray.init(address="local", num_cpus=self.workers, include_dashboard=False,
                     _node_ip_address="127.0.0.1", runtime_env=runtime_env, **quiet)
        return ray

    def run(self, fn: Callable[[Any], Any], items: Sequence[Any],
            setup: Callable[..., None] | None = None, setup_args: tuple = ()
            ) -> Iterator[tuple[int, Any]]:
        """As `LocalEngine.run`."""
        yield from self._run(self.start(), fn, items, setup, setup_args)

    def close(self) -> None:
        """Stop the local Ray this engine started, or leave the cluster it joined."""
        if self._ray is not None and self.owned:
            self._ray.shutdown()
        self._ray = None

    def _run(self, ray, fn, items, setup, setup_args) -> Iterator[tuple[int, Any]]:
        from ray.exceptions import RayActorError, RayTaskError

        actor_class = ray.remote(num_cpus=1, max_restarts=0)(RayWorker)
        idle = [actor_class.remote(setup, setup_args) for _ in range(self.workers)]
        pending = deque((i, 0) for i in range(len(items)))
        in_flight: dict[Any, tuple[int, int, Any]] = {}
        while pending or in_flight:
            while pending and idle:
                i, tries = pending.popleft()
                actor = idle.pop()
                in_flight[actor.call.remote(fn, items[i])] = (i, tries, actor)
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                i, tries, actor = in_flight.pop(ref)
                try:
                    value = ray.get(ref)
                except RayTaskError as exc:  # what `fn` raised, as the local engine raises it
                    cause = getattr(exc, "cause", None)
                    raise (cause if isinstance(cause, Exception) else exc) from None
                except RayActorError:
                    value = _lost_or_retry(i, tries + 1, pending)
                    actor = actor_class.remote(setup, setup_args)
                idle.append(actor)
                if value is not None:
                    yield i, value


class RayWorker:
    """One Ray actor: `setup` once, then `call` per item (made remote by `RayEngine`)."""

    def __init__(self, setup: Callable[..., None] | None, setup_args: tuple) -> None:
        self.setup_failed = _init_worker(setup, setup_args)

    def call(self, fn: Callable[[Any], Any], item: Any) -> Any:
        if self.setup_failed is not None:
            raise self.setup_failed
        return fn(item)


def make_engine(settings: EngineSettings) -> LocalEngine | RayEngine:
    """The engine of `settings`."""
    if settings.engine == RAY:
        return RayEngine(settings.workers, settings.address)
    return LocalEngine(settings.workers)
