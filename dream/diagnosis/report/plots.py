"""The plots of the report, one PNG file each; pure: each function returns a matplotlib `Figure`.

- `residual_field.png`: residual vectors on the image plane (baseline, and extended).
- `residual_vs_joints.png`: residual magnitude against every joint angle.
- `residual_vs_time.png` (with timestamps): per-frame RMS over time; residual along the
  image velocity against image speed.
- `heldout_gains.png`: held-out RMSE of every effect against the baseline.
- `silhouettes.png` (with silhouette panels, `dream.diagnosis.report.silhouettes`): observed vs
  rendered robot masks.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import matplotlib
import numpy as np

matplotlib.use("Agg")  # no display: render to files only (before pyplot is imported)
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from dream.diagnosis.report.format import effect_entries, fmt, num, verdict_names  # noqa: E402
from dream.diagnosis.residuals.residual_set import (  # noqa: E402
    ResidualSet,
    image_velocity,
    per_frame_rms,
)
from dream.diagnosis.residuals.temporal import analyse_velocity  # noqa: E402

FIELD_PNG = "residual_field.png"
JOINTS_PNG = "residual_vs_joints.png"
TIME_PNG = "residual_vs_time.png"
GAINS_PNG = "heldout_gains.png"
SILHOUETTES_PNG = "silhouettes.png"
PLOT_FILES = (FIELD_PNG, JOINTS_PNG, TIME_PNG, GAINS_PNG, SILHOUETTES_PNG)

PANEL_IN = 4.0                 # inches per small panel
MAX_ARROWS = 4000              # residual arrows drawn per panel (evenly subsampled beyond)
ARROW_FRACTION = 0.06          # a 95th-percentile residual is drawn this fraction of the diagonal
ARROW_PERCENTILE = 95          # residual percentile that sets the arrow scale
FRAME_MARGIN_FRACTION = 0.05   # blank margin around the image frame in the field plot
JOINT_COLUMNS = 4              # panels per row of the residual-vs-joints plot
JOINT_BINS = 12                # bins of the binned median line in the residual-vs-joints plot
BASELINE_COLOR = "tab:blue"
EXTENDED_COLOR = "tab:orange"
ACCEPTED_COLOR = "tab:green"
EFFECT_COLOR = "lightsteelblue"

PLOT_CAPTIONS = {
    FIELD_PNG: "Residual vectors on the image plane (observed - predicted, scaled)",
    JOINTS_PNG: "Residual magnitude against each joint",
    TIME_PNG: "Residuals over time and against image speed",
    GAINS_PNG: "Held-out RMSE per effect",
    SILHOUETTES_PNG: "Observed vs rendered silhouettes",
}


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


def empty_panel(ax: Any, text: str) -> None:
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
            ax.quiverkey(q, 0.85, 1.03, gain * ref, f"{fmt(ref)} px", labelpos="W",
                         coordinates="axes")
        rms = np.sqrt(np.mean(np.sum(r ** 2, -1))) if len(r) else float("nan")
        ax.set_title(f"{title}: RMS {fmt(rms)} px", loc="left")
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
        empty_panel(axes[0, 0], "no joints")
    else:
        axes[0, 0].legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return fig


def plot_residual_vs_time(baseline: ResidualSet, extended: ResidualSet | None = None) -> Figure:
    """Per-frame RMS against time (baseline vs extended), and the residual component along
    the image velocity against image speed with the fitted coefficient (see
    `dream.diagnosis.residuals.analyse_velocity` for the sign convention)."""
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
                      label=f"{label}: {fmt(coef)} s")
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
    base = num((diagnosis.get("baseline") or {}).get("heldout_rmse_px"))
    accepted = set(verdict_names(diagnosis))
    labels, values, colors = ["baseline"], [base], ["0.5"]
    for e in effect_entries(diagnosis):
        name = str(e.get("name", "?"))
        labels.append(name)
        values.append(num(e.get("heldout_rmse_px")))
        colors.append(ACCEPTED_COLOR if name in accepted else EFFECT_COLOR)
    after = num((diagnosis.get("gain") or {}).get("heldout_rmse_px_after"))
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
                fmt(v) if np.isfinite(v) else "n/a", va="center", fontsize=8)
    if base is not None:
        ax.axvline(base, color="black", linestyle="--", linewidth=1.0)
    ax.set_yticks(y)
    ax.set_yticklabels(labels)
    ax.set_xlim(0, top * 1.15 if top > 0 else 1.0)
    ax.set_xlabel("held-out RMSE (px)")
    ax.set_title("held-out RMSE per effect (green: accepted)", loc="left")
    fig.tight_layout()
    return fig
