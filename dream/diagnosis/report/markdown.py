"""The text of `report.md`: data summary, baseline and held-out RMSE, the table of effects, the
verdict, parameters (with uncertainties) of the accepted effects, identifiability notes, the
gain, highlights of the residual analysis (`dream.diagnosis.residuals.analyse`) and the plots."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from dream.diagnosis.report.format import cell, effect_entries, fmt, fmt_p, num, verdict_names
from dream.diagnosis.report.plots import PLOT_CAPTIONS
from dream.diagnosis.residuals.image import analyse_overall
from dream.diagnosis.residuals.residual_set import ResidualSet

# Units of the parameters of each effect (extended_model.yaml's vocabulary, docs/data_format.md)
EFFECT_UNITS = {"joint_offset": "rad", "lens_distortion": "", "intrinsics_error": "px",
                "time_offset": "s", "link_length": "m", "keypoint_bias": "m",
                "link_geometry": "m"}


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


def _baseline_analysis(analysis: Mapping | None) -> Mapping:
    """The `analyse` result, also when it is given wrapped as {"baseline": {...}}."""
    if not isinstance(analysis, Mapping):
        return {}
    inner = analysis.get("baseline")
    if "overall" not in analysis and isinstance(inner, Mapping) and "overall" in inner:
        return inner
    return analysis


def _data_summary(res: ResidualSet) -> list[str]:
    cam = res.camera
    observed = int(np.count_nonzero(np.all(np.isfinite(res.uv_observed), -1)))
    lines = [f"- Frames: {len(res.frame_names)} ({res.frame_names[0]} .. {res.frame_names[-1]})",
             f"- Keypoints ({len(res.keypoint_names)}): {', '.join(res.keypoint_names)}",
             f"- Joints ({len(res.joint_names)}): {', '.join(res.joint_names) or 'none'}",
             f"- Observations: {observed} observed, {res.num_used} used by the fit",
             f"- Camera: {cam.width}x{cam.height} px, fx={fmt(cam.fx, 5)}, "
             f"fy={fmt(cam.fy, 5)}, cx={fmt(cam.cx, 5)}, cy={fmt(cam.cy, 5)} px"
             + ("" if cam.distortion is None else
                f", distortion {', '.join(fmt(c) for c in cam.distortion)}")]
    if res.times_s is not None:
        t = np.sort(res.times_s)
        span = float(t[-1] - t[0])
        rate = (len(t) - 1) / span if span > 0 else None
        lines.append(f"- Time: {fmt(span)} s"
                     + (f", {fmt(rate)} frames/s on average" if rate else ""))
    else:
        lines.append("- Time: no timestamps (time effects not testable)")
    return lines


def _effects_table(diagnosis: Mapping) -> list[str]:
    effects = effect_entries(diagnosis)
    if not effects:
        return ["No effect was tested."]
    base = num((diagnosis.get("baseline") or {}).get("heldout_rmse_px"))
    accepted = set(verdict_names(diagnosis))
    lines = ["| effect | held-out RMSE (px) | change vs baseline | significant | accepted | "
             "BIC delta | p-value | evidence |",
             "|---|---:|---:|:---:|:---:|---:|---:|---|"]
    for e in effects:
        name = str(e.get("name", "?"))
        h = num(e.get("heldout_rmse_px"))
        change = "n/a" if h is None or not base else f"{100.0 * (h - base) / base:+.1f} %"
        lines.append(f"| {cell(name)} | {fmt(h)} | {change} | "
                     f"{'yes' if e.get('significant') else 'no'} | "
                     f"{'**yes**' if name in accepted else 'no'} | {fmt(e.get('bic_delta'))} | "
                     f"{fmt_p(e.get('p_value'))} | {cell(e.get('evidence', ''))} |")
    return lines


def _image_finding(diagnosis: Mapping, name: str) -> dict:
    """An effect found in the images (`image_findings`), as an effect entry: per link, the
    shape's parameters without the carving's evidence."""
    found = (diagnosis.get("image_findings") or {}).get(name) or {}
    shape = ("size_m", "position_m", "scale")
    return {"params": {link: {k: v for k, v in params.items() if k in shape}
                       for link, params in found.items() if isinstance(params, Mapping)}}


def _parameter_table(diagnosis: Mapping) -> list[str]:
    accepted = verdict_names(diagnosis)
    by_name = {str(e.get("name")): e for e in effect_entries(diagnosis)}
    truth = diagnosis.get("truth") if isinstance(diagnosis.get("truth"), Mapping) else None
    if not accepted:
        return ["No effect accepted: no parameters."]
    head = "| effect | parameter | value | 1-sigma | unit |" + (" truth |" if truth else "")
    lines = [head, "|---|---|---:|---:|---|" + ("---:|" if truth else "")]
    for name in accepted:
        e = by_name.get(name) or _image_finding(diagnosis, name)
        params = e.get("params")
        leaves = _flatten(params) if params not in (None, {}) else []
        if not leaves:
            lines.append(f"| {cell(name)} | (none) | | | |" + (" |" if truth else ""))
        for path, value in leaves:
            sigma = _lookup(e.get("sigma"), path)
            row = (f"| {cell(name)} | {cell(_path_name(path))} | {fmt(value, 4)} | "
                   f"{'n/a' if num(sigma) is None else fmt(sigma, 2)} | {_unit(name, path)} |")
            if truth:
                t = _lookup(truth.get(name), path)
                row += f" {'n/a' if t is None else fmt(t, 4)} |"
            lines.append(row)
    return lines


def _identifiability(diagnosis: Mapping) -> list[str]:
    lines = []
    for e in effect_entries(diagnosis):
        note = e.get("identifiability")
        if note in (None, "", {}):
            continue
        if isinstance(note, Mapping):
            text = "; ".join(f"{k}: {fmt(v) if num(v) is not None else cell(v)}"
                             for k, v in note.items())
        else:
            text = cell(note)
        lines.append(f"- **{cell(e.get('name', '?'))}**: {text}")
    return lines or ["No identifiability notes."]


def _gain(diagnosis: Mapping) -> list[str]:
    gain = diagnosis.get("gain") if isinstance(diagnosis.get("gain"), Mapping) else {}
    before = num(gain.get("heldout_rmse_px_before"))
    after = num(gain.get("heldout_rmse_px_after"))
    if before is None or after is None:
        return ["Held-out RMSE gain: n/a."]
    rel = f" ({100.0 * (after - before) / before:+.1f} %)" if before > 0 else ""
    lines = [f"Held-out RMSE: {fmt(before)} px (nominal) -> {fmt(after)} px (extended){rel}."]
    remaining = diagnosis.get("remaining") if isinstance(diagnosis.get("remaining"),
                                                         Mapping) else {}
    share = num(remaining.get("unexplained_share"))
    if share is not None:
        lines += ["", f"Unexplained: {100 * share:.0f} % of the baseline's held-out mean "
                      f"squared error. The remaining misfit looks like "
                      f"{cell(remaining.get('looks_like', ''))}."]
    truth = diagnosis.get("truth") if isinstance(diagnosis.get("truth"), Mapping) else {}
    if truth.get("before") and truth.get("after"):
        lines += ["", "Against the data's reference extrinsic: camera position "
                      f"{fmt(1e3 * truth['before']['translation_error_m'])} mm (nominal) -> "
                      f"{fmt(1e3 * truth['after']['translation_error_m'])} mm (extended)."]
    return lines


def _highlights(analysis: Mapping | None) -> list[str]:
    a = _baseline_analysis(analysis)
    if not a:
        return ["No residual analysis."]
    lines = []
    overall = a.get("overall") or {}
    if overall:
        lines.append(f"- Baseline residuals: RMS {fmt(overall.get('rms_px'))} px, median |r| "
                     f"{fmt(overall.get('median_abs_px'))} px over "
                     f"{overall.get('n_used', 'n/a')} used observations.")
    biased = [(k, s) for k, s in (a.get("per_keypoint") or {}).items()
              if isinstance(s, Mapping) and s.get("significant")]
    if biased:
        lines.append("- Keypoints with a significant constant offset: " + ", ".join(
            f"{k} (mean [{', '.join(fmt(m) for m in (s.get('mean_px') or []))}] px, "
            f"p = {fmt_p(s.get('p_value_corrected'))})" for k, s in biased) + ".")
    elif a.get("per_keypoint"):
        lines.append("- No keypoint has a significant constant offset.")
    radial = a.get("radial") or {}
    s3, s1 = radial.get("slope_r3") or {}, radial.get("slope_r") or {}
    if s3 or s1:
        lines.append(f"- Radial residual: slope vs r^3 (k1-like) {fmt(s3.get('slope'))} "
                     f"+/- {fmt(s3.get('se'), 2)} (p = {fmt_p(s3.get('p_value'))}); slope vs r "
                     f"(focal-scale-like) {fmt(s1.get('slope'))} +/- {fmt(s1.get('se'), 2)} "
                     f"(p = {fmt_p(s1.get('p_value'))}).")
    joints = {k: s for k, s in (a.get("per_joint") or {}).items() if isinstance(s, Mapping)}
    flagged = [k for k, s in joints.items() if s.get("significant")]
    if flagged:
        lines.append("- Residuals depend on joint(s): " + ", ".join(
            f"{k} (|corr| {fmt(joints[k].get('max_abs_corr'), 2)} at "
            f"{joints[k].get('keypoint')}.{joints[k].get('component')}, harmonic R^2 "
            f"{fmt(joints[k].get('harmonic_r2'), 2)})" for k in flagged) + ".")
    elif joints:
        lines.append("- No joint angle explains the residuals significantly.")
    time = a.get("time") or {}
    vel = (time.get("velocity") or {}) if isinstance(time, Mapping) else {}
    if vel:
        lines.append(f"- Residual vs image velocity: coefficient {fmt(vel.get('coefficient_s'))} "
                     f"+/- {fmt(vel.get('se_s'), 2)} s (p = {fmt_p(vel.get('p_value'))}; > 0 "
                     f"means the joint readings lag the images by that much); lag-1 "
                     f"autocorrelation of the per-frame RMS "
                     f"{fmt(time.get('rms_lag1_autocorr'), 2)}.")
    elif "time" in a:
        lines.append("- No timestamps: no time analysis.")
    cp = a.get("change_point") or {}
    if cp.get("frame") is not None:
        null = str(cp.get("null") or "")
        left = ("that the arm's pose leaves" if null == "joints" else
                f"(tested against constant residuals: {null.partition(': ')[2]})")
        sparse = cp.get("against_constant") or []
        if sparse:
            left += f"; {', '.join(sparse)} seen in too few frames, against their constant"
        verdict = (", significant: the camera moved there, or the observations changed"
                   if cp.get("significant") else "")
        lines.append(f"- Best single step in the residuals: at frame {cp['frame']} (step "
                     f"{fmt(cp.get('step_px'))} px, explains "
                     f"{fmt(100 * (num(cp.get('explained_fraction')) or 0.0), 2)} % of the "
                     f"residual variance {left}, score p = {fmt_p(cp.get('p_value'))}"
                     f"{verdict}).")
    return lines or ["No residual analysis."]


def report_markdown(diagnosis: Mapping, baseline: ResidualSet, extended: ResidualSet | None,
                    analysis: Mapping | None, plots: Sequence[str] = ()) -> str:
    """The text of `report.md`; `plots` are the PNG file names to link (relative)."""
    base = diagnosis.get("baseline") if isinstance(diagnosis.get("baseline"), Mapping) else {}
    verdict = verdict_names(diagnosis)
    md = ["# Sim-to-real diagnosis", "",
          "What the nominal robot-and-camera model gets wrong on this data, tested by "
          "predicting frames held out of the fit.", "",
          "## Data", "", *_data_summary(baseline), "",
          "## Baseline (nominal model)", "",
          f"- RMSE: {fmt(base.get('rmse_px'))} px",
          f"- Held-out RMSE: {fmt(base.get('heldout_rmse_px'))} px"]
    if extended is not None:
        md += [f"- Extended model RMSE on the same frames: "
               f"{fmt(analyse_overall(extended).get('rms_px'))} px"]
    md += [""]
    md += ["## Effects", "", *_effects_table(diagnosis), "",
           "## Verdict", "",
           ("Accepted, strongest first: " + ", ".join(f"**{cell(v)}**" for v in verdict) + "."
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
        md += ["## Notes", "", *(f"- {cell(n)}" for n in notes), ""]
    truth = diagnosis.get("truth")
    if truth and not isinstance(truth, Mapping):
        md += ["## Truth", "", f"`{cell(truth)}`", ""]
    if plots:
        md += ["## Plots", ""]
        for name in plots:
            caption = PLOT_CAPTIONS.get(name, name)
            md += [f"### {caption}", "", f"![{caption}]({name})", ""]
    return "\n".join(md).rstrip() + "\n"
