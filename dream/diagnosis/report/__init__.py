"""The human report of `dream diagnose`: `report.md` with PNG plots.

`write_report` writes into the report folder (next to `diagnosis.json`, which it does not
touch):

- `report.md` (`markdown`): data summary, baseline and held-out RMSE, the table of effects, the
  verdict, parameters (with uncertainties) of the accepted effects, identifiability notes, the
  gain, highlights of the residual analysis (`dream.diagnosis.residuals.analyse`) and the plots.
- `residual_field.png`, `residual_vs_joints.png`, `residual_vs_time.png` (with timestamps),
  `heldout_gains.png` (`plots`): the residuals on the image plane, against the joints and over
  time, and the held-out RMSE of every effect.
- `silhouettes.png` (`silhouettes`, with silhouette panels): observed vs rendered robot masks.

Every file is written atomically (`write`); a plot of a previous run that this run does not
produce is removed, so running twice leaves a consistent folder. Plotting functions are pure
(they return a matplotlib `Figure`); only `write_report` touches the disk.
"""

from dream.diagnosis.report.markdown import EFFECT_UNITS, report_markdown
from dream.diagnosis.report.plots import (
    FIELD_PNG,
    GAINS_PNG,
    JOINTS_PNG,
    PLOT_CAPTIONS,
    PLOT_FILES,
    SILHOUETTES_PNG,
    TIME_PNG,
    plot_heldout_gains,
    plot_residual_field,
    plot_residual_vs_joints,
    plot_residual_vs_time,
)
from dream.diagnosis.report.silhouettes import SilhouettePanel, plot_silhouettes, silhouette_overlay
from dream.diagnosis.report.write import DPI, REPORT_NAME, write_report

__all__ = ["DPI", "EFFECT_UNITS", "FIELD_PNG", "GAINS_PNG", "JOINTS_PNG", "PLOT_CAPTIONS",
           "PLOT_FILES", "REPORT_NAME", "SILHOUETTES_PNG", "TIME_PNG", "SilhouettePanel",
           "plot_heldout_gains", "plot_residual_field", "plot_residual_vs_joints",
           "plot_residual_vs_time", "plot_silhouettes", "report_markdown", "silhouette_overlay",
           "write_report"]
