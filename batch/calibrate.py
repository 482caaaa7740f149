"""`dream batch calibrate`: one `dream calibrate` process per recording, started by the workers
of an engine (`batch.engine`).

Each recording gets its own folder under the output folder: RESULT.json and the files written
beside it, `calibrate.log` (what `dream calibrate` prints) and `batch.json` (its row of the
summary, the content hash of its inputs). The folder is written in a hidden temporary folder
and renamed into place when complete, so a batch killed at any point leaves only whole folders.
A re-run skips the recordings whose folder says `ok` with the same content hash and redoes the
rest (failed, missing, or changed inputs). A list file's line may give its recording options of
its own (`batch.recordings`): they replace the batch's for it, and enter its content hash.
"""

from __future__ import annotations

import argparse
import json
import logging
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import closing, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from batch.engine import WorkerLost
from batch.interrupt import held_interrupts
from batch.lock import out_lock
from batch.options import (
    KEYPOINT_SOURCES,
    RESULT_NAME,
    absolute_options,
    calibrate_parser,
    check_option_files,
    check_options,
    line_options,
    option_files,
)
from batch.recordings import (
    Listed,
    earlier_names,
    folder_names,
    input_hash,
    list_recordings,
    options_digest,
    recording_digest,
    recording_stat,
)
from batch.summary import OK, failed_row, result_row, write_summary
from dream.errors import InputError
from dream.io import atomic_directory, remove_temporaries, write_json_atomic

log = logging.getLogger(__name__)

LOG_NAME = "calibrate.log"
RECORD_NAME = "batch.json"
OVERLAYS_NAME = "overlays"
SUMMARY_PERIOD_S = 5.0   # the summary of thousands of recordings is not rewritten per result
ERROR_PREFIX = "dream calibrate: error: "
RERUN_ALONE = "run dream calibrate on this recording alone to see where it stops"
# why a signal kills `dream calibrate`, and what to do (by the signal's name)
KILLED_BY = {
    "SIGKILL": ("out of memory?", "check `dmesg` for the out-of-memory killer and give each "
                "worker more memory (fewer --workers)"),
    "SIGSEGV": ("a crash in a native library", RERUN_ALONE),
    "SIGABRT": ("a native library aborted", RERUN_ALONE),
}
KILLED_OTHER = ("stopped from outside, or a crash", "let it run to its end, or " + RERUN_ALONE)


@dataclass(frozen=True)
class CalibrateTask:
    """One recording's calibration: what a worker is sent (paths and options, no data)."""

    recording: str
    name: str
    out_dir: str
    options: Mapping[str, Any] = field(default_factory=dict)
    input_hash: str = ""
    overlays: bool = False
    recording_stat: str = ""
    recording_digest: str = ""
    line_options: str = ""      # its list line's own options, as written (summary `options`)

    def record(self, row: dict[str, Any]) -> dict[str, Any]:
        """The recording folder's `batch.json`: the row and what says whether it is current."""
        return {"input_hash": self.input_hash, "recording_stat": self.recording_stat,
                "recording_digest": self.recording_digest, "row": row}


def calibrate_one(task: CalibrateTask) -> dict[str, Any]:
    """Run `dream calibrate` on one recording into its folder (worker side); returns its row
    of the summary. The command runs in a process of its own, exactly as a user would run it,
    so its result is the one of a single run (bit for bit: the solvers' floating-point sums
    depend on the memory a long-lived process has seen). Any failure becomes the row's
    one-line error, never an exception: one recording does not stop the others."""
    start = time.perf_counter()
    folder = Path(task.out_dir) / task.name
    with atomic_directory(folder, overwrite=True) as tmp:
        result_path = tmp / RESULT_NAME
        command = calibrate_command(task, result_path, tmp / OVERLAYS_NAME)
        with (tmp / LOG_NAME).open("w", encoding="utf-8") as log_file:
            print("$ " + " ".join(command), file=log_file, flush=True)
            run = _run_to_the_end(command, log_file)
            log_file.write(run.stderr)
        seconds = time.perf_counter() - start
        if run.returncode == 0:
            doc = _with_final_paths(result_path, folder, task.overlays)
            row = result_row(task.recording, task.name, doc, seconds, task.line_options)
        else:
            row = failed_row(task.recording, task.name, _error_line(run), seconds,
                             task.line_options)
        write_json_atomic(tmp / RECORD_NAME, task.record(row))
    return row


