"""Reading a URDF file into a `KinematicTree` (kinematics only: meshes are not loaded).

The XML is first checked with a strict parser, because yourdfpy silently recovers from broken
XML; yourdfpy then builds the model (origins as 4x4 matrices from xyz + rpy).
"""

from __future__ import annotations

import functools
import logging
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from dream.errors import InputError
from dream.robot.tree import (
    CONTINUOUS,
    FIXED,
    PRISMATIC,
    REVOLUTE,
    JointModel,
    KinematicTree,
    Mimic,
)

_log = logging.getLogger(__name__)

CONTINUOUS_LIMITS_RAD = (-math.pi, math.pi)  # range given to continuous joints
_URDF_FIX = "give a valid URDF file (XML with <robot>, <link> and <joint> elements)"


def _check_xml(path: Path) -> None:
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise InputError(f"not valid XML ({e})", path, fix=_URDF_FIX) from e
    except OSError as e:
        raise InputError(f"cannot read the URDF ({e.strerror})", path) from e
    if root.tag != "robot":
        raise InputError(f"the root element is <{root.tag}>, not <robot>", path, fix=_URDF_FIX)
    if not root.get("name"):
        raise InputError("the <robot> element has no name (an empty or unfinished file?)", path,
                         fix="give <robot name=...> its links and joints, e.g. the URDF xacro "
                             "makes: xacro robot.urdf.xacro > robot.urdf")


def _limits(joint, path: Path) -> tuple[float, float]:
    if joint.type == CONTINUOUS:
        return CONTINUOUS_LIMITS_RAD
    if joint.type not in (REVOLUTE, PRISMATIC):
        return 0.0, 0.0
    limit = joint.limit
    if limit is None or limit.lower is None or limit.upper is None:
        if joint.type == PRISMATIC:
            raise InputError(f"prismatic joint '{joint.name}' has no lower/upper <limit>", path,
                             fix="add <limit lower=... upper=...> in metres")
        _log.warning("%s: revolute joint '%s' has no limits; using -pi..pi", path, joint.name)
        return CONTINUOUS_LIMITS_RAD
    return float(limit.lower), float(limit.upper)


def _joint_model(joint, path: Path, broken_mimic: bool = False) -> JointModel:
    lower, upper = _limits(joint, path)
    mimic = None
    if joint.mimic is not None and not broken_mimic:
        mimic = Mimic(master=joint.mimic.joint,
                      multiplier=1.0 if joint.mimic.multiplier is None else joint.mimic.multiplier,
                      offset=0.0 if joint.mimic.offset is None else joint.mimic.offset)
    origin = np.eye(4) if joint.origin is None else joint.origin
    axis = np.zeros(3) if joint.type == FIXED else joint.axis
    return JointModel(name=joint.name, type=joint.type, parent=joint.parent, child=joint.child,
                      origin=origin, axis=axis, lower=lower, upper=upper, mimic=mimic)


def _broken_mimics(joints, path: Path) -> frozenset[str]:
    """The joints whose <mimic> names a joint the URDF lacks, logged once; they are read as
    independent joints.

    Shipped URDFs have such tags (a hand's finger mimicking a name its side's prefix was not added
    to); they must not stop a calibration that never moves the finger.
    """
    names = {j.name for j in joints}
    broken = [j for j in joints if j.mimic is not None and (j.mimic.joint or "") not in names]
    if broken:
        _log.warning("%s: <mimic> names a joint the URDF does not have (%s); read as "
                     "independent joints, held at 0 unless the recording logs them. Correct "
                     "the <mimic joint=...> names to make them follow.", path,
                     ", ".join(f"{j.name} -> {j.mimic.joint}" for j in broken))
    return frozenset(j.name for j in broken)


def parse_urdf(path: str | Path) -> KinematicTree:
    """The kinematic tree of a URDF file (cached on path and modification time).

    Raises:
        InputError: the file is missing, unreadable or not a valid URDF (the message names it).
    """
    path = Path(path).expanduser().resolve()
    if not path.is_file():
        raise InputError("URDF file not found", path, fix="check the path to the .urdf file")
    return _parse_cached(path, path.stat().st_mtime_ns)


@functools.lru_cache(maxsize=32)
def _parse_cached(path: Path, mtime_ns: int) -> KinematicTree:
    import yourdfpy  # slow import (trimesh); only needed here

    _check_xml(path)
    try:
        model = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=False,
                                   load_collision_meshes=False,
                                   build_collision_scene_graph=False)
    except (ValueError, KeyError, AttributeError, TypeError, IndexError) as e:
        raise InputError(f"cannot parse the URDF ({type(e).__name__}: {e})", path,
                         fix=_URDF_FIX) from e
    robot = model.robot
    for joint in robot.joints:
        if not joint.name or not joint.parent or not joint.child:
            raise InputError("a <joint> lacks its name, <parent> or <child>", path, fix=_URDF_FIX)
    if not robot.links:
        raise InputError("the URDF has no <link>", path, fix=_URDF_FIX)
    try:
        broken = _broken_mimics(robot.joints, path)
        joints = tuple(_joint_model(j, path, j.name in broken) for j in robot.joints)
    except InputError as e:
        if e.path is not None:
            raise
        raise InputError(e.problem, path, e.fix) from e
    return KinematicTree(name=robot.name or path.stem, links=tuple(lk.name for lk in robot.links),
                         joints=joints, source=path)
