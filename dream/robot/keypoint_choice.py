"""Which link origins of a URDF make good keypoints: the analysis behind `dream robots --urdf`.

A keypoint is a link origin; PnP solves the camera from keypoints that are told apart in the
image and spread in 3D. Over joint configurations drawn within the limits (seeded), the origin
of every link below the base is computed by forward kinematics, and:
- origins *coincide* when their distance stays below `COINCIDENT_TOL_M` in every configuration
  (zero-length joint offsets): they cannot be told apart, one of them at most is a keypoint;
- three or more origins are *collinear* when their spread perpendicular to their best-fit line
  stays below `COLLINEAR_TOL_M` in every configuration. When that line is also the same in every
  configuration (e.g. links on the base's vertical axis), no number of frames fixes the camera's
  rotation about it: such keypoints are useless alone.

The suggestion follows `dream.robot.registry`'s principles: the base link; then, along the arm's
chain (the links through which joints move, past a mobile base's wheels, a quadruped's legs or
a head where one branch carries far more moving joints, up to the hand whose fingers branch off,
or up to the last moving link and then its rigidly attached flange/tool link), one link per group of
coincident origins, the distal name (as DREAM keeps panda_link2 of link1/link2); links whose
origin coincides with one already chosen, side branches (fingers, mounts) and fixed-joint
children at their parent's origin are left out.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dream.errors import RobotError
from dream.robot.robot import Robot
from dream.robot.tree import FIXED, MOVING_TYPES, SUPPORTED_TYPES, KinematicTree

NUM_SAMPLES = 64          # joint configurations drawn within the limits
SAMPLE_SEED = 0           # the draw is the same on every run
COINCIDENT_TOL_M = 1e-3   # origins closer than this in every configuration coincide
COLLINEAR_TOL_M = 5e-3    # a few pixels at 1-2 m: less off the line cannot be measured
MIN_COLLINEAR = 3         # two points always lie on a line
# words naming a flange / tool link, most specific first: matched in the lower-case link name
# between non-letters ("tool0", "link_eef", "lbr_link_ee", "j2s6s200_end_effector")
TOOL_NAME_HINTS = ("flange", "tool", "tcp", "eef", "ee", "end_effector")
# where the chain branches into several moving branches, one carrying at least this many times
# the moving joints of every other, and at least MIN_ARM_BRANCH_JOINTS, is the arm (a mobile
# base's wheels or a quadruped's legs beside it, a head beside it on a torso); branches more
# alike are a hand's fingers, or two arms, and end the chain
ARM_BRANCH_RATIO = 2
MIN_ARM_BRANCH_JOINTS = 3


@dataclass(frozen=True)
class LinkOrigins:
    """Link origins in the base frame over sampled joint configurations.

    Attributes:
        links: L link names.
        points: (S, L, 3) origins, metres, S >= 1 configurations.
    """

    links: tuple[str, ...]
    points: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "links", tuple(self.links))
        points = np.asarray(self.points, dtype=float)
        if points.ndim != 3 or points.shape[0] < 1 or points.shape[1:] != (len(self.links), 3):
            raise RobotError(f"link origins must have shape (S, {len(self.links)}, 3), got "
                             f"{points.shape}")
        object.__setattr__(self, "points", points)

    def of(self, names: Sequence[str]) -> np.ndarray:
        """(S, N, 3) origins of `names` (unknown name -> RobotError)."""
        index = {name: i for i, name in enumerate(self.links)}
        unknown = [n for n in names if n not in index]
        if unknown:
            raise RobotError(f"no sampled origin for link(s) {', '.join(unknown)}")
        return self.points[:, [index[n] for n in names]]


@dataclass(frozen=True)
class CollinearSet:
    """Keypoints whose origins stay on one line in every configuration.

    Attributes:
        links: three or more link names.
        fixed_line: the line is the same in every configuration (useless alone for any number
            of frames); otherwise only a single frame's PnP is degenerate.
    """

    links: tuple[str, ...]
    fixed_line: bool

    def __post_init__(self) -> None:
        object.__setattr__(self, "links", tuple(self.links))
        if len(self.links) < MIN_COLLINEAR:
            raise RobotError(f"a collinear set needs {MIN_COLLINEAR} links, got {self.links}")


@dataclass(frozen=True)
class KeypointAdvice:
    """What `analyse_keypoints` found.

    Attributes:
        base_link: the base the origins are expressed in.
        coincident: groups (two or more links, URDF order) whose origins coincide.
        suggested: the suggested keypoint links, base first, flange/tool last.
        suggested_collinear: collinear sets among the suggested keypoints.
        given: the keypoints asked about (empty: none).
        given_coincident: groups of the given keypoints whose origins coincide.
        given_collinear: collinear sets among the given keypoints.
        skipped: links not analysed (above the base, or below an unsupported joint).
        branches: where the chain branches into alike branches before the arm began (two arms
            on a torso), the first link of each: the suggestion stops there (`arm_branches`).
        branch_keypoints: for each of `branches`, the suggestion carried on along that arm
            (the keypoints of a network for that arm).
    """

    base_link: str
    coincident: tuple[tuple[str, ...], ...]
    suggested: tuple[str, ...]
    suggested_collinear: tuple[CollinearSet, ...]
    given: tuple[str, ...] = ()
    given_coincident: tuple[tuple[str, ...], ...] = ()
    given_collinear: tuple[CollinearSet, ...] = ()
    skipped: tuple[str, ...] = ()
    branches: tuple[str, ...] = ()
    branch_keypoints: tuple[tuple[str, ...], ...] = ()

    def __post_init__(self) -> None:
        for name in ("coincident", "suggested", "suggested_collinear", "given",
                     "given_coincident", "given_collinear", "skipped", "branches"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        object.__setattr__(self, "branch_keypoints",
                           tuple(tuple(links) for links in self.branch_keypoints))
        if not self.suggested or self.suggested[0] != self.base_link:
            raise RobotError(f"the suggested keypoints must start at base link "
                             f"'{self.base_link}', got {self.suggested}")

    @property
    def given_line(self) -> CollinearSet | None:
        """The line every given keypoint stays on in every configuration, if they do (three or
        more distinct ones); None otherwise."""
        distinct = set(_one_per_group(self.given, self.given_coincident))
        return next((s for s in self.given_collinear if distinct <= set(s.links)), None)


def perpendicular_spread(points: np.ndarray) -> np.ndarray:
    """(..., N, 3) points -> (...,) largest distance of a point from their best-fit line, m."""
    p = np.asarray(points, dtype=float)
    if p.ndim < 2 or p.shape[-1] != 3 or p.shape[-2] < 1:
        raise RobotError(f"points must have shape (..., N, 3), got {p.shape}")
    centred = p - p.mean(axis=-2, keepdims=True)
    direction = np.linalg.svd(centred, full_matrices=False)[2][..., 0, :]   # (..., 3)
    along = np.sum(centred * direction[..., None, :], axis=-1, keepdims=True)
    return np.linalg.norm(centred - along * direction[..., None, :], axis=-1).max(axis=-1)


def stays_collinear(points: np.ndarray, tol_m: float = COLLINEAR_TOL_M) -> bool:
    """(S, N, 3): True when the points lie within `tol_m` of one line in every configuration."""
    return bool(np.all(perpendicular_spread(points) < tol_m))


def analysable_links(tree: KinematicTree, base_link: str) -> tuple[str, ...]:
    """Links below `base_link` (itself included) reached through supported joints only."""
    tree.check_link(base_link, "base link")
    depth = len(tree.path(base_link))
    return tuple(link for link in tree.links if tree.is_ancestor(base_link, link) and all(
        tree.joints[i].type in SUPPORTED_TYPES for i in tree.path(link)[depth:]))


def sample_link_origins(tree: KinematicTree, base_link: str, num_samples: int = NUM_SAMPLES,
                        seed: int = SAMPLE_SEED) -> LinkOrigins:
    """Origins of `analysable_links` at `num_samples` joint configurations drawn uniformly
    within the limits (continuous joints: -pi..pi) with `seed`."""
    if num_samples < 1:
        raise RobotError(f"num_samples must be 1 or more, got {num_samples}")
    links = analysable_links(tree, base_link)
    robot = Robot(name=tree.name or "urdf", urdf_path=tree.source or "", base_link=base_link,
                  keypoint_names=links, tree=tree)
    q = robot.sample_joints(np.random.default_rng(seed), (num_samples,))
    return LinkOrigins(links, robot.forward_kinematics(q))


def stay_together(a: np.ndarray, b: np.ndarray, tol_m: float = COINCIDENT_TOL_M) -> bool:
    """Whether two origins (S, 3), sampled over the same configurations, stay within `tol_m`
    of each other in every one (they coincide)."""
    return bool(np.linalg.norm(a - b, axis=-1).max() < tol_m)


def coincident_groups(origins: LinkOrigins, names: Sequence[str] | None = None,
                      tol_m: float = COINCIDENT_TOL_M) -> tuple[tuple[str, ...], ...]:
    """Groups of two or more of `names` (default: every link) whose origins stay within `tol_m`
    of the group's first in every configuration, in the order of `names`."""
    names = tuple(origins.links if names is None else names)
    p = origins.of(names)
    groups: list[list[int]] = []
    for i in range(len(names)):
        for group in groups:
            if stay_together(p[:, i], p[:, group[0]], tol_m):
                group.append(i)
                break
        else:
            groups.append([i])
    return tuple(tuple(names[i] for i in g) for g in groups if len(g) > 1)


