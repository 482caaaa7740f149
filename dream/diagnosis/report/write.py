"""Writing the report folder: `report.md` and its PNG plots (the only part of the report that
touches the disk).

Every file is written atomically; a plot of a previous run that this run does not produce is
removed, so running twice leaves a consistent folder. `diagnosis.json` is not touched.
"""

from __future__ import annotations

import io
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

from matplotlib.figure import Figure

from dream.diagnosis.report.markdown import report_markdown
from dream.diagnosis.report.plots import (
    FIELD_PNG,
    GAINS_PNG,
    JOINTS_PNG,
    PLOT_FILES,
    SILHOUETTES_PNG,
    TIME_PNG,
    plot_heldout_gains,
    plot_residual_field,
    plot_residual_vs_joints,
    plot_residual_vs_time,
    plt,
)
from dream.diagnosis.report.silhouettes import SilhouettePanel, plot_silhouettes
from dream.diagnosis.residuals.residual_set import ResidualSet
from dream.errors import InputError
from dream.io.atomic import write_bytes_atomic

log = logging.getLogger(__name__)

REPORT_NAME = "report.md"
DPI = 100                      # resolution of every PNG


def _png_bytes(fig: Figure) -> bytes:
    """The figure as PNG bytes; the figure is closed."""
    try:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=DPI)
        return buf.getvalue()
    finally:
        plt.close(fig)


def write_report(report_dir: Path, diagnosis: dict, baseline: ResidualSet,
                 extended: ResidualSet | None, analysis: dict,
                 silhouettes: Sequence[SilhouettePanel] = ()) -> Path:
    """Write `report.md` and its PNG plots into `report_dir` (created if needed).

    Args:
        report_dir: the report folder (`dream diagnose --out`).
        diagnosis: the diagnosis.json content (docs/data_format.md); optional keys may be missing.
        baseline: residuals of the nominal model.
        extended: residuals of the extended model on the same frames, or None.
        analysis: `dream.diagnosis.residuals.analyse(baseline)` (or {}).
        silhouettes: frames to show as silhouette overlays (may be empty).
    Returns:
        The path of report.md.
    Raises:
        InputError: a bad argument, or the folder cannot be written.
    """
    report_dir = Path(report_dir)
    if not isinstance(diagnosis, Mapping):
        raise InputError(f"diagnosis must be a dict, got {type(diagnosis).__name__}",
                         fix="pass the content of diagnosis.json")
    if not isinstance(baseline, ResidualSet) or \
            (extended is not None and not isinstance(extended, ResidualSet)):
        raise InputError("baseline (and extended) must be ResidualSets")
    silhouettes = list(silhouettes or ())
    if not all(isinstance(p, SilhouettePanel) for p in silhouettes):
        raise InputError("silhouettes must be SilhouettePanels")
    try:
        report_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the report folder ({exc.strerror})", report_dir,
                         "choose a writable folder") from None
    figures = [(FIELD_PNG, lambda: plot_residual_field(baseline, extended)),
               (JOINTS_PNG, lambda: plot_residual_vs_joints(baseline, extended))]
    if baseline.times_s is not None:
        figures.append((TIME_PNG, lambda: plot_residual_vs_time(baseline, extended)))
    figures.append((GAINS_PNG, lambda: plot_heldout_gains(diagnosis)))
    if silhouettes:
        figures.append((SILHOUETTES_PNG, lambda: plot_silhouettes(silhouettes)))
    written = []
    for name, make in figures:
        write_bytes_atomic(report_dir / name, _png_bytes(make()))
        written.append(name)
    for name in PLOT_FILES:   # a plot of an earlier run that this one does not make
        stale = report_dir / name
        if name not in written and stale.is_file():
            stale.unlink()
    text = report_markdown(diagnosis, baseline, extended, analysis, written)
    path = write_bytes_atomic(report_dir / REPORT_NAME, text.encode("utf-8"))
    log.info("wrote the diagnosis report %s with %d plots", path, len(written))
    return path
