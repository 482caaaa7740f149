"""The human report of `dream diagnose`: `report.md` with PNG plots.

`write_report` writes into the report folder (next to `diagnosis.json`, which it does not
touch):

- `report.md`: data summary, baseline and held-out RMSE, the table of effects, the verdict,
  parameters (with uncertainties) of the accepted effects, identifiability notes, the gain,
  highlights of the residual analysis (`dream.diagnose.residuals.analyse`) and the plots.
- `residual_field.png`: residual vectors on the image plane (baseline, and extended).
- `residual_vs_joints.png`: residual magnitude against every joint angle.
- `residual_vs_time.png` (with timestamps): per-frame RMS over time; residual along the
  image velocity against image speed.
- `heldout_gains.png`: held-out RMSE of every effect against the baseline.
- `silhouettes.png` (with silhouette panels): observed vs rendered robot masks.

Every file is written atomically; a plot of a previous run that this run does not produce is
removed, so running twice leaves a consistent folder. Plotting functions are pure (they return
a matplotlib `Figure`); only `write_report` touches the disk.
"""

from __future__ import annotations

import io
import logging
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

matplotlib.use("Agg")  # no display: render to files only (before pyplot is imported)
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from dream.diagnose.residuals import (  # noqa: E402
    ResidualSet,
    analyse_overall,
    analyse_velocity,
    image_velocity,
    per_frame_rms,
)
from dream.errors import InputError  # noqa: E402
from dream.io.atomic import write_bytes_atomic  # noqa: E402
from dream.silhouette import silhouette_iou  # noqa: E402

log = logging.getLogger(__name__)

REPORT_NAME = "report.md"
FIELD_PNG = "residual_field.png"
JOINTS_PNG = "residual_vs_joints.png"
TIME_PNG = "residual_vs_time.png"
GAINS_PNG = "heldout_gains.png"
SILHOUETTES_PNG = "silhouettes.png"
PLOT_FILES = (FIELD_PNG, JOINTS_PNG, TIME_PNG, GAINS_PNG, SILHOUETTES_PNG)

DPI = 100                      # resolution of every PNG
PANEL_IN = 4.0                 # inches per small panel
MAX_ARROWS = 4000              # residual arrows drawn per panel (evenly subsampled beyond)
ARROW_FRACTION = 0.06          # a 95th-percentile residual is drawn this fraction of the diagonal
ARROW_PERCENTILE = 95          # residual percentile that sets the arrow scale
FRAME_MARGIN_FRACTION = 0.05   # blank margin around the image frame in the field plot
JOINT_COLUMNS = 4              # panels per row of the residual-vs-joints plot
JOINT_BINS = 12                # bins of the binned median line in the residual-vs-joints plot
MAX_SILHOUETTE_PANELS = 6      # frames shown in silhouettes.png
OVERLAY_ALPHA = 0.55           # opacity of the mask colours over the image
IMAGE_DIM = 0.6                # the photo is dimmed to this brightness under the overlay
BASELINE_COLOR = "tab:blue"
EXTENDED_COLOR = "tab:orange"
ACCEPTED_COLOR = "tab:green"
EFFECT_COLOR = "lightsteelblue"
BOTH_RGB = (40, 220, 40)       # observed and rendered robot
OBSERVED_ONLY_RGB = (255, 60, 40)
RENDERED_ONLY_RGB = (40, 120, 255)

# Units of the parameters of each effect (SPEC.md vocabulary).
EFFECT_UNITS = {"joint_offset": "rad", "lens_distortion": "", "intrinsics_error": "px",
                "time_offset": "s", "link_length": "m", "keypoint_bias": "m"}


