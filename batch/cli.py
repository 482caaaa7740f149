"""`dream batch calibrate` and `dream batch synth`: registered through the `dream.commands`
entry point; imports nothing heavy (Ray only when `--engine ray` runs)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields

EXIT_SOME_FAILED = 1     # the batch ran to its end and some recordings failed
ENGINE_HELP = ("local: a process pool on this machine; ray: Ray (the cluster extra), a local "
               "Ray started here or the cluster of --address / RAY_ADDRESS; Ray opens network "
               "ports that belong on a trusted network only (docs/scaling.md, 'Ports and "
               "trust') (default: %(default)s)")
# the request fields `dream batch calibrate` sets itself for each recording
PER_RECORDING = ("data", "out", "overlays", "loaded_model")


def _engine_settings(args: argparse.Namespace):
    from batch.engine import EngineSettings

    return EngineSettings(args.engine, args.workers, args.address)


def _calibrate_options(args: argparse.Namespace) -> dict:
    """The `dream calibrate` options of `args`, as the fields of its request."""
    from dream.cli.calibrate import CalibrateRequest

    names = {f.name for f in fields(CalibrateRequest)} - set(PER_RECORDING)
    return {k: v for k, v in vars(args).items() if k in names}


def cmd_batch_calibrate(args: argparse.Namespace) -> int:
    from batch.calibrate import batch_output, plan_batch, run_batch
    from batch.engine import make_engine
    from batch.interrupt import sigterm_interrupts
    from batch.progress import BatchProgress
    from batch.summary import FAILED, SUMMARY_CSV, SUMMARY_JSON, summary_counts
    from dream.cli.require import below_required

    engine = make_engine(_engine_settings(args))
    plan = plan_batch(args.data, _out_path(args.out), _calibrate_options(args), args.overlays)
    try:
        engine.start()                  # a cluster that cannot be joined writes nothing
        # after Ray's start, which installs a SIGTERM handler of its own
        with sigterm_interrupts(), batch_output(args.out) as out_dir:
            print(f"batch: {len(plan.tasks)} recordings, {len(plan.rows)} done already (same "
                  f"inputs), {len(plan.todo)} to run on the {engine.describe()}",
                  file=sys.stderr)
            progress = BatchProgress("batch", len(plan.tasks), len(plan.rows), engine.workers)
            try:
                rows = run_batch(plan, out_dir, engine, lambda row: progress.update(
                    failed=row["status"] == FAILED))
            finally:
                progress.close()
                engine.close()          # its workers stopped while --out is still locked
    finally:
        engine.close()                  # (again: nothing left to do when closed above)
    ok, failed = summary_counts(rows)
    print(f"{out_dir}: {ok} calibrated, {failed} failed; {SUMMARY_CSV} and {SUMMARY_JSON} list "
          "them, each recording's folder holds its RESULT.json and calibrate.log")
    for row in rows:
        if row["status"] == FAILED:
            print(f"  {row['name']}: {row['error']}")
    below = [row for row in rows if row["status"] != FAILED
             and below_required(row.get("verdict"), args.require)]
    if below:
        print(f"{len(below)} calibrated below --require {args.require}:")
        for row in below:
            print(f"  {row['name']}: {row['verdict']}")
    return EXIT_SOME_FAILED if failed or below else 0


def _out_path(out: str):
    """`--out`, checked before any recording is read or hashed (a file there is refused)."""
    from dream.io import check_output_folder

    return check_output_folder(out)


def cmd_batch_synth(args: argparse.Namespace) -> int:
    from batch.engine import make_engine
    from batch.interrupt import sigterm_interrupts
    from batch.progress import BatchProgress
    from batch.synth import run_batch_synth
    from synth.cli import job_from, report_done

    engine = make_engine(_engine_settings(args))
    job = job_from(args, engine.workers)
    print(f"batch synth: rendering on the {engine.describe()}", file=sys.stderr)
    progress: list[BatchProgress] = []

    def begin(total: int, already: int) -> None:
        progress.append(BatchProgress("batch synth", total, already, engine.workers,
                                      unit="frames"))

    try:
        engine.start()
        with sigterm_interrupts():      # after Ray's start, as in `cmd_batch_calibrate`
            stats = run_batch_synth(job, engine, overwrite=args.overwrite,
                                    on_progress=lambda n: progress[0].update(n),
                                    on_start=begin)
    finally:
        for p in progress:
            p.close()
        engine.close()
    report_done(args, stats)
    return 0


def _add_engine_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--engine", choices=("local", "ray"), default="local", help=ENGINE_HELP)
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes, one core each (onnxruntime on one thread unless "
                        "--threads) (default: this machine's cores; with --address, the "
                        "cluster's)")
    p.add_argument("--address", metavar="ray://HOST:PORT",
                   help="--engine ray: join this running Ray cluster (default: RAY_ADDRESS "
                        "when set, else a local Ray is started here)")


def register(subparsers: argparse._SubParsersAction) -> None:
    """The `dream batch` parser and its two commands."""
    from dream.cli.calibrate import add_calibrate_args
    from dream.cli.options import add_data_args
    from dream.cli.require import add_require_arg
    from synth.cli import add_synth_args

    help_ = "calibrate many recordings, or render one data set, on a process pool or Ray"
    p = subparsers.add_parser("batch", help=help_, description=help_)
    sub = p.add_subparsers(dest="batch_command", required=True,
                           help="calibrate: many recordings; synth: one data set")
    help_ = "one dream calibrate per recording, with a summary (resumable)"
    c = sub.add_parser("calibrate", help=help_, description=help_)
    add_data_args(c, data_help="the recordings: a glob pattern in quotes ('recordings/*', "
                                 "'**' recurses) or a .txt file with one path per line")
    c.add_argument("--out", required=True,
                   help="output folder: one folder per recording, summary.csv and "
                        "summary.json (a re-run skips what is done)")
    c.add_argument("--overlays", action="store_true",
                   help="draw each recording's overlays into its folder")
    add_require_arg(c, "exit with status 1 where some recording's verdict falls below this "
                       "(as where some failed), naming them")
    _add_engine_args(c)
    add_calibrate_args(c)
    c.set_defaults(func=cmd_batch_calibrate)
    help_ = "dream synth's data set rendered in chunks on the workers (resumable)"
    s = sub.add_parser("synth", help=help_, description=help_)
    add_synth_args(s)
    _add_engine_args(s)
    s.set_defaults(func=cmd_batch_synth)
