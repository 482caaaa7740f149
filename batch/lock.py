"""One batch at a time in an output folder: the lock file `.dream-batch.lock` in `--out`.

A batch that starts removes the half-written folders a killed batch left in `--out`; a second
batch started into the folder of a running one would so delete that one's work in progress.
The lock prevents it: it holds the batch's pid and host, is taken before anything is removed,
and removed when the batch ends (an error and Ctrl-C included). A lock whose batch is gone (its
pid no longer runs on this host: a batch killed with kill -9) is taken over; one of another
host cannot be checked from here and is left to its owner (the error says how to remove it).

    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> with out_lock(folder) as lock:
    ...     read_holder(lock).pid == os.getpid()
    True
    >>> (folder / LOCK_NAME).exists()
    False
"""

from __future__ import annotations

import json
import logging
import os
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

from dream.errors import InputError

log = logging.getLogger(__name__)

LOCK_NAME = ".dream-batch.lock"     # hidden, and not a temporary (`dream.io.is_temporary`)
TAKE_OVER_TRIES = 2                 # a stale lock removed, then created once more
CHECK_PID = 0                       # os.kill(pid, 0): whether pid runs, no signal sent
TIME_FORMAT = "%Y-%m-%d %H:%M:%S"

_HELD: set[Path] = set()            # the locks this process holds


@dataclass(frozen=True)
class Holder:
    """The batch that holds a lock."""

    pid: int
    host: str
    started: str = ""

    def describe(self) -> str:
        since = f", since {self.started}" if self.started else ""
        return f"pid {self.pid} on {self.host}{since}"


def this_batch() -> Holder:
    return Holder(os.getpid(), socket.gethostname(), time.strftime(TIME_FORMAT))


def read_holder(lock: Path) -> Holder | None:
    """The holder a lock file names (None when it cannot be read: being written, or not a
    lock of ours)."""
    try:
        doc = json.loads(lock.read_text(encoding="utf-8"))
        return Holder(int(doc["pid"]), str(doc["host"]), str(doc.get("started", "")))
    except (OSError, ValueError, TypeError, KeyError):
        return None


def pid_runs(pid: int) -> bool:
    """Whether a process `pid` runs on this machine (another user's included)."""
    try:
        os.kill(pid, CHECK_PID)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def is_stale(holder: Holder | None) -> bool:
    """A lock of this host whose batch is gone (its pid runs no more, or is this very process,
    which does not hold it (`acquire`): a pid reused by a container started anew)."""
    return (holder is not None and holder.host == socket.gethostname()
            and (holder.pid == os.getpid() or not pid_runs(holder.pid)))


@contextmanager
def out_lock(out_dir: Path) -> Iterator[Path]:
    """`out_dir` locked for this batch while the block runs (`acquire`, then `release`)."""
    lock = acquire(out_dir)
    try:
        yield lock
    finally:
        release(lock)


def acquire(out_dir: Path) -> Path:
    """Create the lock file of `out_dir` (a stale one taken over); returns its path.

    Raises:
        InputError: another batch that runs (or may run) holds it, or it cannot be written.
    """
    lock = out_dir / LOCK_NAME
    for _ in range(TAKE_OVER_TRIES):
        if _create(lock):
            _HELD.add(lock.resolve())
            return lock
        holder = read_holder(lock)
        if lock.resolve() in _HELD or not is_stale(holder):
            raise _in_use(out_dir, lock, holder)
        log.warning("%s: taking over the lock of a batch that is gone (%s)", out_dir,
                    holder.describe())
        lock.unlink(missing_ok=True)
    raise _in_use(out_dir, lock, read_holder(lock))


def _create(lock: Path) -> bool:
    """Create `lock` holding this batch, unless it exists (False)."""
    try:
        fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL)
    except FileExistsError:
        return False
    except OSError as exc:
        raise InputError(f"cannot create the batch's lock file ({exc.strerror or exc})", lock,
                         "give --out a folder you can write") from None
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        json.dump(asdict(this_batch()), f)
    return True


def _in_use(out_dir: Path, lock: Path, holder: Holder | None) -> InputError:
    who = f" ({holder.describe()})" if holder is not None else ""
    return InputError(f"another dream batch writes into this --out{who}", out_dir,
                      f"wait for it to end or give another --out; if no batch runs there any "
                      f"more, delete {lock}")


def release(lock: Path) -> None:
    """Remove the lock file, where it is still this batch's."""
    holder = read_holder(lock)
    if holder is not None and (holder.pid, holder.host) == (os.getpid(), socket.gethostname()):
        lock.unlink(missing_ok=True)
    _HELD.discard(lock.resolve())
