"""Whether two robot references mean the same robot: by URDF content, not by how they are named.

A model names the robot it was trained on as it was given to training: a built-in name
(`panda`) or a URDF path (`/home/me/med7.urdf`); it may carry the SHA-256 of that URDF's text.
The robot a command uses is a `Robot` (its name is the registry's or the URDF's own `<robot
name>`). The two are the same robot when their URDF files have the same content; when the
model's URDF cannot be read here and it carries no hash, when the model's name (or its file
name without suffix) is the robot's name or its URDF's file name.
"""

from __future__ import annotations

import hashlib
import logging
import re
from dataclasses import dataclass
from pathlib import Path

from dream.errors import DreamError, InputError
from dream.robot.registry import builtin_robots, urdf_path_of
from dream.robot.robot import Robot

log = logging.getLogger(__name__)

_SHA256 = re.compile(r"[0-9a-f]{64}")


def same_robot_name(a: str, b: str) -> bool:
    """Whether two robot references (built-in names or URDF paths) name the same robot: equal;
    where both URDFs can be read here, of the same content; else of the same file name
    without suffix (a URDF's path on another machine, or a built-in robot's URDF).

    >>> same_robot_name("/a/z1.urdf", "/b/z1.urdf"), same_robot_name("panda", "/a/z1.urdf")
    (True, False)
    """
    if a == b:
        return True
    hashes = robot_urdf_sha256(a), robot_urdf_sha256(b)
    if None not in hashes:
        return hashes[0] == hashes[1]
    return Path(a).stem == Path(b).stem


def urdf_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a URDF file's bytes.

    Raises:
        InputError: the file cannot be read.
    """
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        raise InputError(f"cannot read the URDF ({exc.strerror})", path,
                         "check that the URDF file exists and is readable") from None


def robot_urdf_sha256(name_or_urdf: str | Path) -> str | None:
    """SHA-256 of the URDF of a built-in name or URDF path; None when there is none to read."""
    try:
        return urdf_sha256(urdf_path_of(name_or_urdf))
    except DreamError:
        return None


@dataclass(frozen=True)
class TrainedRobot:
    """The robot a model says it was trained on.

    Attributes:
        name: a built-in robot name or a URDF path, as training was given it.
        urdf_sha256: SHA-256 (hex) of that URDF's bytes, when the model carries it.
    """

    name: str
    urdf_sha256: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"a trained-on robot needs a name, got {self.name!r}")
        if self.urdf_sha256 is not None and not _SHA256.fullmatch(str(self.urdf_sha256)):
            raise InputError(f"a URDF hash must be 64 hex digits, got {self.urdf_sha256!r}")


def describe(robot: Robot) -> str:
    """'built-in robot NAME' or "robot 'NAME' (URDF PATH)"."""
    builtin = {e.name: e for e in builtin_robots()}
    if robot.name in builtin and _same_file(builtin[robot.name].urdf_path, robot.urdf_path):
        return f"built-in robot '{robot.name}'"
    return f"robot '{robot.name}' (URDF {robot.urdf_path})"


def _describe_name(name: str) -> str:
    builtin = name.strip().lower() in {e.name for e in builtin_robots()}
    return f"built-in robot '{name}'" if builtin else f"robot '{name}'"


def _same_file(a: Path, b: Path) -> bool:
    try:
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


def _names_match(name: str, robot: Robot) -> bool:
    own = {robot.name.lower(), Path(robot.urdf_path).stem.lower()}
    return name.strip().lower() in own or Path(name).stem.lower() in own


def robot_difference(trained: TrainedRobot, robot: Robot) -> str | None:
    """None when the model's robot is `robot`; otherwise one sentence saying what differs."""
    try:
        used = urdf_sha256(robot.urdf_path)
    except InputError:
        used = None
    theirs = trained.urdf_sha256 or robot_urdf_sha256(trained.name)
    if theirs is not None and used is not None:
        if theirs == used:
            return None
        what = ("the URDF hash the model carries differs from that URDF's" if
                trained.urdf_sha256 else "their URDFs differ in content")
        return (f"the model was trained on {_describe_name(trained.name)}, but the robot used is "
                f"{describe(robot)}: {what}")
    if _names_match(trained.name, robot):
        log.debug("the model's robot %r cannot be read here; its name matches %s", trained.name,
                  describe(robot))
        return None
    return (f"the model was trained on {_describe_name(trained.name)}, but the robot used is "
            f"{describe(robot)}")

