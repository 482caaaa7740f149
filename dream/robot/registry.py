"""Built-in robots (URDFs shipped by example-robot-data) and `load_robot`.

Keypoints are link origins. Principles used to choose them for each arm:
- the base link origin is included: it anchors the extrinsic (it is the origin of `T_cam_base`);
- of link origins that coincide for all joint values (zero-length joint offsets), one is kept:
  coincident keypoints are indistinguishable in an image and add no geometry. As DREAM does for
  the Panda (link2 not link1, link6 not link5, hand not link8), the distal link's name is used;
- origins spread along the arm and lying near visible surfaces are preferred;
- the flange / tool link is included, as it carries the wrist's position and orientation.
The coincidences were checked on the URDFs themselves (forward kinematics at random joints)
and every chosen origin lies within about 5 cm of the visual meshes at the zero pose.
`dream.robot.keypoint_choice` applies these principles to any URDF (`dream robots --urdf FILE`)
and suggests exactly the three sets below.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from dream.errors import InputError, RobotError
from dream.robot.resources import robot_data_dir
from dream.robot.robot import Robot
from dream.robot.urdf import parse_urdf

URDF_SUFFIXES = (".urdf", ".xml")


@dataclass(frozen=True)
class RobotEntry:
    """One built-in robot.

    Attributes:
        name: registry name (dataset `class`).
        urdf: URDF path relative to example-robot-data's folder (`robot_data_dir()`).
        base_link: the robot base frame.
        keypoints: default keypoint links, in order.
        description: one line for `dream robots`.
        rationale: why these keypoints.
    """

    name: str
    urdf: str
    base_link: str
    keypoints: tuple[str, ...]
    description: str
    rationale: str

    def __post_init__(self) -> None:
        if not self.name or self.name != self.name.lower():
            raise RobotError(f"registry name '{self.name}' must be non-empty lower case")
        if Path(self.urdf).is_absolute():
            raise RobotError(f"registry URDF path '{self.urdf}' must be relative")
        if not self.keypoints or len(set(self.keypoints)) != len(self.keypoints):
            raise RobotError(f"robot '{self.name}' needs distinct default keypoints")
        object.__setattr__(self, "keypoints", tuple(self.keypoints))

    @property
    def urdf_path(self) -> Path:
        """Absolute path of the URDF file (InputError when example-robot-data is missing)."""
        return robot_data_dir() / self.urdf


PANDA = RobotEntry(
    name="panda",
    urdf="robots/panda_description/urdf/panda.urdf",
    base_link="panda_link0",
    keypoints=("panda_link0", "panda_link2", "panda_link3", "panda_link4", "panda_link6",
               "panda_link7", "panda_hand"),
    description="Franka Emika Panda, 7-DoF arm with hand (DREAM's robot)",
    rationale="DREAM's published Panda keypoints, kept exactly so that its datasets and models "
              "work: link1/link2, link5/link6 and link8/hand coincide, so one of each is kept.",
)

UR5 = RobotEntry(
    name="ur5",
    urdf="robots/ur_description/urdf/ur5_robot.urdf",
    base_link="base_link",
    keypoints=("base_link", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link",
               "wrist_2_link", "wrist_3_link", "tool0"),
    description="Universal Robots UR5, 6-DoF arm (no gripper)",
    rationale="Every UR5 joint has a non-zero origin offset, so the eight distinct link origins "
              "are all kept: base_link anchors the extrinsic; shoulder_link (0.089 m up the "
              "pan axis) and upper_arm_link (0.136 m sideways, at the shoulder cap) fix the "
              "shoulder; forearm_link (elbow) and wrist_1_link sit at the ends of the 0.425 m "
              "and 0.392 m tubes; wrist_2_link, wrist_3_link and tool0 are 0.08 to 0.095 m "
              "apart, about the Panda's link6-link7 spacing, and together give the wrist's "
              "orientation. Only base (= base_link origin, rotated pi) and ee_link (= tool0 "
              "origin) coincide with chosen origins and are left out; tool0 is the standard "
              "flange frame.",
)

XARM7 = RobotEntry(
    name="xarm7",
    urdf="robots/xarm_description/urdf/xarm7.urdf",
    base_link="link_base",
    keypoints=("link_base", "link2", "link3", "link4", "link6", "link_eef"),
    description="UFactory xArm7, 7-DoF arm (no gripper)",
    rationale="joint2, joint6 and joint_eef have zero origin offsets, so link1 = link2, "
              "link5 = link6 and link7 = link_eef for all joint values; one of each pair is "
              "kept (the distal name, as DREAM does for the Panda), leaving six distinct "
              "origins: link_base anchors the extrinsic, link2 is the shoulder (0.267 m up), "
              "link3 and link4 (0.0525 m apart) the elbow, link6 the wrist after the 0.35 m "
              "forearm, and link_eef the flange (0.12 m further).",
)

_REGISTRY: dict[str, RobotEntry] = {e.name: e for e in (PANDA, UR5, XARM7)}


def builtin_robots() -> tuple[RobotEntry, ...]:
    """The registry entries, for `dream robots`."""
    return tuple(_REGISTRY.values())


def _unknown_robot(name: str) -> RobotError:
    return RobotError(f"unknown robot '{name}'; built-in robots are {', '.join(_REGISTRY)}, "
                      "or pass the path to a .urdf file")


def builtin_robot(name: str) -> RobotEntry:
    """The registry entry of a built-in robot (case-insensitive).

    Raises:
        RobotError: unknown name, listing the built-in robots.
    """
    entry = _REGISTRY.get(name.strip().lower())
    if entry is None:
        raise _unknown_robot(name)
    return entry


def _looks_like_path(text: str) -> bool:
    return Path(text).suffix.lower() in URDF_SUFFIXES or "/" in text or "\\" in text


def is_robot_reference(name_or_urdf: str | Path) -> bool:
    """True when `load_robot` takes `name_or_urdf` for a built-in robot or a URDF path (whether
    or not that file exists and loads): a `RobotError` it raises is then about the keypoints
    or links asked for, not about the name."""
    text = str(name_or_urdf)
    if isinstance(name_or_urdf, Path) or text.strip().lower() in _REGISTRY:
        return True
    return _looks_like_path(text) or Path(text).is_file()


def urdf_path_of(name_or_urdf: str | Path) -> Path:
    """The URDF file of a built-in robot's name or of a URDF path, as `load_robot` reads it.

    Raises:
        RobotError: neither a built-in name nor a URDF path.
        InputError: a URDF path whose file does not exist.
    """
    text = str(name_or_urdf)
    if isinstance(name_or_urdf, str) and text.strip().lower() in _REGISTRY:
        return _REGISTRY[text.strip().lower()].urdf_path
    if not is_robot_reference(name_or_urdf):
        raise _unknown_robot(text)
    path = Path(text).expanduser().resolve()
    if not path.is_file():
        raise InputError("URDF file not found", path,
                         fix="give a built-in robot name or an existing .urdf file")
    return path


def load_robot(name_or_urdf: str | Path, keypoints: Sequence[str] | None = None,
               base_link: str | None = None) -> Robot:
    """A built-in robot by name, or a robot read from a user's URDF file.

    Args:
        name_or_urdf: registry name (`panda`, `ur5`, `xarm7`) or path to a URDF file.
        keypoints: keypoint links; default: the registry's. Required for a user URDF.
        base_link: default: the registry's, or the URDF's root link for a user URDF.
    Raises:
        RobotError: unknown robot, link or missing keypoints for a user URDF.
        InputError: the URDF file is missing or not valid.
    """
    if isinstance(keypoints, str):
        keypoints = (keypoints,)
    key = None if keypoints is None else tuple(keypoints)
    text = str(name_or_urdf)
    if isinstance(name_or_urdf, str) and text.strip().lower() in _REGISTRY:
        return _load_builtin(text.strip().lower(), key, base_link)
    path = urdf_path_of(name_or_urdf)
    return _load_user(path, path.stat().st_mtime_ns, key, base_link)


@functools.lru_cache(maxsize=64)
def _load_builtin(name: str, keypoints: tuple[str, ...] | None,
                  base_link: str | None) -> Robot:
    entry = _REGISTRY[name]
    path = entry.urdf_path
    return Robot(name=entry.name, urdf_path=path, base_link=base_link or entry.base_link,
                 keypoint_names=keypoints if keypoints is not None else entry.keypoints,
                 tree=parse_urdf(path))


@functools.lru_cache(maxsize=64)
def _load_user(path: Path, mtime_ns: int, keypoints: tuple[str, ...] | None,
               base_link: str | None) -> Robot:
    tree = parse_urdf(path)
    if keypoints is None:
        raise RobotError(f"a user URDF needs its keypoint links: pass --keypoints LINK,LINK,... "
                         f"(keypoints= in Python); dream robots --urdf {path} lists its "
                         f"{len(tree.links)} links and suggests keypoints")
    return Robot(name=tree.name, urdf_path=path, base_link=base_link or tree.root,
                 keypoint_names=keypoints, tree=tree)