def _run_to_the_end(command: list[str], log_file: Any) -> subprocess.CompletedProcess:
    """`command` run with its output into `log_file` and its errors kept; interrupted
    (Ctrl-C, SIGTERM: KeyboardInterrupt), it is killed and waited for before the interrupt goes
    on, so a stopped batch leaves no `dream calibrate` still running (`subprocess.run` kills it
    but does not wait on an interrupt). A stop while it starts comes once `proc` holds it."""
    proc: subprocess.Popen | None = None
    try:
        with held_interrupts():
            proc = subprocess.Popen(command, stdout=log_file, stderr=subprocess.PIPE, text=True)
        with proc:
            _, stderr = proc.communicate()
    except BaseException:
        if proc is not None:
            proc.kill()
            proc.wait()
        raise
    return subprocess.CompletedProcess(command, proc.returncode, None, stderr)


def _error_line(run: subprocess.CompletedProcess) -> str:
    """The one-line error of a failed `dream calibrate` (a crash: its last line; killed by a
    signal: which)."""
    if run.returncode < 0:
        return killed_line(-run.returncode)
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    for line in lines:
        if line.startswith(ERROR_PREFIX):
            return line[len(ERROR_PREFIX):]
    last = lines[-1] if lines else "no message"
    return f"internal error (exit code {run.returncode}): {last}"


def killed_line(number: int) -> str:
    """The error of a `dream calibrate` killed by signal `number` (SIGKILL: most often the
    kernel's out-of-memory killer)."""
    try:
        name = signal.Signals(number).name
    except ValueError:
        name = "unknown signal"
    cause, fix = KILLED_BY.get(name, KILLED_OTHER)
    return (f"dream calibrate was killed by signal {number} ({name}: {cause}). Fix: {fix}, "
            f"then run the same command again (it redoes the failed recordings)")


def dream_command() -> list[str]:
    """How this Python runs the `dream` program (its console script where installed)."""
    script = Path(sys.executable).parent / "dream"
    return [str(script)] if script.is_file() else [sys.executable, "-m", "dream.cli"]


def calibrate_command(task: CalibrateTask, result: Path, overlays: Path) -> list[str]:
    """The `dream calibrate` command line of a task."""
    command = [*dream_command(), "calibrate", "--data", task.recording, "--out", str(result)]
    if task.overlays:
        command += ["--overlays", str(overlays)]
    return command + calibrate_argv(task.options)


def calibrate_argv(options: Mapping[str, Any]) -> list[str]:
    """The command-line options of `dream calibrate` that give these request fields (those
    at their default left out)."""
    parser = calibrate_parser(argparse.ArgumentParser(add_help=False))
    argv: list[str] = []
    for action in parser._actions:
        if action.dest not in options or action.dest == "data":
            continue
        value = options[action.dest]
        if value is None or value == action.default:
            continue
        flag = next(o for o in action.option_strings if o.startswith("--"))
        if isinstance(action, argparse._StoreTrueAction):
            argv.append(flag)
        else:
            argv += [flag, str(value)]
    return argv


def _with_final_paths(result_path: Path, folder: Path, overlays: bool) -> dict:
    """RESULT.json, its settings naming the recording's folder, not the temporary it was
    written in."""
    doc = json.loads(result_path.read_text(encoding="utf-8"))
    settings = dict(doc.get("settings", {}))
    settings["out"] = str(folder / RESULT_NAME)
    settings["overlays"] = str(folder / OVERLAYS_NAME) if overlays else None
    doc = {**doc, "settings": settings}
    write_json_atomic(result_path, doc)
    return doc


