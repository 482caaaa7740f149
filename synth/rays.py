"""Ray queries through a MuJoCo scene: the first geom between the camera and each keypoint."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

from dream.transforms import invert_T
from synth.gl import mujoco
from synth.scene import RobotScene


def keypoint_ray_hits(scene: RobotScene, data: mujoco.MjData, P_cam: np.ndarray,
                      T_cam_base: np.ndarray, groups: np.ndarray,
                      distractor_geoms: Collection[int] = ()
                      ) -> tuple[list[str | None], np.ndarray, np.ndarray]:
    """For each keypoint at `P_cam` (K, 3), the first geom of the shown `groups` (6,) that a
    ray from the camera centre towards it meets, in `synth.labels.keypoint_labels`' form:
    (URDF link hit or None, (K,) bool hit one of `distractor_geoms`, (K,) distance m, inf
    where nothing was hit). `data` must hold the kinematics of the state to query."""
    T_base_cam = invert_T(T_cam_base)
    origin = T_base_cam[:3, 3].copy()
    groups = np.asarray(groups, np.uint8)
    links, distractor, distance = [], [], []
    geom_id = np.zeros(1, np.int32)
    for P in np.asarray(P_cam, dtype=float):
        direction = T_base_cam[:3, :3] @ (P / np.linalg.norm(P))
        d = mujoco.mj_ray(scene.model, data, origin, direction, groups, 1, -1, geom_id)
        g = int(geom_id[0])
        hit = d >= 0 and g >= 0
        distance.append(d if hit else np.inf)
        link = int(scene.geom_link_index[g]) if hit else 0
        links.append(scene.link_names[link - 1] if link > 0 else None)
        distractor.append(hit and g in distractor_geoms)
    return links, np.array(distractor, dtype=bool), np.array(distance)
