"""The joint log's lag behind the images, read off the robot's silhouettes.

A joint log stamped by another clock than the camera's (a driver's latency, a second machine)
shows the arm where it was some milliseconds before or after each image. A still arm does not
care; a moving one is drawn behind (or ahead of) itself along its motion, and the search's pose
takes up what it can of the difference: on renders of smooth 30 frames/s trajectories, readings
50 ms late left the search 15-344 mm off (median 82 mm) where it is 0.3-9 mm on time.

At the search's winner the silhouettes are compared with the masks with the readings
interpolated at each image time plus a lag (`dream.extended.effective_joints`: the state at
image time t is the reading stamped t + lag, the `time_offset` convention) over a grid of lags;
where the best lag fits clearly better than the readings as stamped, the search runs again from
the winner with the readings shifted by it, and the lag is read again there, until it stays.
It is read also where the winner fails the search's found test: a log late enough can keep
the right pose's silhouettes below it (on a trajectory render with readings 50 ms late, IoU
0.36 at 0.25 m off, 0.71 at 5 mm once the lag was read).
A pose error cannot mimic a lag: it moves the silhouettes alike whichever way the arm moves.

Frames without timestamps, or whose timestamps do not increase strictly, are not examined
(`SearchMasks.timing` None). The last frames, whose image time plus the lag lies beyond the
log, keep its last reading.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from dream.errors import InputError
from dream.extended import interpolate_joints
from dream.quality import CHECK, Finding
from dream.settings_checks import check_fields

if TYPE_CHECKING:
    from dream.coarse.calibration import MarkStart, SearchMasks
    from dream.coarse.search import Winner
    from dream.coarse.settings import SearchSettings
    from dream.robot import Robot
    from dream.sequence import Sequence


@dataclass(frozen=True)
class TimingSettings:
    """How the lag is read (module doc).

    Attributes:
        fit: read the lag at all (False: the readings as stamped).
        max_lag_s: the lags tried lie within this of 0 (s).
        step_s: the grid of lags tried (s); the best is refined between its neighbours.
        min_gain: the mean IoU at the best lag must exceed the IoU with the readings as
            stamped by this to adopt a lag (on renders of 30 frames/s trajectories: lag-free,
            the best lag lay within 0.5 ms of 0, gaining nothing; readings 50 ms late gained
            0.016 at the first winner, 0.15 at the truth).
        resolution_s: once a lag is adopted, the searches again go on until the next step
            (`read_lag`) is below this (or `rounds` ran).
        rounds: at most this many searches again with a new lag.
        sigma_fraction: an adopted lag's 1-sigma, of the lag (or the last round's gap between
            the lag read and the lag in use, where larger), whose effect on the pose enters its
            covariance (`LagEstimate.pose_covariance`; set on renders of 30 frames/s
            trajectories with readings 50 ms late: the lags adopted lay 5 ms short to 2 ms long).
    """

    fit: bool = True
    max_lag_s: float = 0.3
    step_s: float = 0.02
    min_gain: float = 0.005
    resolution_s: float = 0.002
    rounds: int = 4
    sigma_fraction: float = 0.15

    def __post_init__(self) -> None:
        check_fields(self, "timing", positive=("max_lag_s", "step_s", "min_gain",
                                               "resolution_s", "sigma_fraction"),
                     positive_ints=("rounds",))
        if self.step_s > self.max_lag_s:
            raise InputError(f"timing: step_s {self.step_s} exceeds max_lag_s {self.max_lag_s}")


@dataclass(frozen=True)
class LagEstimate:
    """The lag found (module doc): `seconds` (0 where none was adopted), the mean IoU with the
    readings as stamped and at the lag adopted (at the last winner), the last profile read
    (`lags_s`, `ious`), the searches run again, why, and where adopted its 1-sigma and the
    pose's change per second of lag (`xi_per_second`, `dream.pnp` increments: between the
    first winner and the last)."""

    seconds: float
    iou_as_stamped: float
    iou_at_lag: float
    lags_s: np.ndarray
    ious: np.ndarray
    rounds: int
    reason: str
    sigma_s: float = 0.0
    xi_per_second: np.ndarray = field(default_factory=lambda: np.zeros(6))

    @property
    def adopted(self) -> bool:
        return self.seconds != 0.0

    @property
    def pose_covariance(self) -> np.ndarray:
        """(6, 6) what the adopted lag's uncertainty adds to the pose's covariance."""
        return self.sigma_s ** 2 * np.outer(self.xi_per_second, self.xi_per_second)

    def to_dict(self) -> dict:
        return {"seconds": self.seconds, "adopted": self.adopted, "sigma_s": self.sigma_s,
                "iou_as_stamped": self.iou_as_stamped, "iou_at_lag": self.iou_at_lag,
                "lags_s": self.lags_s.tolist(), "ious": self.ious.tolist(),
                "xi_per_second": self.xi_per_second.tolist(), "rounds": self.rounds,
                "reason": self.reason}


def best_lag(lags_s: np.ndarray, ious: np.ndarray) -> float:
    """The lag of the largest IoU, refined by the parabola through it and its neighbours.

    >>> lags = np.array([-0.04, -0.02, 0.0, 0.02, 0.04])
    >>> round(best_lag(lags, 1 - (lags - 0.025) ** 2), 4)
    0.025
    """
    k = int(np.argmax(ious))
    if k == 0 or k == len(ious) - 1:
        return float(lags_s[k])
    left, mid, right = ious[k - 1], ious[k], ious[k + 1]
    curvature = left - 2 * mid + right
    offset = 0.0 if curvature >= 0 else 0.5 * (left - right) / curvature
    return float(lags_s[k] + offset * (lags_s[k + 1] - lags_s[k]))


def lag_profile(iou_at: Callable[[float], float], settings: TimingSettings
                ) -> tuple[np.ndarray, np.ndarray]:
    """(lags (n,), mean IoUs (n,)) over the grid of `settings`; `iou_at(lag)`: the IoU of the
    silhouettes with the readings shifted by `lag`."""
    half = int(round(settings.max_lag_s / settings.step_s))
    lags = np.arange(-half, half + 1) * settings.step_s
    return lags, np.array([iou_at(float(lag)) for lag in lags])


def shifted_joints(joints: np.ndarray, times_s: np.ndarray, lag_s: float,
                   frames: np.ndarray | None = None) -> np.ndarray:
    """(F, J) the readings at each image time plus `lag_s`, interpolated through every frame's
    reading (`dream.extended.interpolate_joints`: a repeated reading is the arm at rest, as
    the readings are taken, not a stale copy), held beyond the first and the last; at 0 the
    readings as they are; `frames`: those frames' rows only. `times_s` must increase strictly
    (`Sequence.increasing_timestamps`)."""
    t = np.asarray(times_s, float)
    return interpolate_joints(t, np.asarray(joints, float),
                              (t if frames is None else t[frames]) + lag_s)


def read_lag(iou_at: Callable[[float], float], search_from: Callable[[float], None],
             settings: TimingSettings, say: Callable[[str], None]) -> LagEstimate:
    """The lag (module doc): `iou_at(lag)` scores the current winner with the readings shifted
    by `lag`; `search_from(lag)` searches again with them and makes its winner the current one.

    The pose found with a lag takes up part of what remains of it, so the lag read at a winner
    lies between the one in use and the true one; the lags in use and read are extrapolated to
    where they agree (the secant method on read - in use), and searched again there, until
    that step is below `resolution_s` (where the pose takes up most of the lag, the lag read
    lies within the resolution of the one in use while the true one is several times as far:
    on renders a stop at that gap left the lag 7 ms short)."""
    in_use, previous, rounds = 0.0, None, 0
    while True:
        lags, ious = lag_profile(iou_at, settings)
        read = best_lag(lags, ious)
        here, there = iou_at(in_use), iou_at(read)
        following = _extrapolated(in_use, read, previous, settings.max_lag_s)
        if (not rounds and there - here < settings.min_gain) \
                or abs(following - in_use) < settings.resolution_s:
            reason = (f"the readings fit best {1000 * read:+.1f} ms from their stamps, the "
                      f"lag in use {1000 * in_use:+.1f} ms (IoU {here:.3f} -> {there:.3f})")
            break
        if rounds == settings.rounds:
            reason = (f"{rounds} searches again, the last with the readings "
                      f"{1000 * in_use:+.0f} ms on")
            break
        say(f"timing: the joint readings fit the images best {1000 * read:+.0f} ms from their "
            f"stamps (IoU {here:.3f} -> {there:.3f}): searching again with them "
            f"{1000 * following:+.0f} ms on")
        previous, in_use, rounds = (in_use, read - in_use), following, rounds + 1
        search_from(in_use)
    if rounds and iou_at(in_use) - iou_at(0.0) < settings.min_gain:   # noise stepped away
        reason, in_use = f"{reason}; the stamps fit as well at the last winner: none adopted", 0.0
    sigma = max(settings.sigma_fraction * abs(in_use), abs(read - in_use)) if in_use else 0.0
    return LagEstimate(in_use, iou_at(0.0), iou_at(in_use), lags, ious, rounds, reason, sigma)


def _extrapolated(in_use: float, read: float, previous: tuple[float, float] | None,
                  most: float) -> float:
    """The next lag to search with: where read - in use reaches 0 on the line through this
    round's and the previous round's (`previous`: its lag in use and read - in use), within
    `most`; the lag read where there is no previous round or the line does not cross ahead.
    (Not bounded by a multiple of the gap: a pose that takes up most of the lag needs steps
    of several gaps; bounded at 3 gaps, a trajectory render's search ended at 37 ms, 127 mm
    off, where the unbounded steps reached 52 ms, 19 mm off.)"""
    gap = read - in_use
    if previous is None or previous[1] == gap:
        return read
    step = -gap * (in_use - previous[0]) / (gap - previous[1])
    following = in_use + step
    ahead = np.sign(step) == np.sign(gap)
    return float(following) if ahead and abs(following) <= most else read


def with_lag(sequence: Sequence, lag_s: float) -> Sequence:
    """`sequence` with every frame's readings shifted by the lag a search adopted
    (`LagEstimate.seconds`; `shifted_joints`), so that what runs after the search draws the
    arm as it saw it; unchanged at 0."""
    if lag_s == 0.0 or len(sequence) < 2:    # one frame: its reading is all there is
        return sequence
    t = sequence.increasing_timestamps
    if t is None:
        raise InputError(f"a lag of {1000 * lag_s:.0f} ms to apply, but the frames' timestamps "
                         "are missing or do not increase", sequence.source,
                         "give the recording the search was run on")
    return sequence.with_joints(shifted_joints(sequence.joints, t, lag_s))


def lag_applied(sequence: Sequence, robot: Robot, estimate: LagEstimate | None,
                marked: MarkStart | None) -> tuple[Sequence, MarkStart | None]:
    """The sequence with the lag a search adopted applied (`with_lag`), so that what runs
    after the search draws the arm as it found it, and the mark's clicked points at the
    shifted readings (its clicks are checked at the pose found); both as given where no lag
    was adopted."""
    from dream.coarse.mark import clicked_points
    from dream.pipeline import joints_in_robot_order

    if estimate is None or not estimate.adopted:
        return sequence, marked
    sequence = with_lag(sequence, estimate.seconds)
    if marked is not None:
        marked = replace(marked, P_clicked_base=clicked_points(
            robot, joints_in_robot_order(sequence, robot), marked.mark))
    return sequence, marked


def timing_finding(timing: dict | None) -> Finding | None:
    """The verdict's timing finding of RESULT.json's `start.timing` (`LagEstimate.to_dict`):
    `check` where a lag was adopted.

    >>> timing_finding({"adopted": True, "seconds": 0.05, "iou_as_stamped": 0.6,
    ...                 "iou_at_lag": 0.75})[0]
    'check'
    >>> timing_finding({"adopted": False, "seconds": 0.0}) is None
    True
    """
    if timing is None or not timing["adopted"]:
        return None
    ms = 1000 * timing["seconds"]
    return CHECK, (f"the joint log's stamps run {abs(ms):.0f} ms {'late' if ms > 0 else 'early'} "
                   f"against the images' (the silhouettes' IoU {timing['iou_as_stamped']:.2f} "
                   f"-> {timing['iou_at_lag']:.2f} with the readings "
                   f"{'taken' if ms > 0 else 'given'} {abs(ms):.0f} ms earlier): the pose was "
                   "found with them corrected; stamp the images and the joint log by one clock "
                   "(or synchronise the clocks), or check the overlays")


def with_timing(sequence: Sequence, joints: np.ndarray, inputs: SearchMasks, winner: Winner,
                settings: SearchSettings, timing: TimingSettings,
                again: Callable[[SearchMasks, Winner], Winner], held: bool,
                progress: Callable[[str], None] | None = None) -> tuple[Winner, SearchMasks]:
    """The lag read at the winner (`read_lag`) in the inputs (`SearchMasks.timing`), their
    joints shifted by it, and the winner of the last search again (the first where none ran);
    `joints`: (F, J) every frame's readings in the robot's order; `again(inputs, winner)`: the
    search again from the winner with those inputs; `held`: motion masks (`pose_iou`).
    Unchanged without timestamps or with `timing.fit` off."""
    from dream.coarse.search import pose_iou
    from dream.pnp import increment_between

    t = sequence.increasing_timestamps
    if not timing.fit or t is None:
        return winner, inputs
    state = {"winner": winner, "inputs": inputs}
    found = [(0.0, winner.best.T_cam_base)]            # (lag, winner's pose) of each search
    scored: dict[float, float] = {}                    # IoU by lag at the current winner

    def at(lag: float) -> np.ndarray:
        return shifted_joints(joints, t, lag, inputs.frames)

    def iou_at(lag: float) -> float:
        if lag not in scored:
            scored[lag] = pose_iou(inputs.meshes, at(lag), inputs.masks, sequence.camera,
                                   state["winner"].best.T_cam_base, settings, held)
        return scored[lag]

    def search_from(lag: float) -> None:
        state["inputs"] = replace(state["inputs"], joints=at(lag))
        state["winner"] = again(state["inputs"], state["winner"])
        found.append((lag, state["winner"].best.T_cam_base))
        scored.clear()

    estimate = read_lag(iou_at, search_from, timing, progress or (lambda line: None))
    if not estimate.adopted:              # the first winner stands
        return winner, replace(inputs, timing=estimate)
    (lag_a, T_a), (lag_b, T_b) = found[0], found[-1]
    estimate = replace(estimate, xi_per_second=increment_between(T_b, T_a) / (lag_a - lag_b))
    return state["winner"], replace(state["inputs"], timing=estimate)