def _one_per_group(names: Sequence[str], groups: Sequence[Sequence[str]]) -> tuple[str, ...]:
    """`names` with each coincident group's later members left out."""
    later = {name for group in groups for name in group[1:]}
    return tuple(n for n in names if n not in later)


def collinear_sets(origins: LinkOrigins, names: Sequence[str],
                   tol_m: float = COLLINEAR_TOL_M) -> tuple[CollinearSet, ...]:
    """The largest sets of three or more of `names` (coincident ones counted once) that stay
    collinear in every configuration, each in the order of `names`."""
    names = _one_per_group(names, coincident_groups(origins, names))
    p = origins.of(names)
    found: list[frozenset[int]] = []
    for i, j in itertools.combinations(range(len(names)), 2):
        members = {i, j} | {k for k in range(len(names)) if k not in (i, j)
                            and stays_collinear(p[:, [i, j, k]], tol_m)}
        if len(members) >= MIN_COLLINEAR and stays_collinear(p[:, sorted(members)], tol_m):
            found.append(frozenset(members))
    largest = {s for s in found if not any(s < other for other in found)}
    out = []
    for members in sorted(largest, key=sorted):
        order = sorted(members)
        pooled = p[:, order].reshape(1, -1, 3)          # every configuration's points together
        out.append(CollinearSet(tuple(names[k] for k in order),
                                fixed_line=stays_collinear(pooled, tol_m)))
    return tuple(out)


