"""`Robot`: a kinematic tree seen from its base link, with the keypoints a network detects.

Frames: every result is expressed in the base link frame (`P_base`, `T_base_link`). A keypoint
named after a link is that link frame's origin. Joint vectors hold the values of `joint_names`
(rad for revolute/continuous joints, m for prismatic ones) in the last axis; any leading batch
shape is allowed and carried through.

Joints that move no keypoint (e.g. the Panda's fingers) are not in `joint_names`; when a link
pose needs them they sit at their rest value (0 clipped into their limits). Mimic joints follow
their master: value = multiplier * master + offset.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dream.arrays import read_only
from dream.errors import RobotError
from dream.robot.kinematics import (
    IDENTITY_R,
    ZERO_P,
    apply,
    child_frame,
    joint_frame,
    joint_point_jacobian,
)
from dream.robot.tree import MOVING_TYPES, SUPPORTED_TYPES, JointModel, KinematicTree

Frame = tuple[np.ndarray, np.ndarray]  # (R (..., 3, 3), p (..., 3)) in the evaluation frame


@dataclass(frozen=True)
class _JointSource:
    """value(joint) = multiplier * (q + offsets)[..., index] + constant; index -1: constant."""

    index: int
    multiplier: float
    constant: float



@dataclass(frozen=True, eq=False)
class Robot:
    """A robot arm for calibration: kinematics from `base_link` to the keypoint links.

    Attributes:
        name: robot name (the `class` of dataset objects).
        urdf_path: the URDF it was read from.
        base_link: the link whose frame is the robot base frame.
        keypoint_names: links whose origins are the keypoints, in output order.
        tree: the parsed URDF (joints with their precomputed origin transforms).
    Derived:
        joint_names: actuated (non-fixed, non-mimic) joints on the chains from the base to the
            keypoints, plus the masters of mimic joints on them, in URDF order. A joint counts
            even when its motion leaves every keypoint origin in place (the Panda's joint 7:
            the hand origin lies on its axis), so joint vectors match the robot's data.
        joint_lower, joint_upper: (J,) limits, rad or m (continuous joints: -pi..pi).
        skeleton_edges: (i, j) keypoint index pairs, each keypoint j linked to its nearest
            keypoint ancestor i in the tree.
    """

    name: str
    urdf_path: Path
    base_link: str
    keypoint_names: tuple[str, ...]
    tree: KinematicTree = field(repr=False)
    joint_names: tuple[str, ...] = field(init=False)
    joint_lower: np.ndarray = field(init=False, repr=False)
    joint_upper: np.ndarray = field(init=False, repr=False)
    skeleton_edges: tuple[tuple[int, int], ...] = field(init=False, repr=False)
    _sources: Mapping[int, _JointSource] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise RobotError("a robot needs a non-empty name")
        if not isinstance(self.tree, KinematicTree):
            raise RobotError("Robot.tree must be a KinematicTree (use load_robot)")
        object.__setattr__(self, "urdf_path", Path(self.urdf_path))
        tree = self.tree
        tree.check_link(self.base_link, "base link")
        if isinstance(self.keypoint_names, str):
            raise RobotError("keypoint_names must be a list of link names, not one string")
        keypoints = tuple(self.keypoint_names)
        object.__setattr__(self, "keypoint_names", keypoints)
        if not keypoints:
            raise RobotError(f"robot '{self.name}' needs at least one keypoint link")
        if len(set(keypoints)) != len(keypoints):
            raise RobotError(f"keypoint links repeat: {list(keypoints)}")
        for k in keypoints:
            tree.check_link(k, "keypoint link")
            if not tree.is_ancestor(self.base_link, k):
                raise RobotError(f"keypoint link '{k}' is not attached below base link "
                                 f"'{self.base_link}'; choose links of the arm below the base")
        chain = self._chain_joint_indices(keypoints)
        for i in chain:
            if tree.joints[i].type not in SUPPORTED_TYPES:
                raise RobotError(f"joint '{tree.joints[i].name}' of type "
                                 f"'{tree.joints[i].type}' lies between the base and a keypoint;"
                                 f" only {', '.join(SUPPORTED_TYPES)} joints are supported")
        masters = {tree.resolve_mimic(tree.joints[i].name)[0] for i in chain
                   if tree.joints[i].moves}
        names = tuple(j.name for j in tree.joints if j.name in masters)
        lookup = {n: k for k, n in enumerate(names)}
        sources: dict[int, _JointSource] = {}
        for i, joint in enumerate(tree.joints):
            if joint.type not in MOVING_TYPES:
                continue
            master, multiplier, offset = tree.resolve_mimic(joint.name)
            if master in lookup:
                sources[i] = _JointSource(lookup[master], multiplier, offset)
            else:
                rest = tree.joints[tree.joint_index[master]].rest_value
                sources[i] = _JointSource(-1, 0.0, multiplier * rest + offset)
        object.__setattr__(self, "joint_names", names)
        object.__setattr__(self, "_sources", sources)
        limits = [tree.joints[tree.joint_index[n]] for n in names]
        object.__setattr__(self, "joint_lower", read_only([j.lower for j in limits]))
        object.__setattr__(self, "joint_upper", read_only([j.upper for j in limits]))
        object.__setattr__(self, "skeleton_edges", self._skeleton(keypoints))

    # ----- structure -----------------------------------------------------------------------

    def _chain_joint_indices(self, links: Sequence[str]) -> tuple[int, ...]:
        """Joints between the base and `links` (all descendants of the base), URDF order."""
        start = len(self.tree.path(self.base_link))
        return tuple(sorted({i for link in links for i in self.tree.path(link)[start:]}))

    def _skeleton(self, keypoints: tuple[str, ...]) -> tuple[tuple[int, int], ...]:
        index = {k: n for n, k in enumerate(keypoints)}
        edges = []
        for n, k in enumerate(keypoints):
            for i in reversed(self.tree.path(k)):
                parent = self.tree.joints[i].parent
                if parent in index:
                    edges.append((index[parent], n))
                    break
        return tuple(edges)

    @property
    def num_joints(self) -> int:
        """J, the length of a joint vector."""
        return len(self.joint_names)

    @property
    def num_keypoints(self) -> int:
        """K, the number of keypoints."""
        return len(self.keypoint_names)

    @property
    def link_names(self) -> tuple[str, ...]:
        """Every link of the URDF."""
        return self.tree.links

    @property
    def chain_joints(self) -> tuple[JointModel, ...]:
        """Joints (fixed ones too) between the base and the keypoints, in URDF order.

        Each carries its precomputed origin `T_parent_joint` (4, 4) and unit axis.
        """
        return tuple(self.tree.joints[i] for i in self._chain_joint_indices(self.keypoint_names))

    @property
    def rest_joints(self) -> np.ndarray:
        """(J,) zero clipped into the limits."""
        return np.clip(0.0, self.joint_lower, self.joint_upper)

    def with_keypoints(self, names: Sequence[str]) -> Robot:
        """The same robot with other keypoint links (unknown link -> RobotError)."""
        if isinstance(names, str):
            names = (names,)
        return dataclasses.replace(self, keypoint_names=tuple(names))

    def with_link_length_changes(self, deltas_m: Mapping[str, float]) -> Robot:
        """The same robot with metres added along some joints' origin offsets.

        Args:
            deltas_m: joint name -> metres added to the length of its origin translation
                (any joint of the URDF, fixed ones included).
        Raises:
            RobotError: unknown joint, non-finite change, or a joint with a zero offset.
        """
        tree = self.tree
        for joint_name, delta in deltas_m.items():
            if joint_name not in tree.joint_index:
                raise RobotError(f"unknown joint '{joint_name}' for robot '{self.name}'; its "
                                 f"joints are: {', '.join(j.name for j in tree.joints)}")
            if not np.isfinite(delta):
                raise RobotError(f"link length change of '{joint_name}' is {delta}")
            joint = tree.joints[tree.joint_index[joint_name]]
            tree = tree.with_joint(joint.with_origin_stretched(float(delta)))
        return dataclasses.replace(self, tree=tree)

    # ----- joint vectors -------------------------------------------------------------------

    def validate_joints(self, joints: np.ndarray) -> np.ndarray:
        """Joint values as a float array (..., J), checked for length and finiteness.

        Raises:
            RobotError: wrong last-axis length, non-numeric or non-finite values; the message
                names the expected joints.
        """
        expected = f"({', '.join(self.joint_names)})"
        try:
            q = np.asarray(joints, dtype=float)
        except (TypeError, ValueError) as e:
            raise RobotError(f"joint values of robot '{self.name}' are not numbers ({e}); "
                             f"expected {self.num_joints} values {expected}") from e
        if q.ndim == 0 or q.shape[-1] != self.num_joints:
            raise RobotError(f"robot '{self.name}' expects {self.num_joints} joint values in the "
                             f"last axis {expected}, got shape {q.shape}")
        bad = ~np.isfinite(q)
        if np.any(bad):
            where = tuple(int(x) for x in np.argwhere(bad)[0])
            raise RobotError(f"joint '{self.joint_names[where[-1]]}' of robot '{self.name}' is "
                             f"{q[where]} (batch index {where[:-1]}); joint values must be finite"
                             f" numbers {expected}")
        return q

    def joints_from_named(self, names: Sequence[str], values: np.ndarray) -> np.ndarray:
        """Reorder named joint values (e.g. a frame's sim_state) into this robot's order.

        Args:
            names: joint names as given by the data, length N.
            values: (..., N) values in the order of `names`.
        Returns:
            (..., J) joint vector; names this robot does not use (fingers) are ignored.
        Raises:
            RobotError: a joint of `joint_names` is missing, names repeat, shapes disagree or
                a used value is not finite.
        """
        names = [str(n) for n in names]
        values = np.asarray(values, dtype=float)
        if values.ndim == 0 or values.shape[-1] != len(names):
            raise RobotError(f"{len(names)} joint names but values of shape {values.shape}")
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise RobotError(f"joint names repeat in the data: {repeated}")
        index = {n: i for i, n in enumerate(names)}
        missing = [n for n in self.joint_names if n not in index]
        if missing:
            raise RobotError(f"joint(s) {', '.join(missing)} missing from the data; robot "
                             f"'{self.name}' needs {', '.join(self.joint_names)}")
        return self.validate_joints(values[..., [index[n] for n in self.joint_names]])

    def sample_joints(self, rng: np.random.Generator, shape: tuple[int, ...] = ()) -> np.ndarray:
        """Joint vectors drawn uniformly within the limits, shape shape + (J,)."""
        size = tuple(shape) + (self.num_joints,)
        return rng.uniform(self.joint_lower, self.joint_upper, size=size)

    def _values(self, joints: np.ndarray, joint_offsets: np.ndarray | None) -> np.ndarray:
        q = self.validate_joints(joints)
        if joint_offsets is None:
            return q
        offsets = np.asarray(joint_offsets, dtype=float)
        if offsets.ndim == 0 or offsets.shape[-1] != self.num_joints \
                or not np.all(np.isfinite(offsets)):
            raise RobotError(f"joint_offsets must be {self.num_joints} finite values "
                             f"({', '.join(self.joint_names)}), got shape {offsets.shape}")
        return q + offsets

    # ----- kinematics ----------------------------------------------------------------------

    def _value(self, index: int, qv: np.ndarray) -> np.ndarray | float:
        source = self._sources.get(index)
        if source is None:
            return 0.0
        if source.index < 0:
            return source.constant
        return source.multiplier * qv[..., source.index] + source.constant

    def _evaluate(self, qv: np.ndarray, links: Sequence[str],
                  start: str) -> tuple[dict[str, Frame], dict[int, Frame]]:
        """Frames of `links` (and the chains to them) relative to link `start`.

        Returns (link frames, joint frames by joint index), all in `start`'s frame.
        """
        frames: dict[str, Frame] = {start: (IDENTITY_R, ZERO_P)}
        joint_frames: dict[int, Frame] = {}
        depth = len(self.tree.path(start))
        for link in links:
            for i in self.tree.path(link)[depth:]:
                joint = self.tree.joints[i]
                if joint.child in frames:
                    continue
                if joint.type not in SUPPORTED_TYPES:
                    raise RobotError(f"cannot compute the pose of link '{link}': joint "
                                     f"'{joint.name}' of type '{joint.type}' is not supported")
                R_joint, p_joint = joint_frame(*frames[joint.parent], joint)
                joint_frames[i] = (R_joint, p_joint)
                frames[joint.child] = child_frame(R_joint, p_joint, joint, self._value(i, qv))
        return frames, joint_frames

    def _stack_points(self, frames: dict[str, Frame], links: Sequence[str],
                      batch: tuple[int, ...]) -> np.ndarray:
        return np.stack([np.broadcast_to(frames[k][1], batch + (3,)) for k in links], axis=-2)

    def forward_kinematics(self, joints: np.ndarray,
                           joint_offsets: np.ndarray | None = None) -> np.ndarray:
        """Keypoint positions in the base frame.

        Args:
            joints: (..., J) values of `joint_names`.
            joint_offsets: optional (J,) (or broadcastable (..., J)) added to `joints` first.
        Returns:
            P_base: (..., K, 3) keypoint link origins in the base link frame, m.
        """
        qv = self._values(joints, joint_offsets)
        frames, _ = self._evaluate(qv, self.keypoint_names, self.base_link)
        return self._stack_points(frames, self.keypoint_names, qv.shape[:-1])

    def link_poses(self, joints: np.ndarray, links: Sequence[str],
                   joint_offsets: np.ndarray | None = None) -> np.ndarray:
        """Poses of any links of the URDF in the base frame.

        Args:
            joints: (..., J) values of `joint_names`.
            links: L link names (one string counts as one link).
            joint_offsets: optional (J,) added to `joints` first.
        Returns:
            T_base_link: (..., L, 4, 4).
        Raises:
            RobotError: an unknown link (the message lists the valid names).
        """
        if isinstance(links, str):
            links = (links,)
        links = tuple(links)
        for link in links:
            self.tree.check_link(link)
        qv = self._values(joints, joint_offsets)
        batch = qv.shape[:-1]
        below = all(self.tree.is_ancestor(self.base_link, link) for link in links)
        start = self.base_link if below else self.tree.root
        frames, _ = self._evaluate(qv, links + (self.base_link,), start)
        R_start_base, p_start_base = frames[self.base_link]
        R_base_start = np.swapaxes(R_start_base, -1, -2)
        T = np.zeros(batch + (len(links), 4, 4))
        for n, link in enumerate(links):
            R, p = frames[link]
            T[..., n, :3, :3] = R_base_start @ R
            T[..., n, :3, 3] = apply(R_base_start, p - p_start_base)
        T[..., 3, 3] = 1.0
        return T

    def keypoint_jacobian(self, joints: np.ndarray,
                          joint_offsets: np.ndarray | None = None) -> np.ndarray:
        """Exact derivative of the keypoint positions with respect to the joint values.

        Args:
            joints: (..., J); joint_offsets: optional (J,) as in `forward_kinematics`.
        Returns:
            dP_base/dq: (..., K, 3, J), m/rad or m/m, in the base frame.
        """
        qv = self._values(joints, joint_offsets)
        batch = qv.shape[:-1]
        frames, joint_frames = self._evaluate(qv, self.keypoint_names, self.base_link)
        points = self._stack_points(frames, self.keypoint_names, batch)
        jac = np.zeros(batch + (self.num_keypoints, self.num_joints, 3))
        start = len(self.tree.path(self.base_link))
        for i, (R_joint, p_joint) in joint_frames.items():
            joint = self.tree.joints[i]
            source = self._sources.get(i)
            if not joint.moves or source is None or source.index < 0:
                continue
            downstream = [n for n, k in enumerate(self.keypoint_names)
                          if i in self.tree.path(k)[start:]]
            columns = joint_point_jacobian(R_joint, p_joint, joint, points[..., downstream, :])
            jac[..., downstream, source.index, :] += source.multiplier * columns
        return np.swapaxes(jac, -1, -2)