def read_record(folder: Path) -> dict | None:
    """A recording folder's `batch.json` (None when missing or unreadable: redo it)."""
    try:
        record = json.loads((folder / RECORD_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and isinstance(record.get("row"), dict) else None


@dataclass(frozen=True)
class BatchPlan:
    """The tasks of a batch: those to run and the rows of those already done."""

    tasks: tuple[CalibrateTask, ...]
    todo: tuple[CalibrateTask, ...]
    rows: dict[str, dict]


def plan_batch(data: str, out_dir: Path, options: Mapping[str, Any],
               overlays: bool) -> BatchPlan:
    """Every recording of `data` as a task; those whose folder holds an `ok` row of the same
    content hash are done already. A recording's content is read again only where its files'
    sizes or modification times changed since its folder was written."""
    out_resolved = out_dir.resolve()
    entries = [e for e in list_recordings(data)     # --data 'runs/*' --out runs/calib
               if e.path != out_resolved and out_resolved not in e.path.parents]
    if not entries:
        raise InputError(f"--data '{data}' matches only the output folder", out_dir,
                         "give --data the recordings and --out a folder outside them")
    check_options(options, entries[0].path)
    check_option_files(options, Path.cwd())
    plans: dict[tuple[str, ...], tuple[dict[str, Any], str]] = {}
    for entry in entries:                 # every line checked before any work
        if entry.argv not in plans:
            plans[entry.argv] = _recording_options(entry, options, overlays)
    tasks, todo, rows = [], [], {}
    names = earlier_names([(str(e.path), shlex.join(e.argv)) for e in entries],
                          folder_names([e.path for e in entries]), _earlier_folders(out_dir))
    for entry, name in zip(entries, names, strict=True):
        path = entry.path
        own, digest = plans[entry.argv]
        record = read_record(out_dir / name) or {}
        stat = recording_stat(path)
        content = (record["recording_digest"] if record.get("recording_stat") == stat
                   and isinstance(record.get("recording_digest"), str)
                   else recording_digest(path))
        task = CalibrateTask(str(path), name, str(out_dir), own,
                             input_hash(digest, content), overlays, stat, content,
                             shlex.join(entry.argv))
        tasks.append(task)
        if record.get("input_hash") == task.input_hash and record["row"].get("status") == OK:
            rows[name] = record["row"]
        else:
            todo.append(task)
    return BatchPlan(tuple(tasks), tuple(todo), rows)


def _earlier_folders(out_dir: Path) -> dict[tuple[str, str], str]:
    """The recording folders an earlier batch wrote into `out_dir`: (recording, its list
    line's options) -> the folder's name."""
    folders: dict[tuple[str, str], str] = {}
    for folder in sorted(out_dir.iterdir()) if out_dir.is_dir() else ():
        row = (read_record(folder) or {}).get("row") or {}
        if isinstance(row.get("recording"), str):
            folders.setdefault((row["recording"], str(row.get("options") or "")), folder.name)
    return folders


def _recording_options(entry: Listed, options: Mapping[str, Any],
                       overlays: bool) -> tuple[dict[str, Any], str]:
    """A recording's options (the batch's, replaced by its list line's, checked; files made
    absolute) and their digest (`options_digest`)."""
    own = line_options(entry)
    if own.keys() & set(KEYPOINT_SOURCES):          # one replaces the other
        options = {k: v for k, v in options.items() if k not in KEYPOINT_SOURCES}
    merged = {**options, **own}
    if own:
        check_options(merged, entry.path, entry.where)
    merged = absolute_options(merged)
    return merged, options_digest({**merged, "overlays": overlays}, option_files(merged))


def run_batch(plan: BatchPlan, out_dir: Path, engine,
              on_result: Callable[[dict], None] | None = None) -> list[dict]:
    """Run the plan's open tasks on `engine`; the summary is rewritten at most every
    `SUMMARY_PERIOD_S` and at the end (each recording's `batch.json` is its record the moment
    it finishes). Returns the rows in the order of the tasks."""
    rows = dict(plan.rows)
    written = time.monotonic()
    try:
        with closing(engine.run(calibrate_one, plan.todo)) as results:  # stopped on leaving
            for i, value in results:
                task = plan.todo[i]
                if isinstance(value, WorkerLost):
                    value = _lost_row(task, value)
                rows[task.name] = value
                if time.monotonic() - written >= SUMMARY_PERIOD_S:
                    write_summary(out_dir, _rows_so_far(plan, rows))
                    written = time.monotonic()
                if on_result is not None:
                    on_result(value)
    except KeyboardInterrupt:           # Ctrl-C, SIGTERM: the summary lists what is done
        write_summary(out_dir, _rows_so_far(plan, rows))
        raise
    ordered = [rows[t.name] for t in plan.tasks]
    write_summary(out_dir, ordered)
    return ordered


def _rows_so_far(plan: BatchPlan, rows: dict[str, dict]) -> list[dict]:
    return [rows[t.name] for t in plan.tasks if t.name in rows]


def _lost_row(task: CalibrateTask, lost: WorkerLost) -> dict:
    """The row (and folder record) of a recording whose worker died."""
    row = failed_row(task.recording, task.name, lost.message, 0.0, task.line_options)
    with atomic_directory(Path(task.out_dir) / task.name, overwrite=True) as tmp:
        (tmp / LOG_NAME).write_text(f"error: {lost.message}\n", encoding="utf-8")
        write_json_atomic(tmp / RECORD_NAME, task.record(row))
    return row


@contextmanager
def batch_output(out: str) -> Iterator[Path]:
    """The batch's output folder, created and locked for this batch while the block runs
    (`batch.lock`: a second batch into it refuses to start). The half-written folders there
    are removed once the lock is held (a killed batch's) and when the block ends (a stopped
    batch's: the block stops its engine's workers first)."""
    from dream.io import make_output_dir

    out_dir = make_output_dir(out)
    with out_lock(out_dir):
        removed = remove_temporaries(out_dir)
        if removed:
            log.info("removed %d half-written folder(s) of an earlier batch", removed)
        try:
            yield out_dir
        finally:
            remove_temporaries(out_dir)