@dataclass(frozen=True, eq=False)
class SilhouettePanel:
    """One frame's observed robot mask against the rendered one, before and after extension.

    Attributes:
        frame: frame name.
        image: (H, W, 3) uint8 RGB photo.
        observed_mask: (H, W) bool, the robot seen in the photo.
        rendered_before: (H, W) bool, the robot rendered by the nominal model.
        rendered_after: (H, W) bool rendered by the extended model, or None.
        iou_before, iou_after: IoU of the observed mask with each rendering (iou_after None
            when there is no `rendered_after`; computed when None and it is given).
    """

    frame: str
    image: np.ndarray
    observed_mask: np.ndarray
    rendered_before: np.ndarray
    rendered_after: np.ndarray | None
    iou_before: float
    iou_after: float | None = None

    def __post_init__(self) -> None:
        image = np.asarray(self.image)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise InputError(f"silhouette panel '{self.frame}': image must be (H, W, 3) uint8, "
                             f"got {image.shape} {image.dtype}", fix="give an RGB uint8 image")
        hw = image.shape[:2]
        for name in ("observed_mask", "rendered_before", "rendered_after"):
            mask = getattr(self, name)
            if mask is None and name == "rendered_after":
                continue
            mask = np.asarray(mask)
            if mask.shape != hw:
                raise InputError(f"silhouette panel '{self.frame}': {name} has shape "
                                 f"{mask.shape}, expected {hw} (the image's)",
                                 fix="render the masks at the image's size")
            object.__setattr__(self, name, mask.astype(bool))
        if self.rendered_after is not None and self.iou_after is None:
            object.__setattr__(self, "iou_after",
                               silhouette_iou(self.observed_mask, self.rendered_after))
        if self.rendered_after is None and self.iou_after is not None:
            raise InputError(f"silhouette panel '{self.frame}': iou_after given without "
                             f"rendered_after", fix="give both or neither")
        for name in ("iou_before", "iou_after"):
            value = getattr(self, name)
            if value is None and name == "iou_after":
                continue
            if not isinstance(value, (int, float, np.floating)) or not 0.0 <= value <= 1.0:
                raise InputError(f"silhouette panel '{self.frame}': {name} = {value!r} is not "
                                 f"in [0, 1]", fix="give the intersection over union")
            object.__setattr__(self, name, float(value))
        object.__setattr__(self, "image", image)


# ---------------------------------------------------------------------------------------------
# Formatting helpers


def _num(x: Any) -> float | None:
    """A finite float, or None (also for text such as a frame name "000012")."""
    if isinstance(x, (bool, str)) or x is None:
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _fmt(x: Any, digits: int = 3) -> str:
    """A number with `digits` significant digits, 'n/a' for missing ones, text as is."""
    v = _num(x)
    if v is None:
        return "n/a" if x is None or isinstance(x, (int, float)) else _cell(str(x))
    if v == 0:
        return "0"
    if abs(v) >= 1e5 or abs(v) < 1e-3:
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}" if abs(v) < 10 ** digits else f"{v:.0f}"


def _fmt_p(p: Any) -> str:
    v = _num(p)
    if v is None:
        return "n/a"
    return "< 1e-12" if v < 1e-12 else _fmt(v, 2)


def _cell(text: Any) -> str:
    """Text safe inside a Markdown table cell."""
    return re.sub(r"\s+", " ", str(text)).replace("|", "\\|").strip()


def _flatten(value: Any, path: tuple = ()) -> list[tuple[tuple, Any]]:
    """Leaves (path, value) of nested dicts / lists of parameters."""
    if isinstance(value, Mapping):
        return [leaf for k, v in value.items() for leaf in _flatten(v, path + (str(k),))]
    if isinstance(value, (list, tuple, np.ndarray)):
        return [leaf for i, v in enumerate(value) for leaf in _flatten(v, path + (i,))]
    return [(path, value)]


def _lookup(value: Any, path: tuple) -> Any:
    """The leaf of nested dicts / lists at `path`, or None."""
    for key in path:
        if isinstance(value, Mapping):
            value = value.get(key)
        elif isinstance(value, (list, tuple, np.ndarray)) and isinstance(key, int) \
                and key < len(value):
            value = value[key]
        else:
            return None
    return value


def _path_name(path: tuple) -> str:
    out = ""
    for key in path:
        out += f"[{key}]" if isinstance(key, int) else (f".{key}" if out else str(key))
    return out or "value"


def _unit(effect: str, path: tuple) -> str:
    if effect == "camera_moved":
        text = " ".join(str(k) for k in path)
        return "rad" if "rotation" in text else ("m" if "translation" in text else "")
    return EFFECT_UNITS.get(effect, "")