def _children(tree: KinematicTree, link: str) -> list:
    return [j for j in tree.joints if j.parent == link and j.type in SUPPORTED_TYPES]


def _moving_depth(tree: KinematicTree, joint) -> int:
    """The moving joints on the longest path from `joint` (itself included) down the tree."""
    own = 1 if joint.type in MOVING_TYPES else 0
    return own + max((_moving_depth(tree, j) for j in _children(tree, joint.child)), default=0)


def _arm_branch(tree: KinematicTree, joints: list) -> list:
    """Of two or more moving branches `joints`, the arm's alone where one carries far more
    moving joints than every other (`ARM_BRANCH_RATIO`), else all of them."""
    depths = sorted(((_moving_depth(tree, j), k) for k, j in enumerate(joints)), reverse=True)
    (best, k), (second, _) = depths[0], depths[1]
    if best >= MIN_ARM_BRANCH_JOINTS and best >= ARM_BRANCH_RATIO * second:
        return [joints[k]]
    return joints


def _tool_link(tree: KinematicTree, link: str) -> str | None:
    """The flange / tool link rigidly attached to `link` (fixed joints only), by name."""
    rigid, todo = [], [link]
    while todo:
        for j in _children(tree, todo.pop()):
            if j.type == FIXED:
                rigid.append(j.child)
                todo.append(j.child)
    for hint in TOOL_NAME_HINTS:
        word = re.compile(rf"(^|[^a-z]){hint}([^a-z]|$)")
        for name in rigid:
            if word.search(name.lower()):
                return name
    return None


def arm_chain(tree: KinematicTree, base_link: str) -> tuple[str, ...]:
    """Links from `base_link` along the arm: through the one child that leads to moving joints
    (where several do and one of them carries far more moving joints than the others, that
    one: the arm of a mobile manipulator, not its wheels or its head), up to a link where two or
    more alike do (a hand with fingers: its origin ends the arm, the tool point between the
    fingers lies on no surface; or two arms) or none do (the last moving link, then its
    flange / tool link if one is named so)."""
    chain = [base_link]
    while True:
        moving = [j for j in _children(tree, chain[-1]) if _moving_depth(tree, j) > 0]
        if len(moving) > 1:
            moving = _arm_branch(tree, moving)
        if len(moving) != 1:
            break
        chain.append(moving[0].child)
    tool = _tool_link(tree, chain[-1]) if not moving else None
    if tool is not None:
        depth = len(tree.path(chain[-1]))
        chain += [tree.joints[i].child for i in tree.path(tool)[depth:]]
    return tuple(chain)


def arm_branches(tree: KinematicTree, base_link: str) -> tuple[str, ...]:
    """Where `arm_chain` ends before it passed `MIN_ARM_BRANCH_JOINTS` moving joints, at a link
    that two or more branches of at least that many moving joints leave (two arms on a torso,
    not a hand's fingers after an arm), the first link of each such branch; else ()."""
    chain = arm_chain(tree, base_link)
    depth = len(tree.path(base_link))
    passed = sum(tree.joints[i].type in MOVING_TYPES for i in tree.path(chain[-1])[depth:])
    arms = [j.child for j in _children(tree, chain[-1])
            if _moving_depth(tree, j) >= MIN_ARM_BRANCH_JOINTS]
    return tuple(arms) if passed < MIN_ARM_BRANCH_JOINTS and len(arms) >= 2 else ()


