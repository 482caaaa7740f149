"""`dream batch synth`: one synthetic data set rendered in chunks of frames on an engine's
workers (`batch.engine`), into one folder on storage every worker sees.

The folder, its settings and its resumption are `synth.generate`'s: a frame exists once its
JSON is written (last, atomically), and every frame depends only on the seed and its index, so
the frames are byte-identical to a one-process `dream synth` of the same seed, and a killed
batch resumes with the frames still missing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from batch.engine import WorkerLost
from dream.errors import DreamError


def render_on(engine, job) -> Callable[[list[int], Callable[[int], None]], None]:
    """A `synth.generate` runner that renders the missing frames on `engine`."""
    from synth.generate import chunks, render_chunk, worker_setup

    def runner(todo: list[int], report: Callable[[int], None]) -> None:
        runs = list(chunks(todo))
        for i, value in engine.run(render_chunk, runs, setup=worker_setup, setup_args=(job,)):
            if isinstance(value, WorkerLost):
                raise DreamError(f"frames {runs[i][0]}-{runs[i][-1]} were not rendered: "
                                 f"{value.message}. Fix: run the same command again to resume")
            report(len(value))

    return runner


def run_batch_synth(job, engine, overwrite: bool = False,
                    on_progress: Callable[[int], None] | None = None,
                    on_start: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Render `job` (a `synth.generate.SynthJob`) on `engine`; returns `generate`'s counts."""
    from synth.generate import generate

    return generate(job, overwrite=overwrite, on_progress=on_progress, on_start=on_start,
                    runner=render_on(engine, job))
