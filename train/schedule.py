"""The learning-rate schedule, as a factor of the peak rate (`optim.lr`) per optimiser step, and
its revision when a time-budgeted run re-plans its steps (`train.budget.BudgetStop`).

`lr_factor` is the schedule of a plan fixed from the start: "onecycle" rises linearly over the
first `warmup_fraction` of the steps, then falls along a cosine to `final_fraction`; "cosine" is
the same without the rise; "constant" stays at the peak.

A revision at step `r` to a new total re-plans only the steps from `r` on, from the factor the
schedule had reached there (`revise_segment`), instead of evaluating the formula for the new
total, which would move the rate back up the cosine when the plan grows:

- after the peak, the rest of the cosine, from the phase reached at `r`, is spread over the
  steps left (`r` .. the new total): the rate keeps falling, faster when the plan shrank and
  slower when it grew, and stays at `final_fraction` when the old plan had already ended;
- during the warm-up, the linear rise goes on from the factor reached at `r` to the peak at the
  new plan's warm-up end (at the next step when that end has already passed): a revision can
  stretch or shorten the warm-up, never take the rate above the peak.

A revision to an unchanged total leaves the schedule as it was. `LrSchedule` is the factor
`torch.optim.lr_scheduler.LambdaLR` calls; it keeps its segments as plain numbers, which
LambdaLR saves in the scheduler state, so a resumed run continues the revised schedule.
Everything here is pure (no torch).
"""

from __future__ import annotations

import math
from dataclasses import astuple, dataclass

ONECYCLE, CONSTANT = "onecycle", "constant"   # `train.config.SCHEDULES` ("cosine": no warm-up)
PEAK = 1.0          # the factor at the top of the schedule (the learning rate `optim.lr`)
END_PHASE = 1.0     # the cosine's phase at the end of a plan (0: at the peak)


def warmup_steps(total_steps: int, schedule: str, warmup_fraction: float) -> int:
    """Steps of the linear warm-up of a `total_steps` plan (0 without one)."""
    return int(warmup_fraction * total_steps) if schedule == ONECYCLE else 0


def cosine_factor(phase: float, final_fraction: float) -> float:
    """The factor at `phase` of the cosine decay: the peak at 0, `final_fraction` from 1 on."""
    phase = min(END_PHASE, phase)
    return final_fraction + (PEAK - final_fraction) * 0.5 * (1 + math.cos(math.pi * phase))


def lr_factor(step: int, total_steps: int, schedule: str, warmup_fraction: float,
              final_fraction: float) -> float:
    """Learning rate / peak learning rate at optimiser step `step` of a `total_steps` plan
    (module doc): linear warm-up, then cosine down to `final_fraction`."""
    if schedule == CONSTANT:
        return PEAK
    warmup = warmup_steps(total_steps, schedule, warmup_fraction)
    if step < warmup:
        return (step + 1) / warmup
    return cosine_factor((step - warmup) / max(1, total_steps - warmup), final_fraction)


@dataclass(frozen=True)
class Segment:
    """The schedule from optimiser step `start` on: a linear rise from `start_factor` (at
    `start`) to the peak (at `decay_start - 1`), then the cosine from phase `start_phase` at
    step `decay_start` to its end phase at step `end`. After the peak `decay_start` is `start`
    (no rise)."""

    start: int
    start_factor: float
    decay_start: int
    start_phase: float
    end: int


def first_segment(total_steps: int, schedule: str, warmup_fraction: float) -> Segment:
    """The whole schedule of a `total_steps` plan (the one `lr_factor` gives)."""
    warmup = warmup_steps(total_steps, schedule, warmup_fraction)
    return Segment(0, PEAK / warmup if warmup else PEAK, warmup, 0.0, total_steps)


def segment_phase(segment: Segment, step: int) -> float:
    """The cosine's phase at `step` (>= `segment.decay_start`), at most the end phase."""
    remaining = END_PHASE - segment.start_phase
    done = (step - segment.decay_start) / max(1, segment.end - segment.decay_start)
    return min(END_PHASE, segment.start_phase + remaining * done)


def segment_factor(segment: Segment, step: int, final_fraction: float) -> float:
    """The factor of `segment` at `step` (>= `segment.start`)."""
    if step >= segment.decay_start:
        return cosine_factor(segment_phase(segment, step), final_fraction)
    rise_steps = segment.decay_start - 1 - segment.start   # to the peak, at decay_start - 1
    if rise_steps <= 0:
        return segment.start_factor
    steps_to_peak = segment.decay_start - 1 - step          # 0 gives the peak exactly
    return PEAK - (PEAK - segment.start_factor) * steps_to_peak / rise_steps


def revise_segment(segment: Segment, step: int, total_steps: int, schedule: str,
                   warmup_fraction: float, final_fraction: float) -> Segment:
    """The schedule from `step` on after the plan became `total_steps` steps, continuing
    `segment` from the factor it reached at `step` (module doc)."""
    if step >= segment.decay_start:     # after the peak: the rest of the cosine
        phase = segment_phase(segment, step)
        return Segment(step, cosine_factor(phase, final_fraction), step, phase,
                       max(total_steps, step))
    peak_end = max(warmup_steps(total_steps, schedule, warmup_fraction), step + 1)
    return Segment(step, segment_factor(segment, step, final_fraction), peak_end, 0.0,
                   max(total_steps, peak_end))


class LrSchedule:
    """The factor `LambdaLR` calls per optimiser step, for a plan that may be revised
    (`revise`). Its attributes are plain values: LambdaLR saves them in the scheduler state,
    and a resumed run restores them.

    Args:
        total_steps: the planned optimiser steps.
        schedule, warmup_fraction, final_fraction: `train.config.OptimConfig`'s.
    """

    def __init__(self, total_steps: int, schedule: str, warmup_fraction: float,
                 final_fraction: float):
        self.schedule = schedule
        self.warmup_fraction = warmup_fraction
        self.final_fraction = final_fraction
        # the segments, as tuples of `Segment`'s fields, by increasing start
        self.segments = [astuple(first_segment(total_steps, schedule, warmup_fraction))]

    def _segment_at(self, step: int) -> Segment:
        """The segment that holds `step`: the last one starting at or before it."""
        for fields in reversed(self.segments):
            if fields[0] <= step:
                return Segment(*fields)
        return Segment(*self.segments[0])

    def __call__(self, step: int) -> float:
        if self.schedule == CONSTANT:
            return PEAK
        return segment_factor(self._segment_at(step), step, self.final_fraction)

    def revise(self, step: int, total_steps: int) -> None:
        """The plan became `total_steps` steps at optimiser step `step`: the factors before
        `step` stay, those from `step` on continue from the factor reached there."""
        segment = revise_segment(self._segment_at(step), step, total_steps, self.schedule,
                                 self.warmup_fraction, self.final_fraction)
        self.segments = [s for s in self.segments if s[0] < step] + [astuple(segment)]
