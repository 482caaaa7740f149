"""A robot's URDF as a MuJoCo scene for rendering: `build_scene` -> `RobotScene`.

Frames: the MuJoCo world frame is the robot base frame; every link body's frame equals the
URDF link frame (`Robot.link_poses`) for the joint values given to `RobotScene.set_joints`.
Only kinematics and rendering are meant: gravity and contacts are off.

Compiled models are cached on disk (`synth.scene_cache`); `build_scene` returns a fresh
`MjModel` on every call, so callers may change its fields (colours, poses, textures) freely.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dream.arrays import read_only
from dream.errors import RobotError
from dream.robot import Robot
from dream.robot.link_geometry import LinkGeometry, extended_visuals
from dream.robot.visuals import MESH, read_link_visuals
from synth import scene_cache
from synth.gl import mujoco
from synth.scene_settings import SceneSettings
from synth.scene_spec import (
    CAMERA_NAME,
    DISTRACTOR_PREFIX,
    FLOOR_NAME,
    JOINT_PREFIX,
    LIGHT_PREFIX,
    LINK_PREFIX,
    MARKER_PREFIX,
    MATERIAL_PREFIX,
    ROBOT_MATERIAL,
    TEXTURE_PREFIX,
    VISUAL_PREFIX,
    build_spec,
)

__all__ = ["RobotScene", "SceneSettings", "build_scene"]

logger = logging.getLogger(__name__)


def _frozen(a, dtype: type = np.int32) -> np.ndarray:
    """Read-only ids (int32 unless told otherwise)."""
    return read_only(a, dtype)


def _id(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    return mujoco.mj_name2id(model, kind, name)


def _ids(model: mujoco.MjModel, kind: mujoco.mjtObj, prefix: str, count: int) -> np.ndarray:
    ids = [_id(model, kind, f"{prefix}{i}") for i in range(count)]
    if any(i < 0 for i in ids):
        raise RobotError(f"the model lacks some '{prefix}N' elements; build it with build_scene")
    return _frozen(ids)


@dataclass(frozen=True, eq=False)
class RobotScene:
    """A compiled robot scene and the indices a renderer or randomiser needs.

    Attributes:
        model: the MuJoCo model (world frame = robot base frame). Mutable: callers may change
            geom colours, body poses, lights, textures.
        robot: the robot it was built from.
        options: the options it was built with.
    Derived (read-only int32 arrays unless said otherwise):
        link_names: every URDF link in URDF order (`robot.link_names`); a link's label is its
            index here + 1.
        link_body_ids: (len(link_names),) MuJoCo body of each link, -1 for links above the
            base (not in the scene).
        robot_geom_ids: (G,) geoms of the robot's visuals.
        geom_link_index: (ngeom,) link index + 1 of each robot visual geom, 0 for every other
            geom (markers, floor, distractors).
        marker_geom_ids: (K,) marker sphere of each keypoint, or (0,) without markers.
        distractor_body_ids, distractor_geom_ids: (D,) each distractor's body and box geom.
        light_ids: (L,) the randomisable lights.
        texture_ids, material_ids: (T,) the randomisable 2D textures and their materials.
        floor_geom_id, floor_material_id, floor_texture_id: ints, -1 without a floor.
        robot_material_id: the material shared by every robot geom (specular, shininess).
        camera_id: the fixed world camera renderers place.
        default_geom_rgba: (ngeom, 4) float32 copy of the built colours.
        joint_qpos_adr: (J,) qpos address of each of `robot.joint_names`.
        extra_joint_names: tuple of the other independent (non-mimic) moving joints below the
            base, e.g. a gripper's fingers; set through `set_joints(..., extra=...)`.
        extra_qpos_adr: (E,) their qpos addresses.
        extra_rest: (E,) float, their default values (0 clipped into the limits).
    """

    model: mujoco.MjModel
    robot: Robot
    options: SceneSettings
    link_names: tuple[str, ...] = field(init=False)
    link_body_ids: np.ndarray = field(init=False, repr=False)
    robot_geom_ids: np.ndarray = field(init=False, repr=False)
    geom_link_index: np.ndarray = field(init=False, repr=False)
    marker_geom_ids: np.ndarray = field(init=False, repr=False)
    distractor_body_ids: np.ndarray = field(init=False, repr=False)
    distractor_geom_ids: np.ndarray = field(init=False, repr=False)
    light_ids: np.ndarray = field(init=False, repr=False)
    texture_ids: np.ndarray = field(init=False, repr=False)
    material_ids: np.ndarray = field(init=False, repr=False)
    floor_geom_id: int = field(init=False)
    floor_material_id: int = field(init=False)
    robot_material_id: int = field(init=False)
    floor_texture_id: int = field(init=False)
    camera_id: int = field(init=False)
    default_geom_rgba: np.ndarray = field(init=False, repr=False)
    joint_qpos_adr: np.ndarray = field(init=False, repr=False)
    extra_joint_names: tuple[str, ...] = field(init=False)
    extra_qpos_adr: np.ndarray = field(init=False, repr=False)
    extra_rest: np.ndarray = field(init=False, repr=False)
    _joint_qpos_adr_all: np.ndarray = field(init=False, repr=False)
    _source_index: np.ndarray = field(init=False, repr=False)
    _multiplier: np.ndarray = field(init=False, repr=False)
    _offset: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.model, mujoco.MjModel):
            raise RobotError("RobotScene.model must be a mujoco.MjModel (use build_scene)")
        if not isinstance(self.robot, Robot) or not isinstance(self.options, SceneSettings):
            raise RobotError("RobotScene needs a dream Robot and SceneSettings (use build_scene)")
        self._index_elements()
        self._index_joints()

    def _set(self, name: str, value) -> None:
        object.__setattr__(self, name, value)

    def _index_elements(self) -> None:
        """Find every element by its name (see `synth.scene_spec`)."""
        m, obj, opt = self.model, mujoco.mjtObj, self.options
        links = tuple(self.robot.link_names)
        self._set("link_names", links)
        self._set("link_body_ids", _frozen([_id(m, obj.mjOBJ_BODY, LINK_PREFIX + k)
                                            for k in links]))
        if self.link_body_ids[links.index(self.robot.base_link)] < 0:
            raise RobotError("the model has no body for the base link; build it with build_scene")
        body_link = {int(b): i for i, b in enumerate(self.link_body_ids) if b >= 0}
        robot_geoms, link_index = [], np.zeros(m.ngeom, dtype=np.int32)
        for g in range(m.ngeom):
            name = mujoco.mj_id2name(m, obj.mjOBJ_GEOM, g) or ""
            if name.startswith(VISUAL_PREFIX):
                robot_geoms.append(g)
                link_index[g] = body_link[int(m.geom_bodyid[g])] + 1
        self._set("robot_geom_ids", _frozen(robot_geoms))
        self._set("geom_link_index", _frozen(link_index))
        markers = [_id(m, obj.mjOBJ_GEOM, MARKER_PREFIX + k) for k in self.robot.keypoint_names]
        if opt.keypoint_markers and any(i < 0 for i in markers):
            raise RobotError("the model lacks keypoint markers; build it with build_scene")
        self._set("marker_geom_ids", _frozen(markers if opt.keypoint_markers else []))
        self._set("distractor_body_ids", _ids(m, obj.mjOBJ_BODY, DISTRACTOR_PREFIX,
                                              opt.num_distractors))
        self._set("distractor_geom_ids", _ids(m, obj.mjOBJ_GEOM, DISTRACTOR_PREFIX,
                                              opt.num_distractors))
        self._set("light_ids", _ids(m, obj.mjOBJ_LIGHT, LIGHT_PREFIX, opt.num_lights))
        self._set("texture_ids", _ids(m, obj.mjOBJ_TEXTURE, TEXTURE_PREFIX, opt.num_textures))
        self._set("material_ids", _ids(m, obj.mjOBJ_MATERIAL, MATERIAL_PREFIX,
                                       opt.num_textures))
        self._set("floor_geom_id", _id(m, obj.mjOBJ_GEOM, FLOOR_NAME))
        self._set("floor_material_id", _id(m, obj.mjOBJ_MATERIAL, FLOOR_NAME))
        self._set("robot_material_id", _id(m, obj.mjOBJ_MATERIAL, ROBOT_MATERIAL))
        self._set("floor_texture_id", _id(m, obj.mjOBJ_TEXTURE, FLOOR_NAME))
        if opt.floor and min(self.floor_geom_id, self.floor_material_id,
                             self.floor_texture_id) < 0:
            raise RobotError("the model lacks its floor; build it with build_scene")
        self._set("camera_id", _id(m, obj.mjOBJ_CAMERA, CAMERA_NAME))
        if self.camera_id < 0:
            raise RobotError("the model lacks its render camera; build it with build_scene")
        self._set("default_geom_rgba", _frozen(m.geom_rgba, np.float32))

    def _index_joints(self) -> None:
        """qpos address and value source of every joint: value = mult * source + offset."""
        m, tree, robot = self.model, self.robot.tree, self.robot
        names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or "" for j in range(m.njnt)]
        urdf_names = [n[len(JOINT_PREFIX):] for n in names]
        in_model = set(urdf_names)
        for n in robot.joint_names:
            if n not in in_model:
                raise RobotError(f"the model lacks joint '{n}'; build it with build_scene")
        extra = tuple(n for n in urdf_names if n not in robot.joint_names
                      and tree.joints[tree.joint_index[n]].mimic is None)
        sources = list(robot.joint_names) + list(extra)
        index, mult, offset = [], [], []
        for n in urdf_names:
            master, k, c = tree.resolve_mimic(n)
            if master in sources:
                index.append(sources.index(master))
                mult.append(k)
                offset.append(c)
            else:  # master outside the scene: stays at its rest value
                index.append(0)
                mult.append(0.0)
                offset.append(k * tree.joints[tree.joint_index[master]].rest_value + c)
        adr = m.jnt_qposadr
        self._set("_joint_qpos_adr_all", _frozen(adr))
        self._set("joint_qpos_adr", _frozen([adr[urdf_names.index(n)]
                                             for n in robot.joint_names]))
        self._set("extra_joint_names", extra)
        self._set("extra_qpos_adr", _frozen([adr[urdf_names.index(n)] for n in extra]))
        self._set("extra_rest", _frozen([tree.joints[tree.joint_index[n]].rest_value
                                         for n in extra], float))
        self._set("_source_index", _frozen(index))
        self._set("_multiplier", _frozen(mult, float))
        self._set("_offset", _frozen(offset, float))

    def joint_values(self, q: np.ndarray, extra: Mapping[str, float] | None = None
                     ) -> np.ndarray:
        """The qpos vector (nq,) for robot joints `q` (J,) and `extra` joint values.

        Mimic joints follow their master; extra joints not given sit at `extra_rest`.

        Raises:
            RobotError: wrong number or non-finite joint values, or an unknown extra joint.
        """
        q = self.robot.validate_joints(q)
        if q.ndim != 1:
            raise RobotError(f"set one joint vector of shape ({self.robot.num_joints},), got "
                             f"shape {q.shape}")
        values = self.extra_rest.copy()
        for name, value in (extra or {}).items():
            if name not in self.extra_joint_names:
                raise RobotError(f"'{name}' is not an extra joint of robot '{self.robot.name}'; "
                                 f"set {', '.join(self.robot.joint_names)} through q and "
                                 f"choose extra joints among: "
                                 f"{', '.join(self.extra_joint_names) or 'none'}")
            if not np.isfinite(value):
                raise RobotError(f"extra joint '{name}' is {value}; give a finite value")
            values[self.extra_joint_names.index(name)] = float(value)
        sources = np.concatenate([q, values])
        qpos = np.zeros(self.model.nq)
        picked = sources[self._source_index] if len(sources) else np.zeros(len(self._offset))
        qpos[self._joint_qpos_adr_all] = self._multiplier * picked + self._offset
        return qpos

    def set_joints(self, data: mujoco.MjData, q: np.ndarray,
                   extra: Mapping[str, float] | None = None) -> None:
        """Write joint values into `data.qpos` and update the kinematics (`mj_kinematics`).

        Args:
            data: an `MjData` of `model`.
            q: (J,) values of `robot.joint_names`, rad or m.
            extra: optional values of `extra_joint_names` (e.g. Panda fingers, m).
        """
        data.qpos[:] = self.joint_values(q, extra)
        mujoco.mj_kinematics(self.model, data)

    def body_pose(self, data: mujoco.MjData, link: str) -> np.ndarray:
        """T_base_link (4, 4) of a link body as MuJoCo computed it (after `set_joints`)."""
        if link not in self.link_names:
            self.robot.tree.check_link(link)
        body = int(self.link_body_ids[self.link_names.index(link)])
        if body < 0:
            raise RobotError(f"link '{link}' lies above base link '{self.robot.base_link}' and "
                             "is not in the scene")
        T = np.eye(4)
        T[:3, :3] = data.xmat[body].reshape(3, 3)
        T[:3, 3] = data.xpos[body]
        return T


def _mesh_files(visuals) -> list[Path]:
    return [v.mesh_path for vs in visuals.values() for v in vs if v.kind == MESH]


def build_scene(robot: Robot, options: SceneSettings | None = None,
                cache_dir: str | Path | None = None, use_cache: bool = True,
                other_robot: Robot | None = None,
                link_geometry: tuple[LinkGeometry, ...] = ()) -> RobotScene:
    """The MuJoCo scene of `robot` (links below its base, visual meshes) plus the extras of
    `options`, from the on-disk cache when possible.

    Args:
        robot: from `dream.robot.load_robot`.
        options: lights, distractors, textures, floor, markers; default `SceneSettings()`.
        cache_dir: folder of cache entries; default `$DREAM_CACHE_DIR/scenes` or
            `~/.cache/dream/scenes`.
        use_cache: read and write the cache.
        other_robot: another robot whose visuals join the scene as a distractor (posed by
            `synth.other_robot.OtherRobotGeoms`).
        link_geometry: boxes added to links, or links scaled (a model extension's
            `link_geometry`, `dream.robot.link_geometry`); they are part of the robot.
    Raises:
        InputError: unreadable URDF or mesh file.
        RobotError: a robot MuJoCo cannot compile (the message says why).
    """
    options = SceneSettings() if options is None else options
    if not isinstance(options, SceneSettings):
        raise RobotError(f"options must be SceneSettings, got {type(options).__name__}")
    start = time.perf_counter()
    visuals = extended_visuals(read_link_visuals(robot.urdf_path), tuple(link_geometry))
    files, described = _mesh_files(visuals), options.as_dict()
    if link_geometry:
        described["link_geometry"] = {g.link: g.to_params() for g in link_geometry}
    other_visuals = None
    if other_robot is not None:
        other_visuals = read_link_visuals(other_robot.urdf_path)
        files += [Path(other_robot.urdf_path)] + _mesh_files(other_visuals)
        described["other_robot"] = f"{other_robot.name}:{other_robot.urdf_path}"
    key, description = scene_cache.scene_key(robot, files, described)
    root = scene_cache.cache_root(cache_dir)
    if use_cache:
        try:
            scene = RobotScene(scene_cache.load_entry(root, key), robot, options)
        except scene_cache.CacheMiss:
            pass
        except RobotError as e:  # an entry that does not fit this robot
            logger.warning("scene cache entry %s does not fit (%s); rebuilding it", key, e)
            scene_cache.remove_entry(root, key)
        else:
            logger.debug("scene %s from cache in %.3f s", key, time.perf_counter() - start)
            return scene
    try:
        model = build_spec(robot, visuals, options, other_visuals).compile()
    except ValueError as e:
        raise RobotError(f"MuJoCo cannot compile the scene of robot '{robot.name}' ({e}); "
                         "check the URDF's visuals and joints") from e
    scene = RobotScene(model, robot, options)
    if use_cache:
        scene_cache.save_entry(root, key, model, description)
    logger.debug("scene %s built in %.3f s", key, time.perf_counter() - start)
    return scene