def _effects(diagnosis: Mapping) -> list[Mapping]:
    effects = diagnosis.get("effects") or []
    return [e for e in effects if isinstance(e, Mapping)]


def _verdict(diagnosis: Mapping) -> list[str]:
    return [str(v) for v in (diagnosis.get("verdict") or [])]


def _baseline_analysis(analysis: Mapping | None) -> Mapping:
    """The `analyse` result, also when it is given wrapped as {"baseline": {...}}."""
    if not isinstance(analysis, Mapping):
        return {}
    inner = analysis.get("baseline")
    if "overall" not in analysis and isinstance(inner, Mapping) and "overall" in inner:
        return inner
    return analysis


# ---------------------------------------------------------------------------------------------
# Markdown


def _data_summary(res: ResidualSet) -> list[str]:
    cam = res.camera
    observed = int(np.count_nonzero(np.all(np.isfinite(res.uv_observed), -1)))
    lines = [f"- Frames: {len(res.frame_names)} ({res.frame_names[0]} .. {res.frame_names[-1]})",
             f"- Keypoints ({len(res.keypoint_names)}): {', '.join(res.keypoint_names)}",
             f"- Joints ({len(res.joint_names)}): {', '.join(res.joint_names) or 'none'}",
             f"- Observations: {observed} observed, {res.num_used} used by the fit",
             f"- Camera: {cam.width}x{cam.height} px, fx={_fmt(cam.fx, 5)}, "
             f"fy={_fmt(cam.fy, 5)}, cx={_fmt(cam.cx, 5)}, cy={_fmt(cam.cy, 5)} px"
             + ("" if cam.distortion is None else
                f", distortion {', '.join(_fmt(c) for c in cam.distortion)}")]
    if res.times_s is not None:
        t = np.sort(res.times_s)
        span = float(t[-1] - t[0])
        rate = (len(t) - 1) / span if span > 0 else None
        lines.append(f"- Time: {_fmt(span)} s"
                     + (f", {_fmt(rate)} frames/s on average" if rate else ""))
    else:
        lines.append("- Time: no timestamps (time effects not testable)")
    return lines


def _effects_table(diagnosis: Mapping) -> list[str]:
    effects = _effects(diagnosis)
    if not effects:
        return ["No effect was tested."]
    base = _num((diagnosis.get("baseline") or {}).get("heldout_rmse_px"))
    accepted = set(_verdict(diagnosis))
    lines = ["| effect | held-out RMSE (px) | change vs baseline | significant | accepted | "
             "BIC delta | p-value | evidence |",
             "|---|---:|---:|:---:|:---:|---:|---:|---|"]
    for e in effects:
        name = str(e.get("name", "?"))
        h = _num(e.get("heldout_rmse_px"))
        change = "n/a" if h is None or not base else f"{100.0 * (h - base) / base:+.1f} %"
        lines.append(f"| {_cell(name)} | {_fmt(h)} | {change} | "
                     f"{'yes' if e.get('significant') else 'no'} | "
                     f"{'**yes**' if name in accepted else 'no'} | {_fmt(e.get('bic_delta'))} | "
                     f"{_fmt_p(e.get('p_value'))} | {_cell(e.get('evidence', ''))} |")
    return lines


def _parameter_table(diagnosis: Mapping) -> list[str]:
    accepted = _verdict(diagnosis)
    by_name = {str(e.get("name")): e for e in _effects(diagnosis)}
    truth = diagnosis.get("truth") if isinstance(diagnosis.get("truth"), Mapping) else None
    if not accepted:
        return ["No effect accepted: no parameters."]
    head = "| effect | parameter | value | 1-sigma | unit |" + (" truth |" if truth else "")
    lines = [head, "|---|---|---:|---:|---|" + ("---:|" if truth else "")]
    for name in accepted:
        e = by_name.get(name, {})
        params = e.get("params")
        leaves = _flatten(params) if params not in (None, {}) else []
        if not leaves:
            lines.append(f"| {_cell(name)} | (none) | | | |" + (" |" if truth else ""))
        for path, value in leaves:
            sigma = _lookup(e.get("sigma"), path)
            row = (f"| {_cell(name)} | {_cell(_path_name(path))} | {_fmt(value, 4)} | "
                   f"{'n/a' if _num(sigma) is None else _fmt(sigma, 2)} | {_unit(name, path)} |")
            if truth:
                t = _lookup(truth.get(name), path)
                row += f" {'n/a' if t is None else _fmt(t, 4)} |"
            lines.append(row)
    return lines


