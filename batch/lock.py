"""One batch at a time in an output folder: the lock file `.dream-batch.lock` in `--out`.

A batch that starts removes the half-written folders a killed batch left in `--out`; a second
batch started into the folder of a running one would so delete that one's work in progress.
The lock prevents it: it holds the batch's pid and host and is held with `flock` while the
batch runs, is taken before anything is removed, and removed when the batch ends (an error and
Ctrl-C included). A lock whose batch is gone (not held, its pid no longer running on this host:
a batch killed with kill -9) is taken over, by one batch only; one of another host cannot be
checked from here and is left to its owner (the error says how to remove it).

    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> with out_lock(folder) as lock:
    ...     read_holder(lock).pid == os.getpid()
    True
    >>> (folder / LOCK_NAME).exists()
    False
"""

from __future__ import annotations

import fcntl
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
LOCK_MODE = 0o644

_HELD: dict[Path, int] = {}         # the locks this process holds, and their descriptors


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
    """Take the lock of `out_dir` (a stale one taken over); returns its path.

    The file is held with `flock` while the batch runs, so two batches that start together
    cannot both take over one stale lock: the second finds it held. The holder it names is
    checked as well (a lock of another host, or of a running process of this one, is kept).

    Raises:
        InputError: another batch that runs (or may run) holds it, or it cannot be written.
    """
    lock = out_dir / LOCK_NAME
    for _ in range(TAKE_OVER_TRIES):
        fd, created = _open(lock)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise _in_use(out_dir, lock, read_holder(lock)) from None
        if not _still_at(fd, lock):       # removed by the batch that held it: open anew
            os.close(fd)
            continue
        holder = None if created else read_holder(lock)
        if not created and (lock.resolve() in _HELD or not is_stale(holder)):
            os.close(fd)
            raise _in_use(out_dir, lock, holder)
        if holder is not None:
            log.warning("%s: taking over the lock of a batch that is gone (%s)", out_dir,
                        holder.describe())
        _write_holder(fd)
        _HELD[lock.resolve()] = fd
        return lock
    raise _in_use(out_dir, lock, read_holder(lock))


def _open(lock: Path) -> tuple[int, bool]:
    """A descriptor of `lock`, and whether this call created it."""
    try:
        try:
            return os.open(lock, os.O_RDWR | os.O_CREAT | os.O_EXCL, LOCK_MODE), True
        except FileExistsError:
            return os.open(lock, os.O_RDWR), False
    except OSError as exc:
        raise InputError(f"cannot open the batch's lock file ({exc.strerror or exc})", lock,
                         "give --out a folder you can write") from None


def _still_at(fd: int, lock: Path) -> bool:
    """Whether the open file `fd` is still the one at `lock`'s path."""
    try:
        return os.fstat(fd).st_ino == os.stat(lock).st_ino
    except FileNotFoundError:
        return False


def _write_holder(fd: int) -> None:
    os.ftruncate(fd, 0)
    os.lseek(fd, 0, os.SEEK_SET)
    os.write(fd, json.dumps(asdict(this_batch())).encode())


def _in_use(out_dir: Path, lock: Path, holder: Holder | None) -> InputError:
    who = f" ({holder.describe()})" if holder is not None else ""
    return InputError(f"another dream batch writes into this --out{who}", out_dir,
                      f"wait for it to end or give another --out; if no batch runs there any "
                      f"more, delete {lock}")


def release(lock: Path) -> None:
    """Remove the lock file and let it go, where this batch holds it."""
    fd = _HELD.pop(lock.resolve(), None)
    if fd is None:
        return
    lock.unlink(missing_ok=True)           # while still held: no one takes the removed file
    os.close(fd)
