"""The kinematic tree of a URDF: links, and joints with their precomputed origin transforms.

A joint's `origin` is `T_parent_joint`: the joint frame expressed in the parent link frame. At
joint value 0 the child link frame is the joint frame; a revolute joint then rotates the child
about `axis` (unit vector in the joint frame), a prismatic joint translates it along `axis`.
Everything here is plain data; the numbers are computed in `dream.robot.kinematics`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dream.arrays import read_only
from dream.errors import InputError, RobotError

FIXED = "fixed"
REVOLUTE = "revolute"
CONTINUOUS = "continuous"
PRISMATIC = "prismatic"
ROTATING_TYPES = (REVOLUTE, CONTINUOUS)
SUPPORTED_TYPES = (FIXED, REVOLUTE, CONTINUOUS, PRISMATIC)
MOVING_TYPES = (REVOLUTE, CONTINUOUS, PRISMATIC)
URDF_TYPES = SUPPORTED_TYPES + ("floating", "planar")  # every type the URDF format defines

UNIT_TOLERANCE = 1e-9  # |axis| may differ from 1 by this much before it is renormalised
MIN_AXIS_NORM = 1e-12  # a shorter axis has no direction
MIN_OFFSET_M = 1e-12  # a shorter origin translation has no direction to stretch along



@dataclass(frozen=True)
class Mimic:
    """A joint whose value is `multiplier * value(master) + offset`."""

    master: str
    multiplier: float = 1.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        if not self.master:
            raise InputError("a <mimic> element names no joint")
        if not (np.isfinite(self.multiplier) and np.isfinite(self.offset)):
            raise InputError(f"mimic of '{self.master}' has a non-finite multiplier or offset")


@dataclass(frozen=True, eq=False)
class JointModel:
    """One URDF joint.

    Attributes:
        name, type, parent, child: as in the URDF; `type` is one of `SUPPORTED_TYPES` or another
            URDF type (floating, planar) that kinematics refuses when it lies on a used chain.
        origin: T_parent_joint, shape (4, 4), metres.
        axis: unit vector (3,) in the joint frame (child frame at value 0).
        lower, upper: limits in rad or m; continuous joints get -pi..pi, fixed ones 0..0.
        mimic: set when the joint follows another joint.
    """

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float = 0.0
    upper: float = 0.0
    mimic: Mimic | None = None

    def __post_init__(self) -> None:
        if self.type not in URDF_TYPES:
            raise InputError(f"joint '{self.name}' has type '{self.type}'",
                             fix=f"use one of {', '.join(URDF_TYPES)}")
        origin = np.asarray(self.origin, dtype=float)
        if origin.shape != (4, 4) or not np.all(np.isfinite(origin)):
            raise InputError(f"joint '{self.name}' has an invalid origin")
        axis = np.asarray(self.axis, dtype=float).reshape(-1)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)):
            raise InputError(f"joint '{self.name}' has an invalid axis {self.axis}")
        if self.type in MOVING_TYPES:
            norm = np.linalg.norm(axis)
            if norm < MIN_AXIS_NORM:
                raise InputError(f"joint '{self.name}' has a zero axis",
                                 fix="give its <axis xyz=...> a direction")
            if abs(norm - 1.0) > UNIT_TOLERANCE:
                axis = axis / norm
        if not (self.lower <= self.upper):
            raise InputError(f"joint '{self.name}' has lower limit {self.lower} above upper "
                             f"limit {self.upper}")
        object.__setattr__(self, "origin", read_only(origin))
        object.__setattr__(self, "axis", read_only(axis))

    @property
    def moves(self) -> bool:
        """True for revolute, continuous and prismatic joints (also when they mimic another)."""
        return self.type in MOVING_TYPES

    @property
    def rest_value(self) -> float:
        """0 clipped into the limits: the value used when nothing sets this joint."""
        return float(np.clip(0.0, self.lower, self.upper))

    def with_origin_stretched(self, delta_m: float) -> JointModel:
        """The same joint with `delta_m` metres added along its origin translation."""
        t = self.origin[:3, 3]
        length = float(np.linalg.norm(t))
        if length < MIN_OFFSET_M:
            raise RobotError(f"joint '{self.name}' has a zero origin offset; its link length "
                             "cannot change along it")
        origin = self.origin.copy()
        origin[:3, 3] = t * (1.0 + delta_m / length)
        return dataclasses.replace(self, origin=origin)


@dataclass(frozen=True, eq=False)
class KinematicTree:
    """Links and joints of one URDF, validated to form a single tree.

    Attributes:
        name: the URDF's robot name.
        links: link names in URDF order.
        joints: joints in URDF order.
        source: the URDF file, when there is one.
    Derived: `root` (the one link without parent joint), `joint_index`, `parent_joint`.
    """

    name: str
    links: tuple[str, ...]
    joints: tuple[JointModel, ...]
    source: Path | None = None
    root: str = field(init=False)
    joint_index: Mapping[str, int] = field(init=False, repr=False)
    parent_joint: Mapping[str, int] = field(init=False, repr=False)
    _paths: Mapping[str, tuple[int, ...]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "links", tuple(self.links))
        object.__setattr__(self, "joints", tuple(self.joints))
        where = self.source
        if len(set(self.links)) != len(self.links):
            raise InputError("two links have the same name", where)
        joint_index: dict[str, int] = {}
        parent_joint: dict[str, int] = {}
        link_set = set(self.links)
        for i, j in enumerate(self.joints):
            if j.name in joint_index:
                raise InputError(f"two joints are named '{j.name}'", where)
            joint_index[j.name] = i
            for end in (j.parent, j.child):
                if end not in link_set:
                    raise InputError(f"joint '{j.name}' refers to unknown link '{end}'", where)
            if j.child in parent_joint:
                raise InputError(f"link '{j.child}' is the child of two joints", where)
            parent_joint[j.child] = i
        roots = [name for name in self.links if name not in parent_joint]
        if len(roots) != 1:
            raise InputError(f"the links must form one tree, found roots {roots}", where)
        for j in self.joints:
            if j.mimic is not None:
                master = joint_index.get(j.mimic.master)
                if master is None:
                    raise InputError(f"joint '{j.name}' mimics unknown joint "
                                     f"'{j.mimic.master}'", where)
                if not self.joints[master].moves:
                    raise InputError(f"joint '{j.name}' mimics '{j.mimic.master}', which is not "
                                     "revolute, continuous or prismatic", where)
        paths: dict[str, tuple[int, ...]] = {}
        for link in self.links:
            chain: list[int] = []
            node = link
            while node in parent_joint:
                chain.append(parent_joint[node])
                node = self.joints[parent_joint[node]].parent
                if len(chain) > len(self.joints):
                    raise InputError(f"the joints form a cycle through link '{link}'", where)
            paths[link] = tuple(reversed(chain))
        object.__setattr__(self, "root", roots[0])
        object.__setattr__(self, "joint_index", joint_index)
        object.__setattr__(self, "parent_joint", parent_joint)
        object.__setattr__(self, "_paths", paths)
        for j in self.joints:  # mimic cycles would make values undefined
            self.resolve_mimic(j.name)

    def check_link(self, link: str, what: str = "link") -> None:
        """Raise RobotError unless `link` is a link of this tree, listing the valid names."""
        if link not in self._paths:
            raise RobotError(f"unknown {what} '{link}' for robot '{self.name}'; its links are: "
                             f"{', '.join(self.links)}")

    def path(self, link: str) -> tuple[int, ...]:
        """Indices of the joints from the root down to `link`, root first."""
        self.check_link(link)
        return self._paths[link]

    def is_ancestor(self, ancestor: str, link: str) -> bool:
        """True when `ancestor` is `link` or lies on its chain towards the root."""
        self.check_link(ancestor)
        return ancestor == self.root or any(
            self.joints[i].child == ancestor for i in self.path(link))

    def resolve_mimic(self, joint: str) -> tuple[str, float, float]:
        """(master, multiplier, offset) with value(joint) = multiplier * value(master) + offset.

        Follows mimic chains to a joint that mimics nothing; a joint without mimic is its own
        master with (1, 0).
        """
        multiplier, offset = 1.0, 0.0
        current = self.joints[self.joint_index[joint]]
        for _ in range(len(self.joints) + 1):
            if current.mimic is None:
                return current.name, multiplier, offset
            multiplier, offset = (multiplier * current.mimic.multiplier,
                                  offset + multiplier * current.mimic.offset)
            current = self.joints[self.joint_index[current.mimic.master]]
        raise InputError(f"mimic joints form a cycle through '{joint}'", self.source)

    def with_joint(self, joint: JointModel) -> KinematicTree:
        """The same tree with the joint of the same name replaced."""
        if joint.name not in self.joint_index:
            raise RobotError(f"unknown joint '{joint.name}' for robot '{self.name}'")
        joints = list(self.joints)
        joints[self.joint_index[joint.name]] = joint
        return dataclasses.replace(self, joints=tuple(joints))