def _identifiability(diagnosis: Mapping) -> list[str]:
    lines = []
    for e in _effects(diagnosis):
        note = e.get("identifiability")
        if note in (None, "", {}):
            continue
        if isinstance(note, Mapping):
            text = "; ".join(f"{k}: {_fmt(v) if _num(v) is not None else _cell(v)}"
                             for k, v in note.items())
        else:
            text = _cell(note)
        lines.append(f"- **{_cell(e.get('name', '?'))}**: {text}")
    return lines or ["No identifiability notes."]


def _gain(diagnosis: Mapping) -> list[str]:
    gain = diagnosis.get("gain") if isinstance(diagnosis.get("gain"), Mapping) else {}
    before = _num(gain.get("heldout_rmse_px_before"))
    after = _num(gain.get("heldout_rmse_px_after"))
    if before is None or after is None:
        return ["Held-out RMSE gain: n/a."]
    rel = f" ({100.0 * (after - before) / before:+.1f} %)" if before > 0 else ""
    return [f"Held-out RMSE: {_fmt(before)} px (nominal) -> {_fmt(after)} px (extended){rel}."]


def _highlights(analysis: Mapping | None) -> list[str]:
    a = _baseline_analysis(analysis)
    if not a:
        return ["No residual analysis."]
    lines = []
    overall = a.get("overall") or {}
    if overall:
        lines.append(f"- Baseline residuals: RMS {_fmt(overall.get('rms_px'))} px, median |r| "
                     f"{_fmt(overall.get('median_abs_px'))} px over "
                     f"{overall.get('n_used', 'n/a')} used observations.")
    biased = [(k, s) for k, s in (a.get("per_keypoint") or {}).items()
              if isinstance(s, Mapping) and s.get("significant")]
    if biased:
        lines.append("- Keypoints with a significant constant offset: " + ", ".join(
            f"{k} (mean [{', '.join(_fmt(m) for m in (s.get('mean_px') or []))}] px, "
            f"p = {_fmt_p(s.get('p_value_corrected'))})" for k, s in biased) + ".")
    elif a.get("per_keypoint"):
        lines.append("- No keypoint has a significant constant offset.")
    radial = a.get("radial") or {}
    s3, s1 = radial.get("slope_r3") or {}, radial.get("slope_r") or {}
    if s3 or s1:
        lines.append(f"- Radial residual: slope vs r^3 (k1-like) {_fmt(s3.get('slope'))} "
                     f"+/- {_fmt(s3.get('se'), 2)} (p = {_fmt_p(s3.get('p_value'))}); slope vs r "
                     f"(focal-scale-like) {_fmt(s1.get('slope'))} +/- {_fmt(s1.get('se'), 2)} "
                     f"(p = {_fmt_p(s1.get('p_value'))}).")
    joints = {k: s for k, s in (a.get("per_joint") or {}).items() if isinstance(s, Mapping)}
    flagged = [k for k, s in joints.items() if s.get("significant")]
    if flagged:
        lines.append("- Residuals depend on joint(s): " + ", ".join(
            f"{k} (|corr| {_fmt(joints[k].get('max_abs_corr'), 2)} at "
            f"{joints[k].get('keypoint')}.{joints[k].get('component')}, harmonic R^2 "
            f"{_fmt(joints[k].get('harmonic_r2'), 2)})" for k in flagged) + ".")
    elif joints:
        lines.append("- No joint angle explains the residuals significantly.")
    time = a.get("time") or {}
    vel = (time.get("velocity") or {}) if isinstance(time, Mapping) else {}
    if vel:
        lines.append(f"- Residual vs image velocity: coefficient {_fmt(vel.get('coefficient_s'))} "
                     f"+/- {_fmt(vel.get('se_s'), 2)} s (p = {_fmt_p(vel.get('p_value'))}; > 0 "
                     f"means the joint readings lag the images by that much); lag-1 "
                     f"autocorrelation of the per-frame RMS "
                     f"{_fmt(time.get('rms_lag1_autocorr'), 2)}.")
    elif "time" in a:
        lines.append("- No timestamps: no time analysis.")
    cp = a.get("change_point") or {}
    if cp.get("frame") is not None:
        lines.append(f"- Best single step in the residuals: at frame {cp['frame']} (step "
                     f"{_fmt(cp.get('step_px'))} px, explains "
                     f"{_fmt(100 * (_num(cp.get('explained_fraction')) or 0.0), 2)} % of the "
                     f"residual variance, score p = {_fmt_p(cp.get('p_value'))}"
                     f"{', significant' if cp.get('significant') else ''}).")
    return lines or ["No residual analysis."]


