"""Joint readings logged slower than the images: a held log found, and interpolated in time.

A joint log that updates at 5 Hz beside a 30 Hz camera gives every frame the latest reading, so
runs of identical readings follow each other while the arm moves on: a frame's joints lag the
arm by up to one log period, and a fixed camera's extrinsic absorbs that as millimetres of
error. `reading_updates` finds the frames where a new reading first appears. A reading was
logged after the last frame that lacks it and at the latest at the first frame that has it.
`update_times` places it in that interval: on the line of a regular log clock where the
updates follow one (a controller logging at a fixed rate: each interval narrows where the
others put the clock), else at the interval's midpoint. `interpolated_joints` interpolates each
joint in time between the readings with a shape-preserving cubic (PCHIP: it does not overshoot
where the arm stops; the last reading is held).

    >>> import numpy as np
    >>> t = np.arange(6) * 0.1
    >>> q = np.array([[0.0], [0.0], [0.0], [0.3], [0.3], [0.3]])
    >>> updates = reading_updates(t, q, HeldReadingsSettings(min_updates=2))
    >>> updates.held, updates.update_index.tolist()
    (True, [0, 3])
    >>> np.round(interpolated_joints(t, q, updates)[:, 0], 3).tolist()
    [0.0, 0.12, 0.24, 0.3, 0.3, 0.3]
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats
from scipy.interpolate import PchipInterpolator

from dream.errors import InputError
from dream.sequence import Sequence

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class HeldReadingsSettings:
    """When a joint log counts as held.

    Attributes:
        min_repeat_fraction: at least this share of the frames repeats the previous frame's
            reading exactly.
        min_updates: and the readings change at least this often (fewer: a static recording,
            whose repeated readings are the truth).
        min_update_spacing: and the median number of frames from one update to the next is
            at least this: a log that updates with every frame while the arm moves repeats
            its readings only where the arm rests (parked before or after a motion), and
            those repeats are the truth.
    """

    min_repeat_fraction: float = 0.5
    min_updates: int = 3
    min_update_spacing: int = 2

    def __post_init__(self) -> None:
        if not 0.0 < self.min_repeat_fraction < 1.0:
            raise InputError(f"min_repeat_fraction must lie in (0, 1), got "
                             f"{self.min_repeat_fraction}")
        if self.min_updates < 2:
            raise InputError(f"min_updates must be >= 2, got {self.min_updates}")
        if self.min_update_spacing < 2:
            raise InputError(f"min_update_spacing must be >= 2 frames, got "
                             f"{self.min_update_spacing}")


@dataclass(frozen=True)
class ReadingUpdates:
    """Where a joint log's readings change.

    Attributes:
        update_index: (U,) the frames where a new reading first appears (frame 0 first).
        repeat_fraction: the share of frames whose reading equals the previous frame's.
        held: the log is held (`HeldReadingsSettings`).
        period_s: the median time between updates, s (None with fewer than 2 updates).
    """

    update_index: np.ndarray
    repeat_fraction: float
    held: bool
    period_s: float | None

    def to_dict(self, interpolated: bool) -> dict[str, Any]:
        """RESULT.json's `joint_readings` (docs/data_format.md#resultjson)."""
        return {"held": self.held, "interpolated": interpolated,
                "updates": int(len(self.update_index)),
                "repeat_fraction": float(self.repeat_fraction),
                "update_period_s": self.period_s}


