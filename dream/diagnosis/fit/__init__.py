"""Joint fit of the extrinsic and a set of model effects over all frames.

The model predicts every observed keypoint of every frame:

    uv[f, k] = project(camera(theta), T_f(xi, theta) @ P_base[f, k](theta))

with `xi` the extrinsic's increment on a starting pose (the same convention as `dream.pnp`) and
`theta` the parameters of the effects (`dream.extension`).

- `problem`: the measured data (`Problem`) and the effects' parameters (`Param`,
  `candidate_params`, `build_extension`).
- `model`: the prediction and its finite-difference Jacobian (`Model`), and `fit_model`, which
  minimises a Huber cost of the pixel residuals and returns the parameters, their covariance
  and the residuals (`FitResult`).
- `identify`: `identifiable_params` drops parameters the data cannot tell apart from the
  extrinsic (or from each other); `group_p_values` tests parameter groups against zero, so that
  those that do not differ significantly can be pruned; `undetermined_covariance` adds to the
  stated uncertainty what the parameters held at zero (dropped) may be.
"""

from dream.diagnosis.fit.identify import (
    Identifiability,
    group_p_values,
    identifiable_params,
    undetermined_covariance,
)
from dream.diagnosis.fit.model import FitResult, Model, fit_model
from dream.diagnosis.fit.problem import (
    POINT_EFFECTS,
    VIEW_EFFECTS,
    Param,
    Problem,
    build_extension,
    candidate_params,
    offset_joints,
)

__all__ = ["POINT_EFFECTS", "VIEW_EFFECTS", "FitResult", "Identifiability", "Model", "Param",
           "Problem", "build_extension", "candidate_params", "fit_model", "group_p_values",
           "identifiable_params", "offset_joints", "undetermined_covariance"]
