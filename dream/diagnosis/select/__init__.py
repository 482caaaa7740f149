"""Model selection: which effects the data supports, judged on frames held out of the fit.

For the current model (at first the baseline: the extrinsic alone) every remaining effect of the
catalog is added in turn: its identifiable parameters are fitted jointly with the extrinsic and
the accepted effects over all frames, parameter groups that do not differ from zero are pruned,
and the model is cross-validated by frames (interleaved folds). The effect is significant only
when (1) the held-out cost per frame falls with a one-sided paired t-test p-value below
`alpha`, (2) the BIC falls by more than `bic_margin`, and (3) the held-out RMSE falls by at least
`min_relative_gain`. The most helpful significant effect is accepted and the search repeats on
top of it (greedy forward selection), after dropping the accepted effects' groups that it has made
redundant; on data without an effect the verdict is empty.

- `settings`: every constant (`DiagnoseSettings`).
- `crossval`: cross-validation by frames (`Evaluation`, `cross_validate`, `evaluate`).
- `camera_move`: the change frame of a camera move (`best_change`).
- `prune`: one effect added to the current model, its parameter groups pruned (`try_effect`);
  the accepted effects' groups that a later one made redundant, dropped (`prune_accepted`).
- `plausible`: the physical plausibility of fitted parameters (`PLAUSIBLE`, `implausible`).
- `greedy`: the greedy forward selection (`diagnose`, `Diagnosis`, `Verdict`).
"""

from dream.diagnosis.fit.model import param_table, params_of
from dream.diagnosis.select.camera_move import best_change
from dream.diagnosis.select.crossval import Evaluation, cross_validate, evaluate
from dream.diagnosis.select.greedy import (
    Diagnosis,
    Verdict,
    applicable,
    diagnose,
    refit_on_new_mask,
)
from dream.diagnosis.select.plausible import (
    PLAUSIBLE,
    first_implausible,
    implausible,
    implausible_effect,
)
from dream.diagnosis.select.prune import FORWARD_EFFECTS, prune_accepted, try_effect
from dream.diagnosis.select.settings import DiagnoseSettings

__all__ = ["FORWARD_EFFECTS", "PLAUSIBLE", "DiagnoseSettings", "Diagnosis", "Evaluation",
           "Verdict", "applicable", "best_change", "cross_validate", "diagnose", "evaluate",
           "first_implausible", "implausible", "implausible_effect", "param_table", "params_of",
           "prune_accepted", "refit_on_new_mask", "try_effect"]
