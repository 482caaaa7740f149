"""Another robot in the scene, unlabelled: a distractor that looks like the robot being labelled.

Real calibration recordings often show a second arm (a twin cell, a robot in the background).
A keypoint network that never saw one puts the wrist keypoints on it. The scene holds one world
body per link of the other robot (`synth.scene_spec.OTHER_ROBOT_BODY`); each frame moves every
body to its link's pose for the drawn base pose and joints.

Frames: `T_base_other` maps the other robot's base frame into the labelled robot's base frame
(the world); `T_other_link` is a link pose in the other robot's base frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dream.arrays import read_only
from dream.errors import RobotError
from dream.robot import Robot
from dream.transforms import quaternion_xyzw_from_R
from synth.gl import mujoco
from synth.scene_spec import OTHER_ROBOT_BODY

PARKED_Z_M = -100.0   # where the bodies wait while the other robot is not in the frame


@dataclass(frozen=True)
class OtherRobotDraw:
    """One draw of the other robot: base pose (4, 4), joints (J,) in its `joint_names` order,
    one flat colour (4,) for every part (None: its real colours), and the links drawn (None:
    all; loose parts name the end of a chain)."""

    T_base_other: np.ndarray
    joints: np.ndarray
    rgba: np.ndarray | None = None
    links: tuple[str, ...] | None = None


@dataclass(frozen=True, eq=False)
class OtherRobotGeoms:
    """The other robot's bodies and geoms in a compiled scene, and how to place them.

    Attributes:
        robot: the other robot (its kinematics place the links).
        links: (B,) the links that have visuals, one body each.
        body_ids: (B,) their bodies.
        geom_ids: (G,) every geom of those bodies.
        real_rgba: (G, 4) the built colours.
    """

    robot: Robot
    links: tuple[str, ...] = field(repr=False)
    body_ids: np.ndarray = field(repr=False)
    geom_ids: np.ndarray = field(repr=False)
    real_rgba: np.ndarray = field(repr=False)

    @classmethod
    def from_model(cls, model: mujoco.MjModel, robot: Robot) -> OtherRobotGeoms:
        """Find the other robot's bodies by name (`build_scene(..., other_robot=robot)`)."""
        prefix = OTHER_ROBOT_BODY + ":"
        links, bodies = [], []
        for b in range(model.nbody):
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or ""
            if name.startswith(prefix):
                links.append(name[len(prefix):])
                bodies.append(b)
        if not bodies:
            raise RobotError("the scene has no other robot; build it with "
                             "build_scene(..., other_robot=ROBOT)")
        for link in links:
            robot.tree.check_link(link)
        geoms = np.flatnonzero(np.isin(model.geom_bodyid, bodies))
        return cls(robot, tuple(links), read_only(bodies, np.int32), read_only(geoms, np.int32),
                   read_only(model.geom_rgba[geoms], np.float32))

    def apply(self, model: mujoco.MjModel, draw: OtherRobotDraw | None) -> None:
        """Place (or park, for None) the other robot in `model`; `mj_kinematics` follows."""
        if draw is None:
            model.body_pos[self.body_ids] = [0.0, 0.0, PARKED_Z_M]
            return
        T_base_link = draw.T_base_other @ self.robot.link_poses(draw.joints, self.links)
        for link, body, T in zip(self.links, self.body_ids, T_base_link, strict=True):
            if draw.links is not None and link not in draw.links:
                model.body_pos[body] = [0.0, 0.0, PARKED_Z_M]
                continue
            model.body_pos[body] = T[:3, 3]
            model.body_quat[body] = np.roll(quaternion_xyzw_from_R(T[:3, :3]), 1)
        model.geom_rgba[self.geom_ids] = self.real_rgba if draw.rgba is None else draw.rgba
