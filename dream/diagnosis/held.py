"""Held joint readings in a diagnosis: found in the data, corrected before the model search.

A joint log that updates slower than the camera repeats its last reading between updates (runs
of identical readings while the images change). That is seen in the data itself, not fitted:
the diagnosis names it `held_readings` (its period and the held joints), interpolates the
readings in time between their updates (`dream.readings.interpolated_joints`), leaves out the
keypoints of the frames after the last update (their joints are not known), as `dream
calibrate` does, and searches the catalog on the corrected readings. A constant lag of the
updates behind the images is then `time_offset` on top of it, so held readings are never
reported as a time offset.

Each update is placed in the frame interval where it first appears (`update_times`): where the
log's clock drifts through the frame interval, the intervals together pin the true instants to
a few milliseconds (each interval widened by the frame stamps' own scatter, so that stamps
that jitter do not pin it falsely); where its period is a whole number of frames, every update
keeps the same unknown place in its interval, and the placement may be off by up to half a
frame interval.
Within the range the intervals allow (`sampling_phase_range`), a lag is that sampling phase
(`HeldReadings.phase_s`), which the data cannot tell from a time offset. So is a fitted lag just
outside it, where the part outside is not significant: its chi-square test against zero (with
the fit's sigma) has a p-value above `group_alpha`, the test every parameter group of an
effect must pass (`DiagnoseSettings`). A lag outside it by more is a time offset whose 1-sigma
includes the range's spread (its width / sqrt(12)).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from scipy import stats

from dream.diagnosis.fit import Problem
from dream.extended import effective_joints, interpolated_frames
from dream.extension import HeldReadings
from dream.readings import clock_phase_range, log_clock, reading_updates


def held_readings_in(problem: Problem) -> HeldReadings | None:
    """The held readings the data shows (None without timestamps or runs of repeats):
    the period between updates (the log clock's, `dream.readings.log_clock`, where the updates
    follow one: not rounded to frames) and the held joints (empty: all)."""
    if problem.times_s is None:
        return None
    updates = reading_updates(problem.times_s, problem.joints)
    names = problem.robot.joint_names
    held = [n for j, n in enumerate(names)
            if reading_updates(problem.times_s, problem.joints[:, [j]]).held]
    if not held or updates.period_s is None:
        return None
    clock = log_clock(problem.times_s, updates.update_index)
    period = updates.period_s if clock is None else clock[1]
    return HeldReadings(period, () if len(held) == len(names) else tuple(held))


def corrected_problem(problem: Problem, held: HeldReadings) -> Problem:
    """The problem with the held readings interpolated in time between their updates, and the
    keypoints of the frames after the log's last update unobserved: their joints are the last
    reading, which lags the arm by up to one period (`dream.extended.interpolated_frames`)."""
    names = problem.robot.joint_names
    joints = effective_joints(problem.joints, problem.times_s, None, held, names)
    known = interpolated_frames(problem.joints, problem.times_s, None, held, names)
    uv = problem.uv.copy()
    uv[~known] = np.nan
    return dataclasses.replace(problem, joints=joints, uv=uv)


def held_entry(problem: Problem, held: HeldReadings, logged_rmse_px: float,
               corrected_rmse_px: float) -> dict[str, Any]:
    """diagnosis.json's `effects` entry of held readings: the data's evidence and the held-out
    RMSE of the baseline with the readings as logged and interpolated."""
    updates = reading_updates(problem.times_s, problem.joints)
    return {"name": "held_readings", "significant": True, "round": 0,
            "params": {"period_s": held.period_s, "joints": list(held.joints),
                       "phase_s": held.phase_s},
            "evidence": (f"{len(updates.update_index)} reading updates in "
                         f"{problem.num_frames} frames, one every {held.period_s:.3f} s "
                         f"({updates.repeat_fraction:.0%} of the frames repeat the previous "
                         f"reading); held-out RMSE {logged_rmse_px:.3f} px as logged, "
                         f"{corrected_rmse_px:.3f} px interpolated between the updates"),
            "heldout_rmse_px": corrected_rmse_px,
            "heldout_rmse_px_as_logged": logged_rmse_px,
            "from_data": True,
            "frames_per_update": float(np.diff(updates.update_index).mean())
            if len(updates.update_index) > 1 else None}


def sampling_phase_range(problem: Problem, frame_interval_s: float,
                         tail_probability: float) -> tuple[float, float]:
    """(lo, hi), s: the lags that the held log's sampling phase may cause (module doc):
    `dream.readings.clock_phase_range` where the updates follow a clock through every
    interval (each widened by the frame stamps' scatter, but with `tail_probability`), else
    half a frame interval either way."""
    updates = reading_updates(problem.times_s, problem.joints)
    located = clock_phase_range(problem.times_s, updates.update_index, tail_probability)
    return located if located is not None else (-frame_interval_s / 2, frame_interval_s / 2)


def fold_sampling_phase(doc: dict[str, Any], held: HeldReadings,
                        phase_range: tuple[float, float], group_alpha: float) -> HeldReadings:
    """Move an accepted time offset that the sampling phase's `phase_range` (s,
    `sampling_phase_range`) explains out of `doc`'s verdict and into the held readings' phase
    (returned); widen a lag beyond it by the range's spread (module doc)."""
    entry = next((e for e in doc["effects"] if e["name"] == "time_offset"
                  and "time_offset" in doc["verdict"]), None)
    if entry is None:
        return held
    seconds = float(entry["params"]["seconds"])
    sigma = entry.get("sigma") or {}
    lo, hi = phase_range
    p_outside = outside_p_value(seconds, phase_range, sigma.get("seconds"))
    if p_outside > group_alpha:
        doc["verdict"].remove("time_offset")
        where = ("within" if lo <= seconds <= hi else "not significantly beyond (the part "
                 f"outside against zero: p = {p_outside:.2g})")
        doc["notes"].append(f"a lag of {seconds * 1e3:.1f} ms, {where} the {lo * 1e3:.1f} to "
                            f"{hi * 1e3:.1f} ms that the log's update times leave open, is the "
                            "held readings' sampling phase, not a time offset")
        return dataclasses.replace(held, phase_s=seconds)
    spread = (hi - lo) / np.sqrt(12.0)
    sigma["seconds"] = float(np.hypot(sigma.get("seconds") or 0.0, spread))
    entry["sigma"] = sigma
    entry["evidence"] = (f"{entry.get('evidence', '')}; 1-sigma includes the held updates' "
                         f"unknown sampling phase ({spread * 1e3:.1f} ms)")
    return held


def outside_p_value(seconds: float, phase_range: tuple[float, float],
                    sigma_s: float | None) -> float:
    """The two-sided p-value of the part of a fitted lag `seconds` outside `phase_range`
    (s) against zero, with the fit's 1-sigma `sigma_s` (s): 1 inside the range; without a
    finite positive sigma, 0 outside it.

        >>> round(outside_p_value(-0.0173, (-1 / 60, 1 / 60), 0.0006), 2)   # 1.06 sigma out
        0.29
        >>> outside_p_value(-0.025, (-1 / 60, 1 / 60), 0.0006) < 1e-9
        True
    """
    lo, hi = phase_range
    outside = max(lo - seconds, seconds - hi, 0.0)
    if outside == 0.0:
        return 1.0
    if sigma_s is None or not np.isfinite(sigma_s) or sigma_s <= 0.0:
        return 0.0
    return float(2.0 * stats.norm.sf(outside / sigma_s))
