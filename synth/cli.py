"""`dream synth`: registered through the `dream.commands` entry point; imports nothing heavy."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path
from typing import TextIO

PROGRESS_PERIOD_S = 1.0          # a terminal: the progress line is rewritten this often
PIPED_PROGRESS_PERIOD_S = 10.0   # a file or pipe: one whole line this often

log = logging.getLogger(__name__)


class Progress:
    """The command's progress report on stderr (frames, rate, time left), fed by
    `synth.generate.generate`'s `on_start` and `on_progress` callbacks: on a terminal one line
    rewritten in place every `PROGRESS_PERIOD_S`; written to a file or a pipe, a whole line
    every `PIPED_PROGRESS_PERIOD_S` (no carriage returns piling up in one line)."""

    def __init__(self, stream: TextIO | None = None) -> None:
        self.stream = stream or sys.stderr
        isatty = getattr(self.stream, "isatty", None)
        self.interactive = bool(isatty()) if callable(isatty) else False
        self.period_s = PROGRESS_PERIOD_S if self.interactive else PIPED_PROGRESS_PERIOD_S
        self.total = self.done = self.already = 0
        self.start = time.perf_counter()
        self.last = 0.0
        self.open_line = False

    def begin(self, total: int, already: int) -> None:
        self.total, self.done, self.already = total, already, already
        self.start = self.last = time.perf_counter()

    def update(self, n: int) -> None:
        self.done += n
        now = time.perf_counter()
        if now - self.last >= self.period_s or self.done == self.total:
            self.last = now
            rate = (self.done - self.already) / max(now - self.start, 1e-9)
            left = (self.total - self.done) / rate if rate > 0 else float("inf")
            text = (f"synth: {self.done}/{self.total} frames, {rate:.1f} frames/s, "
                    f"{left:.0f} s left")
            if self.interactive:
                print(f"\r{text} ", end="", file=self.stream, flush=True)
                self.open_line = True
                if self.done == self.total:
                    self.close()
            else:
                print(text, file=self.stream, flush=True)

    def close(self) -> None:
        """End the progress line (so that an error message starts a line of its own)."""
        if self.open_line:
            print(file=self.stream, flush=True)
            self.open_line = False


def cmd_synth(args: argparse.Namespace) -> int:
    from synth.generate import CHUNK_FRAMES, generate, worker_count

    job = job_from(args, args.workers)
    workers = worker_count(args.workers, args.num)
    if workers < args.workers:
        print(f"synth: {workers} rendering processes instead of --workers {args.workers} (no more "
              f"than the CPU's {os.cpu_count()} cores or the {args.num} frames' chunks of "
              f"{CHUNK_FRAMES})", file=sys.stderr)
    progress = Progress()
    try:
        stats = generate(job, overwrite=args.overwrite, on_progress=progress.update,
                         on_start=progress.begin)
    finally:
        progress.close()
    report_done(args, stats)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    help_ = "render a domain-randomised synthetic dataset (DREAM layout, with ground truth)"
    p = subparsers.add_parser("synth", help=help_, description=help_)
    add_synth_args(p)
    p.add_argument("--workers", type=int, default=1,
                   help="parallel rendering processes, at most the cores (default: %(default)s)")
    p.set_defaults(func=cmd_synth)


def job_from(args: argparse.Namespace, workers: int):
    """The `SynthJob` of the options of `add_synth_args`, the recipe checked (a note about a
    fixed camera logged)."""
    from synth.camera_note import fixed_camera_note
    from synth.config import load_config
    from synth.generate import SynthJob

    keypoints = None
    if args.keypoints:
        from dream.cli.options import parse_keypoints
        from dream.pipeline import robot_with_option_keypoints

        keypoints = parse_keypoints(args.keypoints)
        robot_with_option_keypoints(args.robot, keypoints)   # a link the URDF lacks: one line
    extension = None
    if args.model_extension:
        from dream.extension import read_extension

        extension = read_extension(args.model_extension)
    config = load_config(args.config, args.set)
    note = fixed_camera_note(config, args.config, args.set)
    if note:
        log.warning(note)
    if args.contact_sheet and not args.contact_sheet.lower().endswith(".png"):
        from dream.errors import InputError

        raise InputError("the contact sheet is written as PNG", args.contact_sheet,
                         "give --contact-sheet a file name ending in .png")
    return SynthJob(robot=args.robot, out_dir=Path(args.out), num_frames=args.num,
                    config=config, seed=args.seed, keypoints=keypoints, workers=workers,
                    extension=extension)


def report_done(args: argparse.Namespace, stats: dict) -> None:
    """The closing lines of a synth run (and the contact sheet, when asked for)."""
    print(f"{args.out}: {stats['rendered']} frames rendered, {stats['skipped']} already there, "
          f"{stats['frames_per_s']:.1f} frames/s")
    if args.contact_sheet:
        from synth.contact_sheet import write_contact_sheet

        print(f"contact sheet: {write_contact_sheet(args.out, args.contact_sheet)}")


def add_synth_args(p: argparse.ArgumentParser) -> None:
    """The options of `dream synth` besides `--workers` (`dream batch synth` shares them)."""
    p.add_argument("--robot", required=True, help="built-in robot name or URDF path")
    p.add_argument("--keypoints", help="comma-separated link names (required for a URDF path)")
    p.add_argument("--num", type=int, required=True, help="number of frames")
    p.add_argument("--out", required=True, help="output folder (resumed when it exists)")
    p.add_argument("--config", help="YAML recipe (default: configs/synth/default.yaml values)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a recipe key (repeatable), e.g. camera.radius_m=[1.0,1.5]")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed: each frame depends only on it and its index (default: "
                        "%(default)s)")
    p.add_argument("--model-extension", metavar="FILE",
                   help="render the world this model extension describes (YAML of dream "
                        "diagnose: joint_offset, link_length, lens_distortion, "
                        "intrinsics_error, keypoint_bias; time_offset and camera_moved in "
                        "sequence modes) and write the nominal joints and camera")
    p.add_argument("--contact-sheet", metavar="FILE.png",
                   help="after rendering, write the first 16 frames side by side with their "
                        "keypoint labels (to judge a recipe by eye)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a folder made with other settings")
