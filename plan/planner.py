"""Planning the robot poses to record: valid candidates, a D-optimal choice, a short path.

    candidates = find_candidates(robot, prior, feasibility, settings)   # MuJoCo checks
    plan = choose_poses(robot, prior, candidates, settings)             # pure

Candidates are joint vectors drawn uniformly inside the joint ranges that pass every check of
`plan.feasibility` with the stated camera. The chosen set maximises the mean log det of the
extrinsic's information over camera poses drawn from the stated uncertainty
(`plan.design`), and is put in an order that shortens the path from the start configuration.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from dream.errors import InputError
from dream.plausibility import check_robot_joints
from dream.robot import Robot
from dream.settings_checks import check_fields
from plan.camera_prior import CameraPrior
from plan.design import information_table, predicted_sigmas, select_d_optimal
from plan.feasibility import Feasibility, PoseCheck, PoseChecker, keypoints_in_view
from plan.ordering import order_clear_moves, order_poses, path_length

logger = logging.getLogger(__name__)

DRAW_BATCH = 2000         # joint vectors drawn and screened for view at once
LIMIT_TOLERANCE = 1e-9    # a range this far outside the URDF limits still counts as inside
RANDOM_SETS = 50          # random valid sets whose predicted sigma the plan is compared with


@dataclass(frozen=True)
class PlanSettings:
    """How to plan. Pixels, counts.

    Attributes:
        num_poses: poses in the plan.
        candidates: valid poses to choose from.
        max_draws: joint vectors drawn at most while looking for them.
        camera_samples: camera poses drawn from the stated uncertainty (the first is the
            stated one) over which the criterion is averaged.
        noise_px: the expected keypoint noise (1-sigma per pixel coordinate).
        restarts: extra greedy selections from random first poses.
        seed: random seed of the draws.
    """

    num_poses: int = 12
    candidates: int = 600
    max_draws: int = 60000
    camera_samples: int = 16
    noise_px: float = 1.0
    restarts: int = 4
    seed: int = 0

    def __post_init__(self) -> None:
        check_fields(self, "plan", positive_ints=("num_poses", "candidates", "max_draws",
                                                  "camera_samples"),
                     positive=("noise_px",), non_negative=("restarts", "seed"))
        if self.num_poses > self.candidates:
            raise InputError(f"{self.num_poses} poses cannot be chosen from {self.candidates} "
                             "candidates", fix="ask for more --candidates than --num poses")


@dataclass(frozen=True, eq=False)
class Candidates:
    """Valid poses found: `joints` (N, J) and their checks; `draws` examined and why the others
    failed (check name -> count); the `checker` that checked them (moves between the chosen
    poses are checked with it)."""

    joints: np.ndarray
    checks: tuple[PoseCheck, ...]
    draws: int
    failures: Mapping[str, int] = field(default_factory=dict)
    checker: PoseChecker | None = field(default=None, repr=False)

    def describe_failures(self) -> str:
        return ", ".join(f"{n} {why}" for why, n in Counter(self.failures).most_common()) \
            or "none"


@dataclass(frozen=True, eq=False)
class Plan:
    """The chosen poses in visiting order, with what they predict.

    Attributes:
        joints: (N, J) configurations, rad or m, in `robot.joint_names` order.
        checks: each pose's `PoseCheck`.
        predicted: `plan.design.predicted_sigmas` of the set at the stated camera.
        random_predicted: the median over random valid sets of the same size of their
            worst-direction camera-position and rotation 1-sigma.
        path_length: joint-space length of the path from `start` (without one: from the
            first pose).
        start: (J,) the start configuration given, or None (the path then begins at the pose
            nearest the robot's rest configuration).
        candidates: the candidate search it chose from.
        move_clearance_m: (N,) the least clearance along each straight joint-space move of
            the path (from the start first, when one was given;
            `PoseChecker.motion_clearance`), None: unchecked.
    """

    joints: np.ndarray
    checks: tuple[PoseCheck, ...]
    predicted: dict
    random_predicted: dict
    path_length: float
    start: np.ndarray | None
    candidates: Candidates
    move_clearance_m: np.ndarray | None = None


def joint_ranges(robot: Robot, ranges: Mapping[str, tuple[float, float]] | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) (J,) of the robot's joints: the URDF limits, narrowed by `ranges`
    (joint name -> (low, high), rad or m), which must lie inside them."""
    lower, upper = robot.joint_lower.copy(), robot.joint_upper.copy()
    for name, (low, high) in (ranges or {}).items():
        if name not in robot.joint_names:
            raise InputError(f"robot '{robot.name}' has no joint '{name}'",
                             fix=f"name one of {', '.join(robot.joint_names)}")
        j = robot.joint_names.index(name)
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise InputError(f"joint range {name}={low}:{high} must be two finite values, low "
                             "before high", fix="give e.g. --joint-range panda_joint1=-1.5:1.5")
        if low < lower[j] - LIMIT_TOLERANCE or high > upper[j] + LIMIT_TOLERANCE:
            raise InputError(f"joint range {name}={low:g}:{high:g} lies outside the URDF "
                             f"limits {lower[j]:g}:{upper[j]:g} (rad or m)",
                             fix="narrow the range to within the limits (radians, not degrees)")
        lower[j], upper[j] = low, high
    return lower, upper


def find_candidates(robot: Robot, prior: CameraPrior, feasibility: Feasibility,
                    settings: PlanSettings, ranges: tuple[np.ndarray, np.ndarray],
                    progress: Callable[[int, int], None] | None = None) -> Candidates:
    """Up to `settings.candidates` valid poses drawn uniformly within `ranges` (lower, upper).

    Raises:
        InputError: no drawn pose keeps every keypoint in view of the stated camera.
    """
    rng = np.random.default_rng(settings.seed)
    checker = PoseChecker(robot, feasibility, prior.camera, prior.T_cam_base)
    found, checks, failures, draws = [], [], Counter(), 0
    ever_seen = np.zeros(robot.num_keypoints, bool)
    while len(found) < settings.candidates and draws < settings.max_draws:
        batch = rng.uniform(*ranges, size=(min(DRAW_BATCH, settings.max_draws - draws),
                                            robot.num_joints))
        each = keypoints_in_view(robot.forward_kinematics(batch), prior.camera,
                                 prior.T_cam_base, feasibility.margin_px)
        ever_seen |= each.any(axis=0)
        seen = each.all(axis=1)
        for i, q in enumerate(batch):
            draws += 1
            if not seen[i]:
                failures["keypoint out of view"] += 1
                continue
            check = checker.check(q)
            if check.valid:
                found.append(q)
                checks.append(check)
                if len(found) == settings.candidates:
                    break
            else:
                failures[check.failed] += 1
        if progress is not None:
            progress(len(found), draws)
    if failures["keypoint out of view"] == draws:
        never = [k for k, seen in zip(robot.keypoint_names, ever_seen, strict=True) if not seen]
        which = f" ({', '.join(never)} never in view)" if never else ""
        raise InputError(f"the camera sees every keypoint of '{robot.name}' in none of "
                         f"{draws} poses drawn within the joint ranges{which}",
                         fix="check the camera position and look-at point (metres, base frame) "
                             "and the intrinsics, or lower --margin-px")
    joints = np.array(found).reshape(-1, robot.num_joints)
    return Candidates(joints, tuple(checks), draws, dict(failures), checker)


def _check_enough(candidates: Candidates, num: int) -> None:
    found = len(candidates.joints)
    if found == 0:
        raise InputError(f"no valid pose was found in {candidates.draws} draws (rejected: "
                         f"{candidates.describe_failures()})",
                         fix="lower the table (--table-z), move keep-out boxes, widen the joint "
                             "ranges or lower --margin-px / --clearance-m")
    if found < num:
        raise InputError(f"only {found} valid poses were found in {candidates.draws} draws "
                         f"(rejected: {candidates.describe_failures()}), fewer than the "
                         f"{num} asked for",
                         fix=f"ask for at most --num {found}, or widen the joint ranges, move "
                             "keep-out boxes or allow more draws (--max-draws)")
    if found < 2 * num:
        logger.warning("only %d valid poses to choose %d from; the plan gains little over "
                       "random poses", found, num)


def start_joints(robot: Robot, start: np.ndarray | None) -> np.ndarray | None:
    """`start` (J,) checked against the URDF limits ("are these degrees?"); None stays None."""
    if start is None:
        return None
    start = robot.validate_joints(start)
    check_robot_joints(robot, start[None], ["--start"])
    return start


def choose_poses(robot: Robot, prior: CameraPrior, candidates: Candidates,
                 settings: PlanSettings, start: np.ndarray | None = None) -> Plan:
    """The D-optimal `settings.num_poses` of `candidates`, ordered from `start` (default: the
    path begins at the pose nearest the robot's rest configuration; the rest configuration
    itself is not a pose of the plan, and the convex hulls the checks use may overlap there)."""
    _check_enough(candidates, settings.num_poses)
    rng = np.random.default_rng(settings.seed)
    start = start_joints(robot, start)
    P_base = robot.forward_kinematics(candidates.joints)
    F = information_table(P_base, prior.camera, prior.samples(rng, settings.camera_samples),
                          settings.noise_px)
    chosen = select_d_optimal(F, settings.num_poses, restarts=settings.restarts, rng=rng)
    order, moves = _order(candidates, chosen, robot.rest_joints if start is None else start,
                          check_first=start is not None)
    chosen = chosen[order]
    nominal = F[0]
    random_sets = [predicted_sigmas(nominal[rng.choice(len(nominal), settings.num_poses,
                                                       replace=False)].sum(0),
                                    prior.T_cam_base) for _ in range(RANDOM_SETS)]
    joints = candidates.joints[chosen]
    return Plan(joints=joints, checks=tuple(candidates.checks[i] for i in chosen),
                predicted=predicted_sigmas(nominal[chosen].sum(0), prior.T_cam_base),
                random_predicted={key: float(np.median([s[key] for s in random_sets]))
                                  for key in ("position_worst_m", "rotation_worst_rad")},
                path_length=path_length(joints, joints[0] if start is None else start,
                                        np.arange(len(joints))),
                start=start, candidates=candidates, move_clearance_m=moves)


def _order(candidates: Candidates, chosen: np.ndarray, start: np.ndarray, check_first: bool
           ) -> tuple[np.ndarray, np.ndarray | None]:
    """The visiting order of the chosen poses from `start` and each move's clearance (None:
    unchecked, when the candidates carry no checker); without `check_first` the move from
    `start` is neither checked nor returned."""
    Q = candidates.joints[chosen]
    checker = candidates.checker
    if checker is None:
        return order_poses(Q, start), None
    order, moves = order_clear_moves(Q, start, checker.motion_clearance,
                                     checker.feasibility.clearance_m, check_first)
    return order, moves if check_first else moves[1:]