def _check(timestamps: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(timestamps, dtype=float)
    q = np.asarray(joints, dtype=float)
    if t.ndim != 1 or q.ndim != 2 or len(t) != len(q) or len(t) == 0:
        raise InputError(f"timestamps (F,) and joints (F, J) expected, got {t.shape} and "
                         f"{q.shape}")
    return _check_times(t), q


def _check_times(timestamps: np.ndarray) -> np.ndarray:
    t = np.asarray(timestamps, dtype=float)
    if t.ndim != 1 or len(t) == 0:
        raise InputError(f"timestamps (F,) expected, got {t.shape}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise InputError("timestamps must be finite and in increasing order")
    return t


def reading_updates(timestamps: np.ndarray, joints: np.ndarray,
                    settings: HeldReadingsSettings | None = None) -> ReadingUpdates:
    """The frames where the readings change, and whether the log is held.

    Args:
        timestamps: (F,) frame times, s, increasing.
        joints: (F, J) the reading of every frame.
    """
    settings = settings or HeldReadingsSettings()
    t, q = _check(timestamps, joints)
    repeats = np.all(q[1:] == q[:-1], axis=1)
    update_index = np.concatenate([[0], np.flatnonzero(~repeats) + 1])
    repeat_fraction = float(repeats.mean()) if len(repeats) else 0.0
    held = (repeat_fraction >= settings.min_repeat_fraction
            and len(update_index) >= settings.min_updates
            and np.median(np.diff(update_index)) >= settings.min_update_spacing)
    period = float(np.median(np.diff(t[update_index]))) if len(update_index) > 1 else None
    return ReadingUpdates(update_index, repeat_fraction, bool(held), period)


MIN_CLOCK_UPDATES = 4           # a log clock is fitted to at least this many updates
CLOCK_TOLERANCE_FRACTION = 0.25  # ... and kept when it misses no update's interval by more
                                 # than this fraction of the frame interval (timing jitter)
CLOCK_REFITS = 3                 # fits of the clock, each recounting the updates by the last


def update_times(timestamps: np.ndarray, update_index: np.ndarray,
                 use_clock: bool = True) -> np.ndarray:
    """(U,) the times at which the readings first seen at `update_index` were logged.

    Reading u was logged in (t[i-1], t[i]] with i = update_index[u] (the first frame's at
    the latest at t[0]). Where the updates follow a regular clock s = a + period * n (n: the
    update's count, updates that left the reading unchanged skipped), the least-squares line
    through the intervals' midpoints locates each update to a fraction of a frame interval; it
    is kept when it passes within `CLOCK_TOLERANCE_FRACTION` of a frame interval of every
    interval, and clipped into them; the first frame's reading then sits one period before the
    next update (at most t[0]). Otherwise (or with `use_clock` False) each update sits at its
    interval's midpoint, the first frame's at t[0].

        >>> t = np.arange(12) / 30
        >>> np.round(update_times(t, np.array([0, 3, 6, 9])) * 30, 2).tolist()
        [0.0, 2.5, 5.5, 8.5]
    """
    t, index, lo, hi = _update_intervals(timestamps, update_index)
    mid = np.where(index > 0, 0.5 * (lo + hi), hi)
    later = index > 0
    fitted = log_clock(t, index) if use_clock else None
    if fitted is None:
        return mid
    clock, period = fitted
    out = mid.copy()
    out[later] = np.clip(clock, np.nextafter(lo[later], np.inf), hi[later])  # (t[i-1], t[i]]
    if index[0] == 0:  # the first frame's reading: the tick before the next update, <= t[0]
        out[0] = min(t[0], out[later][0] - period)
    return out


def _update_intervals(timestamps: np.ndarray, update_index: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, index, lo, hi): each update was logged in (lo, hi] = (t[i-1], t[i]], i its frame."""
    t = _check_times(timestamps)
    index = np.asarray(update_index)
    if (index.ndim != 1 or len(index) == 0 or not np.issubdtype(index.dtype, np.integer)
            or index[0] < 0 or index[-1] >= len(t) or np.any(np.diff(index) < 1)):
        raise InputError("update_times needs strictly increasing frame indices (U,) within "
                         "the timestamps")
    return t, index, t[np.maximum(index - 1, 0)], t[index]


def log_clock(timestamps: np.ndarray, update_index: np.ndarray
              ) -> tuple[np.ndarray, float] | None:
    """The regular clock of a log's updates after frame 0 (module doc, `update_times`): its
    time at each of them and its period, s; None where fewer than `MIN_CLOCK_UPDATES` follow
    frame 0 or no clock passes within `CLOCK_TOLERANCE_FRACTION` of a frame interval of every
    update's interval. Its period is not rounded to frames: a 5.36 Hz log beside a 30 Hz
    camera updates every 5 or 6 frames (0.2 s apart in the median), and its clock ticks every
    0.1865 s.

        >>> t = np.arange(300) / 30
        >>> first = np.searchsorted(t, np.arange(0.05, 9.9, 0.1865))   # the frames showing each
        >>> round(log_clock(t, np.concatenate([[0], first]))[1], 3)
        0.186
    """
    t, index, lo, hi = _update_intervals(timestamps, update_index)
    later = index > 0
    if later.sum() < MIN_CLOCK_UPDATES:
        return None
    fitted = _clock_line(0.5 * (lo[later] + hi[later]))
    if fitted is None:
        return None
    clock, period = fitted
    miss = np.maximum(lo[later] - clock, clock - hi[later])
    if np.max(miss) > CLOCK_TOLERANCE_FRACTION * float(np.median(np.diff(t))):
        return None
    return clock, period


def clock_phase_range(timestamps: np.ndarray, update_index: np.ndarray,
                      tail_probability: float | None = None) -> tuple[float, float] | None:
    """(lo, hi), s: the range of the mean time by which `update_times` places a log's updates
    after their true instants, over every regular clock a + P n that passes through each
    update's interval (a linear program in a and P, at the mean count n); None where no clock
    is located or none passes through every interval. A clock whose updates drift through the
    frame interval pins it to a few milliseconds; one whose period is a whole number of frames
    leaves a whole frame interval (the placement at its middle). With a `tail_probability`,
    each interval is first widened on both sides by the frame stamps' own scatter
    (`stamp_jitter`) times the Gaussian quantile that every one of the 2U bounds holds but
    with that probability (U updates): stamps that jitter by a millisecond otherwise give a
    range that misses the true placement in a quarter of the logs.

        >>> t = np.arange(300) / 30
        >>> on_frames = np.arange(6, 300, 6)            # every 6 frames: 0.2 s, phase unknown
        >>> lo, hi = clock_phase_range(t, np.concatenate([[0], on_frames]))
        >>> round(lo * 30, 3), round(hi * 30, 3)
        (-0.5, 0.5)
        >>> drifting = np.searchsorted(t, np.arange(0.05, 9.9, 0.1865))
        >>> lo, hi = clock_phase_range(t, np.concatenate([[0], drifting]))
        >>> bool(hi - lo < 0.0025)                   # 2 ms, against 33 ms above
        True
    """
    from scipy.optimize import linprog

    fitted = log_clock(timestamps, update_index)
    if fitted is None:
        return None
    clock, period = fitted
    _, index, lo, hi = _update_intervals(timestamps, update_index)
    later = index > 0
    count = np.round((clock - clock[0]) / period)   # the clock is clock[0] + period * count
    rows = np.column_stack([np.ones_like(count), count])
    bounds = [(None, None), (None, None)]
    at_mean = np.array([1.0, count.mean()])
    slack = 0.0
    if tail_probability is not None:
        slack = stamp_jitter(timestamps) * float(
            stats.norm.isf(tail_probability / (2 * int(later.sum()))))
    extremes = []
    for sign in (1.0, -1.0):   # min and max of a + P mean(n) with lo < a + P n <= hi
        res = linprog(sign * at_mean, A_ub=np.vstack([rows, -rows]),
                      b_ub=np.concatenate([hi[later] + slack, -lo[later] + slack]),
                      bounds=bounds, method="highs")
        if res.status != 0:
            return None
        extremes.append(sign * res.fun)
    placed = float(clock.mean())   # the fitted clock at the mean count
    return placed - extremes[1], placed - extremes[0]


def stamp_jitter(timestamps: np.ndarray) -> float:
    """The scatter of frame timestamps about a regular frame clock, s: the standard deviation
    of their residuals from the least-squares line against their frame count (a dropped frame
    counted by the median interval); 0 with fewer than 3 frames.

        >>> t = np.arange(300) / 30
        >>> bool(stamp_jitter(t) < 1e-12)
        True
        >>> jittered = t + np.random.default_rng(0).normal(0.0, 0.001, 300)
        >>> round(stamp_jitter(jittered) * 1e3, 1)
        1.0
    """
    t = _check_times(timestamps)
    if len(t) < 3:
        return 0.0
    steps = np.round(np.diff(t) / float(np.median(np.diff(t))))   # 2: a frame dropped
    count = np.concatenate([[0.0], np.cumsum(steps)])
    slope, intercept = np.polyfit(count, t, 1)
    return float(np.std(t - (intercept + slope * count), ddof=2))


def _clock_line(mid: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The regular clock a + period * n fitted to the update intervals' midpoints `mid` (U,):
    (its time at each update's count n, the period); None where the spacing does not fit one.
    Each fit's period recounts the updates that changed nothing (a gap of several periods), so
    a long pause counted from the first, frame-rounded period estimate is corrected."""
    period = float(np.median(np.diff(mid)))
    clock = None
    for _ in range(CLOCK_REFITS):
        if not period > 0:
            return None
        steps = np.round(np.diff(mid) / period)
        if np.any(steps < 1):
            return None
        count = np.concatenate([[0.0], np.cumsum(steps)])
        period, intercept = np.polyfit(count, mid, 1)
        clock = intercept + period * count
    return (clock, float(period)) if period > 0 else None


def interpolated_joints(timestamps: np.ndarray, joints: np.ndarray,
                        updates: ReadingUpdates, use_clock: bool = True) -> np.ndarray:
    """(F, J) every frame's joints interpolated in time between the readings' updates.

    Each reading is placed at its `update_times` time (`use_clock`: on a regular log clock
    where one fits); between them PCHIP interpolates each joint (on rendered trajectories:
    3.7 mm median camera error against 5.2 mm for linear interpolation,
    `benchmarks/held_readings.py`); after the last update the last reading is held.
    """
    t, q = _check(timestamps, joints)
    index = updates.update_index
    if len(index) < 2:
        return q.copy()
    knots = update_times(t, index, use_clock)
    # shape-preserving cubic (no overshoot where the arm stops); linear through two readings
    curve = PchipInterpolator(knots, q[index], axis=0)
    out = curve(np.clip(t, knots[0], knots[-1]))
    out[t >= knots[-1]] = q[index[-1]]   # the last reading held, exactly
    return out


def after_last_update(timestamps: np.ndarray, updates: ReadingUpdates,
                      use_clock: bool = True) -> np.ndarray:
    """(F,) True for the frames after a held log's last update (`update_times`, `use_clock` as
    there): `interpolated_joints` holds the last reading there, which lags the arm by up to one
    update period. All False where the log is not held.

        >>> t = np.arange(8) / 30
        >>> q = np.repeat(np.arange(3.0), 3)[:8, None]      # updates at frames 0, 3, 6
        >>> after_last_update(t, reading_updates(t, q)).tolist()
        [False, False, False, False, False, False, True, True]
    """
    t = _check_times(timestamps)
    if not updates.held or len(updates.update_index) < 2:
        return np.zeros(len(t), bool)
    return t > update_times(t, updates.update_index, use_clock)[-1]


def sequence_updates(sequence: Sequence, settings: HeldReadingsSettings | None = None
                     ) -> ReadingUpdates | None:
    """`reading_updates` of a sequence; None where its frames have no timestamps or are not
    in time order (nothing to tell)."""
    t = sequence.timestamps
    if len(sequence) < 2 or t is None or np.any(np.diff(t) < 0):
        return None
    return reading_updates(t, sequence.joints, settings)


def with_interpolated_readings(sequence: Sequence, settings: HeldReadingsSettings | None = None,
                               use_clock: bool = True
                               ) -> tuple[Sequence, ReadingUpdates | None]:
    """The sequence with held readings interpolated in time (`interpolated_joints`, `use_clock`
    as there), and what was found (`sequence_updates`); the sequence unchanged where its log is
    not held."""
    updates = sequence_updates(sequence, settings)
    if updates is None or not updates.held:
        return sequence, updates
    q = interpolated_joints(sequence.timestamps, sequence.joints, updates, use_clock)
    log.info("joint readings held between %d updates: interpolated in time",
             len(updates.update_index))
    return sequence.with_joints(q), updates


def without_frames_after_last_update(sequence: Sequence, updates: ReadingUpdates | None,
                                     use_clock: bool = True) -> tuple[Sequence, tuple[str, ...]]:
    """The sequence less the frames after its held log's last update (`after_last_update`),
    whose joints are not known, and their names; unchanged where the log is not held."""
    if updates is None or not updates.held:
        return sequence, ()
    # never frame 0: it has the first reading
    late = after_last_update(sequence.timestamps, updates, use_clock)
    names = tuple(f.name for f, drop in zip(sequence.frames, late, strict=True) if drop)
    if names:
        log.info("%d frames after the joint log's last update left out: %s", len(names),
                 ", ".join(names))
    return sequence.subset(~late), names


UPDATE_TIME_TOLERANCE = 1e-9   # of a period


def solved_readings(sequence: Sequence, result: dict[str, Any]) -> Sequence:
    """`sequence` with the joints a RESULT.json document `result` was solved with: where `dream
    calibrate` interpolated a held joint log (`joint_readings.interpolated`), the readings
    interpolated in time and the frames after the log's last update left out."""
    if not (result.get("joint_readings") or {}).get("interpolated"):
        return sequence
    updates = sequence_updates(sequence)
    if updates is None or not updates.held:
        return sequence
    sequence, _ = with_interpolated_readings(sequence)
    return without_frames_after_last_update(sequence, updates)[0]


def held_update_times(times_s: np.ndarray, period_s: float, phase_s: float) -> np.ndarray:
    """(F,) the time of the last update at or before each image time, for a log that updates
    every `period_s`, the first update `phase_s` before the first image."""
    times_s = np.asarray(times_s, dtype=float)
    first = times_s[0] - phase_s
    # an update that falls on an image time shows in that image (rounding aside)
    return first + np.floor((times_s - first) / period_s + UPDATE_TIME_TOLERANCE) * period_s


def held_log(sequence: Sequence, hold_frames: int, rng: np.random.Generator) -> Sequence:
    """The sequence as a log that updates every `hold_frames` frames records it (a simulation
    of a held log, for tests and benchmarks): each reading is sampled from the frames' joints,
    interpolated linearly in time, at a random instant between the frame before its first frame
    and that frame, then held. The frames must have increasing timestamps."""
    if hold_frames < 1:
        raise InputError(f"hold_frames must be >= 1, got {hold_frames}")
    stamps = sequence.timestamps
    if stamps is None:
        raise InputError("a held log needs the frames' timestamps", sequence.source)
    t, q = _check(stamps, sequence.joints)
    starts = np.arange(0, len(q), hold_frames)
    gaps = np.diff(t, prepend=t[0])[starts]
    t_sample = t[starts] - rng.uniform(0.0, 1.0, len(starts)) * gaps
    samples = np.stack([np.interp(t_sample, t, q[:, j]) for j in range(q.shape[1])], axis=1)
    return sequence.with_joints(samples[np.arange(len(q)) // hold_frames])