def suggest_keypoints(tree: KinematicTree, base_link: str,
                      origins: LinkOrigins) -> tuple[str, ...]:
    """The base link, then one link per run of coincident origins along `arm_chain` (its
    distal name; the flange / tool ends the chain), skipping origins already chosen."""
    chain = arm_chain(tree, base_link)
    p = origins.of(chain)
    runs: list[list[int]] = []
    for i in range(len(chain)):
        if runs and stay_together(p[:, i], p[:, runs[-1][0]]):
            runs[-1].append(i)
        else:
            runs.append([i])
    chosen: list[int] = []
    for run in runs:
        pick = run[0] if run[0] == 0 else run[-1]      # the base keeps its name
        if not any(stay_together(p[:, pick], p[:, c]) for c in chosen):
            chosen.append(pick)
    return tuple(chain[i] for i in chosen)


def logged_joint_links(tree: KinematicTree, base_link: str, logged: Sequence[str],
                       driven: Sequence[str]) -> tuple[str, ...]:
    """Links that, added to the keypoint links `driven`, make a robot move the joints named in
    `logged` (the data's joint columns) below `base_link`: the child link of each such joint
    that moves, follows no other and is not driven yet, where every moving joint from the base
    to it is logged or driven (a joint the data lacks would be needed, so a branch stops before
    it) and no other of them lies below it (a second arm's last logged joint, a head's). Joints
    behind a floating or planar joint are left out. The silhouettes then draw those links at
    their readings instead of at rest."""
    depth = len(tree.path(base_link))
    on_chain = {i for link in driven for i in tree.path(link)[depth:]}
    known = set(logged) | {tree.joints[i].name for i in on_chain}
    found = []
    for name in dict.fromkeys(logged):
        i = tree.joint_index.get(name)
        if i is None or i in on_chain:
            continue
        joint = tree.joints[i]
        if joint.type not in MOVING_TYPES or joint.mimic is not None or joint.child in driven \
                or joint.child == base_link or not tree.is_ancestor(base_link, joint.child):
            continue
        path = [tree.joints[k] for k in tree.path(joint.child)[depth:]]
        if all(j.type in SUPPORTED_TYPES and (j.type not in MOVING_TYPES
                                              or tree.resolve_mimic(j.name)[0] in known)
               for j in path):
            found.append(joint.child)
    return tuple(link for link in found
                 if not any(other != link and tree.is_ancestor(link, other) for other in found))


def analyse_keypoints(tree: KinematicTree, base_link: str | None = None,
                      given: Sequence[str] = ()) -> KeypointAdvice:
    """Coincident origins, the suggested keypoints and, for `given` keypoint links, which of
    them coincide or stay collinear.

    Raises:
        RobotError: an unknown base link or given link, or a given link not below the base
            (the message names it).
    """
    base = base_link or tree.root
    origins = sample_link_origins(tree, base)
    given = tuple(given)
    for link in given:
        tree.check_link(link, "keypoint link")
        if link not in origins.links:
            raise RobotError(f"keypoint link '{link}' is not below base link '{base}' through "
                             f"{', '.join(SUPPORTED_TYPES)} joints")
    suggested = suggest_keypoints(tree, base, origins)
    branches = arm_branches(tree, base)
    return KeypointAdvice(
        base_link=base, coincident=coincident_groups(origins), suggested=suggested,
        suggested_collinear=collinear_sets(origins, suggested), given=given,
        given_coincident=coincident_groups(origins, given) if given else (),
        given_collinear=collinear_sets(origins, given) if given else (),
        skipped=tuple(link for link in tree.links if link not in origins.links),
        branches=branches,
        branch_keypoints=tuple(along_branch(tree, origins, suggested, b) for b in branches))


def along_branch(tree: KinematicTree, origins: LinkOrigins, suggested: Sequence[str],
                 branch: str) -> tuple[str, ...]:
    """`suggested` (which stops where alike branches begin) carried on along `branch` (the
    first link of one arm): its links as `suggest_keypoints` picks them from there, less those
    whose origin coincides with one already chosen."""
    chosen = list(suggested)
    for link in suggest_keypoints(tree, branch, origins):
        p = origins.of([link, *chosen])
        if not any(stay_together(p[:, 0], p[:, k]) for k in range(1, p.shape[1])):
            chosen.append(link)
    return tuple(chosen)