PLOT_CAPTIONS = {
    FIELD_PNG: "Residual vectors on the image plane (observed - predicted, scaled)",
    JOINTS_PNG: "Residual magnitude against each joint",
    TIME_PNG: "Residuals over time and against image speed",
    GAINS_PNG: "Held-out RMSE per effect",
    SILHOUETTES_PNG: "Observed vs rendered silhouettes",
}


def report_markdown(diagnosis: Mapping, baseline: ResidualSet, extended: ResidualSet | None,
                    analysis: Mapping | None, plots: Sequence[str] = ()) -> str:
    """The text of `report.md`; `plots` are the PNG file names to link (relative)."""
    base = diagnosis.get("baseline") if isinstance(diagnosis.get("baseline"), Mapping) else {}
    verdict = _verdict(diagnosis)
    md = ["# Sim-to-real diagnosis", "",
          "What the nominal robot-and-camera model gets wrong on this data, tested by "
          "predicting frames held out of the fit.", "",
          "## Data", "", *_data_summary(baseline), "",
          "## Baseline (nominal model)", "",
          f"- RMSE: {_fmt(base.get('rmse_px'))} px",
          f"- Held-out RMSE: {_fmt(base.get('heldout_rmse_px'))} px"]
    if extended is not None:
        md += [f"- Extended model RMSE on the same frames: "
               f"{_fmt(analyse_overall(extended).get('rms_px'))} px"]
    md += [""]
    md += ["## Effects", "", *_effects_table(diagnosis), "",
           "## Verdict", "",
           ("Accepted, strongest first: " + ", ".join(f"**{_cell(v)}**" for v in verdict) + "."
            if verdict else "No effect accepted: the nominal model predicts held-out frames as "
                            "well as any extension."), ""]
    if diagnosis.get("extended_model"):
        md += [f"Extended model: `{diagnosis['extended_model']}`", ""]
    md += ["## Parameters of the accepted effects", "", *_parameter_table(diagnosis), "",
           "## Identifiability", "", *_identifiability(diagnosis), "",
           "## Gain", "", *_gain(diagnosis), "",
           "## Residual analysis", "", *_highlights(analysis), ""]
    notes = [str(n) for n in (diagnosis.get("notes") or [])]
    if notes:
        md += ["## Notes", "", *(f"- {_cell(n)}" for n in notes), ""]
    truth = diagnosis.get("truth")
    if truth and not isinstance(truth, Mapping):
        md += ["## Truth", "", f"`{_cell(truth)}`", ""]
    if plots:
        md += ["## Plots", ""]
        for name in plots:
            caption = PLOT_CAPTIONS.get(name, name)
            md += [f"### {caption}", "", f"![{caption}]({name})", ""]
    return "\n".join(md).rstrip() + "\n"


# ---------------------------------------------------------------------------------------------
# Plots (pure: each returns a Figure)


def _nice(x: float) -> float:
    """1, 2 or 5 times a power of ten, near `x` (> 0)."""
    exp = math.floor(math.log10(x))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10 ** exp >= x * 0.7:
            return m * 10 ** exp
    return 10.0 ** (exp + 1)


def _used(res: ResidualSet) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Used observed points (N, 2), residuals (N, 2), frame (N,) and keypoint (N,) indices."""
    f, k = np.nonzero(res.used)
    return res.uv_observed[f, k], res.residual[f, k], f, k


def _empty(ax: Any, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
    ax.set_xticks([])
    ax.set_yticks([])


def plot_residual_field(baseline: ResidualSet, extended: ResidualSet | None = None) -> Figure:
    """Residual vectors at the observed keypoints on the image plane, one panel per model,
    drawn at one common scale (scale bar in px)."""
    panels = [("baseline", baseline)] + ([("extended", extended)] if extended is not None else [])
    cam = baseline.camera
    mags = np.concatenate([np.hypot(*_used(r)[1].T) for _, r in panels])
    ref = float(np.percentile(mags, ARROW_PERCENTILE)) if mags.size else 0.0
    ref = _nice(ref) if ref > 0 else 1.0
    gain = ARROW_FRACTION * math.hypot(cam.width, cam.height) / ref
    aspect = cam.height / cam.width
    fig, axes = plt.subplots(1, len(panels), squeeze=False,
                             figsize=(PANEL_IN * 1.5 * len(panels), PANEL_IN * 1.5 * aspect + 0.8))
    for ax, (title, res) in zip(axes[0], panels, strict=True):
        uv, r, _, _ = _used(res)
        if len(uv) > MAX_ARROWS:
            pick = np.linspace(0, len(uv) - 1, MAX_ARROWS).astype(int)
            uv, r = uv[pick], r[pick]
        unused = np.all(np.isfinite(res.uv_observed), -1) & ~res.used
        margin = FRAME_MARGIN_FRACTION * max(cam.width, cam.height)
        ax.add_patch(Rectangle((-0.5, -0.5), cam.width, cam.height, fill=False, color="black",
                               linewidth=1.0))
        ax.plot([res.camera.cx], [res.camera.cy], "k+", markersize=10)
        if np.any(unused):
            ax.plot(*res.uv_observed[unused].T, "x", color="0.6", markersize=3, label="outlier")
        if len(uv):
            q = ax.quiver(uv[:, 0], uv[:, 1], gain * r[:, 0], gain * r[:, 1], angles="xy",
                          scale_units="xy", scale=1.0, width=0.003,
                          color=BASELINE_COLOR if title == "baseline" else EXTENDED_COLOR)
            ax.quiverkey(q, 0.85, 1.03, gain * ref, f"{_fmt(ref)} px", labelpos="W",
                         coordinates="axes")
        rms = np.sqrt(np.mean(np.sum(r ** 2, -1))) if len(r) else float("nan")
        ax.set_title(f"{title}: RMS {_fmt(rms)} px", loc="left")
        ax.set_xlim(-0.5 - margin, cam.width - 0.5 + margin)
        ax.set_ylim(cam.height - 0.5 + margin, -0.5 - margin)  # v down
        ax.set_aspect("equal")
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
    fig.tight_layout()
    return fig


def _binned_median(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if len(x) < 2 * JOINT_BINS or np.ptp(x) <= 0:
        return np.zeros(0), np.zeros(0)
    edges = np.linspace(x.min(), x.max(), JOINT_BINS + 1)
    idx = np.clip(np.digitize(x, edges) - 1, 0, JOINT_BINS - 1)
    centres = 0.5 * (edges[:-1] + edges[1:])
    med = np.array([np.median(y[idx == b]) if np.any(idx == b) else np.nan
                    for b in range(JOINT_BINS)])
    ok = np.isfinite(med)
    return centres[ok], med[ok]


def plot_residual_vs_joints(baseline: ResidualSet, extended: ResidualSet | None = None) -> Figure:
    """|residual| of every used keypoint against each joint angle (one panel per joint), with
    the binned median; baseline and extended."""
    J = len(baseline.joint_names)
    cols = max(1, min(JOINT_COLUMNS, J))
    rows = max(1, math.ceil(J / cols))
    fig, axes = plt.subplots(rows, cols, squeeze=False, figsize=(PANEL_IN * cols * 0.8,
                                                                  PANEL_IN * rows * 0.7))
    sets = [("baseline", baseline, BASELINE_COLOR)]
    if extended is not None and extended.joints.shape[1] == J:
        sets.append(("extended", extended, EXTENDED_COLOR))
    for j in range(rows * cols):
        ax = axes.flat[j]
        if j >= J:
            ax.axis("off")
            continue
        for label, res, color in sets:
            _, r, f, _ = _used(res)
            q, mag = res.joints[f, j], np.hypot(r[:, 0], r[:, 1])
            ax.plot(q, mag, ".", color=color, markersize=2, alpha=0.4)
            xb, yb = _binned_median(q, mag)
            ax.plot(xb, yb, "-", color=color, linewidth=1.5, label=f"{label} median")
        ax.set_title(baseline.joint_names[j], fontsize=9)
        ax.set_xlabel("joint (rad)", fontsize=8)
        ax.set_ylabel("|residual| (px)", fontsize=8)
        ax.tick_params(labelsize=7)
    if J == 0:
        _empty(axes[0, 0], "no joints")
    else:
        axes[0, 0].legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return fig


def plot_residual_vs_time(baseline: ResidualSet, extended: ResidualSet | None = None) -> Figure:
    """Per-frame RMS against time (baseline vs extended), and the residual component along
    the image velocity against image speed with the fitted coefficient (see
    `dream.diagnose.residuals.analyse_velocity` for the sign convention)."""
    fig, (ax_t, ax_v) = plt.subplots(1, 2, figsize=(PANEL_IN * 2.4, PANEL_IN * 0.9))
    sets = [("baseline", baseline, BASELINE_COLOR)]
    if extended is not None and extended.times_s is not None:
        sets.append(("extended", extended, EXTENDED_COLOR))
    for label, res, color in sets:
        if res.times_s is None:
            continue
        order = np.argsort(res.times_s, kind="stable")
        t, rms = res.times_s[order], per_frame_rms(res)[order]
        ok = np.isfinite(rms)
        ax_t.plot(t[ok] - baseline.times_s.min(), rms[ok], ".-", color=color, markersize=3,
                  linewidth=0.8, label=label)
        _, r, f, k = _used(res)
        v = image_velocity(res)[f, k]
        good = np.all(np.isfinite(v), -1)
        speed = np.hypot(v[good, 0], v[good, 1])
        moving = speed > 0
        along = np.sum(r[good] * v[good], -1)[moving] / speed[moving]
        ax_v.plot(speed[moving], along, ".", color=color, markersize=2, alpha=0.4)
        coef = analyse_velocity(res)["coefficient_s"]
        if coef is not None and speed.size:
            xs = np.array([0.0, float(speed.max())])
            ax_v.plot(xs, coef * xs, "-", color=color, linewidth=1.5,
                      label=f"{label}: {_fmt(coef)} s")
    ax_t.set_xlabel("time (s)")
    ax_t.set_ylabel("per-frame RMS (px)")
    ax_t.set_title("residual over time", loc="left")
    ax_t.legend(fontsize=8)
    ax_v.axhline(0.0, color="0.5", linewidth=0.8)
    ax_v.set_xlabel("image speed (px/s)")
    ax_v.set_ylabel("residual along velocity (px)")
    ax_v.set_title("residual vs image speed (slope = time offset)", loc="left")
    if ax_v.get_legend_handles_labels()[0]:
        ax_v.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_heldout_gains(diagnosis: Mapping) -> Figure:
    """Horizontal bars: held-out RMSE of the baseline, of every effect (accepted ones
    highlighted) and of the extended model, with the baseline as a dashed line."""
    base = _num((diagnosis.get("baseline") or {}).get("heldout_rmse_px"))
    accepted = set(_verdict(diagnosis))
    labels, values, colors = ["baseline"], [base], ["0.5"]
    for e in _effects(diagnosis):
        name = str(e.get("name", "?"))
        labels.append(name)
        values.append(_num(e.get("heldout_rmse_px")))
        colors.append(ACCEPTED_COLOR if name in accepted else EFFECT_COLOR)
    after = _num((diagnosis.get("gain") or {}).get("heldout_rmse_px_after"))
    if accepted and after is not None:
        labels.append("extended (accepted)")
        values.append(after)
        colors.append(EXTENDED_COLOR)
    fig, ax = plt.subplots(figsize=(PANEL_IN * 1.6, 0.9 + 0.35 * len(labels)))
    y = np.arange(len(labels))[::-1]
    shown = np.array([np.nan if v is None else v for v in values], dtype=float)
    ax.barh(y, np.nan_to_num(shown), color=colors)
    finite = shown[np.isfinite(shown)]
    top = float(finite.max()) if finite.size else 1.0
    for yi, v in zip(y, shown, strict=True):
        ax.text((v if np.isfinite(v) else 0.0) + 0.01 * top, yi,
                _fmt(v) if np.isfinite(v) else "n/a", va="center", fontsize=8)
    if base is not None:
        ax.axvline(base, color="black", linestyle="--", linewidth=1.0)
    ax.set_yticks(y)
    ax.set_yticklabels(labels)
    ax.set_xlim(0, top * 1.15 if top > 0 else 1.0)
    ax.set_xlabel("held-out RMSE (px)")
    ax.set_title("held-out RMSE per effect (green: accepted)", loc="left")
    fig.tight_layout()
    return fig


def silhouette_overlay(image: np.ndarray, observed: np.ndarray,
                       rendered: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: the dimmed photo with both masks coloured: BOTH_RGB where they agree,
    OBSERVED_ONLY_RGB where only the photo has robot, RENDERED_ONLY_RGB where only the model."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"image must be (H, W, 3), got {image.shape}")
    observed = np.asarray(observed, dtype=bool)
    rendered = np.asarray(rendered, dtype=bool)
    if observed.shape != image.shape[:2] or rendered.shape != image.shape[:2]:
        raise InputError(f"masks {observed.shape} and {rendered.shape} do not match the image "
                         f"{image.shape[:2]}")
    out = image.astype(float) * IMAGE_DIM
    for mask, rgb in ((observed & rendered, BOTH_RGB), (observed & ~rendered, OBSERVED_ONLY_RGB),
                      (~observed & rendered, RENDERED_ONLY_RGB)):
        out[mask] = (1 - OVERLAY_ALPHA) * out[mask] + OVERLAY_ALPHA * np.array(rgb, float)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def plot_silhouettes(panels: Sequence[SilhouettePanel]) -> Figure:
    """One row per frame (at most MAX_SILHOUETTE_PANELS): the overlay before, and after when
    some panel has an extended rendering; IoU in the titles."""
    panels = list(panels)[:MAX_SILHOUETTE_PANELS]
    cols = 2 if any(p.rendered_after is not None for p in panels) else 1
    rows = max(1, len(panels))
    h, w = panels[0].image.shape[:2] if panels else (3, 4)
    fig, axes = plt.subplots(rows, cols, squeeze=False,
                             figsize=(PANEL_IN * cols, PANEL_IN * rows * h / w + 0.6))
    for i, p in enumerate(panels):
        views = [("nominal", p.rendered_before, p.iou_before),
                 ("extended", p.rendered_after, p.iou_after)][:cols]
        for ax, (name, rendered, iou) in zip(axes[i], views, strict=True):
            if rendered is None:
                _empty(ax, "no extended rendering")
                continue
            ax.imshow(silhouette_overlay(p.image, p.observed_mask, rendered))
            ax.set_title(f"{p.frame} {name}: IoU {iou:.3f}", fontsize=9)
            ax.axis("off")
    if not panels:
        _empty(axes[0, 0], "no silhouettes")
    fig.suptitle("green: both, red: photo only, blue: model only", fontsize=9)
    fig.tight_layout()
    return fig


# ---------------------------------------------------------------------------------------------
# Writing (the only part that touches the disk)


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
        diagnosis: the diagnosis.json content (SPEC.md); optional keys may be missing.
        baseline: residuals of the nominal model.
        extended: residuals of the extended model on the same frames, or None.
        analysis: `dream.diagnose.residuals.analyse(baseline)` (or {}).
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
