"""The `mujoco.MjSpec` of a robot scene: URDF links as bodies, visuals as geoms, plus extras.

Frames: the MuJoCo world frame is the robot base frame (the base link is a joint-less body at
the world origin). Each link below the base is a body placed by its parent joint's origin
(`T_parent_joint`), with a hinge (revolute, continuous) or slide (prismatic) joint along the
URDF axis at the body origin; fixed joints give bodies without joints. So a body frame equals
the URDF link frame for every joint value.

Elements are found again by name (`synth.scene.RobotScene`), so a model loaded from the cache needs
nothing else: bodies `link:<link>`, joints `joint:<joint>`, robot geoms
`visual:<link>:<visual>:<part>`, markers `marker:<link>`, distractors `distractor:<i>`, lights
`light:<i>`, textures and materials `texture:<i>` / `material:<i>`, floor `floor`, the
render camera `camera`, and, when asked for, another robot as a distractor: a world body
`other_robot:<link>` per link with visuals, its geoms `other:<link>:<visual>:<part>`, placed by
the caller (`synth.other_robot`).
"""

from __future__ import annotations

import hashlib
import logging
import math
from collections.abc import Mapping

import numpy as np

from dream.robot import Robot
from dream.robot.tree import CONTINUOUS, FIXED, PRISMATIC, ROTATING_TYPES
from dream.robot.visuals import MESH, LinkVisual, load_mesh_parts
from synth.gl import mujoco
from synth.scene_settings import SceneSettings

logger = logging.getLogger(__name__)

LINK_PREFIX = "link:"
JOINT_PREFIX = "joint:"
VISUAL_PREFIX = "visual:"
MARKER_PREFIX = "marker:"
DISTRACTOR_PREFIX = "distractor:"
LIGHT_PREFIX = "light:"
TEXTURE_PREFIX = "texture:"
MATERIAL_PREFIX = "material:"
ROBOT_MATERIAL = "robot"
ROBOT_MATERIAL_RGBA = (0.5, 0.5, 0.5, 1.0)  # MuJoCo's default geom rgba: defaults look alike
FLOOR_NAME = "floor"
CAMERA_NAME = "camera"
OTHER_ROBOT_BODY = "other_robot"
OTHER_PREFIX = "other:"

ROBOT_GROUP = 0  # geom groups, so a renderer can show or hide each kind
FLOOR_GROUP = 1
DISTRACTOR_GROUP = 2
MARKER_GROUP = 3

MARKER_RGBA = (1.0, 0.0, 1.0, 1.0)
FLOOR_RGB1 = (0.45, 0.45, 0.45)
FLOOR_RGB2 = (0.55, 0.55, 0.55)
TEXTURE_RGB1 = (0.3, 0.3, 0.3)
TEXTURE_RGB2 = (0.7, 0.7, 0.7)
DISTRACTOR_RGBA = (0.5, 0.5, 0.5, 1.0)
FLOOR_RGBA = (1.0, 1.0, 1.0, 1.0)  # white: the texture gives the colour
FLOOR_GRID_SPACING_M = 0.1  # plane "size[2]": spacing of the grid MuJoCo renders it with
MIN_MESH_VERTICES = 4  # MuJoCo refuses meshes with fewer vertices


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=float).reshape(9))
    return q


def _short_hash(*items: bytes) -> str:
    h = hashlib.sha1()
    for item in items:
        h.update(item)
    return h.hexdigest()[:16]


def _add_link_body(spec_parent, name: str, T_parent_link: np.ndarray, options: SceneSettings):
    body = spec_parent.add_body(name=LINK_PREFIX + name)
    body.pos = T_parent_link[:3, 3]
    body.quat = _quat_wxyz(T_parent_link[:3, :3])
    body.mass = options.link_mass_kg
    body.inertia = [options.link_inertia_kg_m2] * 3
    body.explicitinertial = True
    return body


def _add_joint(body, joint) -> None:
    if joint.type == FIXED:
        return
    if joint.type in ROTATING_TYPES:
        kind = mujoco.mjtJoint.mjJNT_HINGE
    elif joint.type == PRISMATIC:
        kind = mujoco.mjtJoint.mjJNT_SLIDE
    else:
        logger.warning("joint '%s' of type '%s' is rendered as fixed", joint.name, joint.type)
        return
    j = body.add_joint(name=JOINT_PREFIX + joint.name, type=kind)
    j.axis = joint.axis
    j.pos = [0.0, 0.0, 0.0]
    if joint.type == CONTINUOUS:
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
    else:
        j.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        j.range = [joint.lower, joint.upper]


class _MeshAssets:
    """Adds each distinct mesh part once to the spec and hands back its name."""

    def __init__(self, spec: mujoco.MjSpec) -> None:
        self._spec = spec
        self._names: dict[str, str] = {}

    def add(self, vertices: np.ndarray, faces: np.ndarray) -> str:
        key = _short_hash(vertices.tobytes(), faces.tobytes())
        if key not in self._names:
            mesh = self._spec.add_mesh(name=f"mesh:{key}")
            mesh.uservert = vertices.reshape(-1).tolist()
            mesh.userface = faces.reshape(-1).tolist()
            mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
            self._names[key] = mesh.name
        return self._names[key]


def _geom_common(geom, rgba, group: int) -> None:
    geom.rgba = rgba
    geom.group = group
    geom.contype = 0
    geom.conaffinity = 0
    if group == ROBOT_GROUP:
        # One shared material: its specular/shininess are randomisable, while each geom's own
        # rgba (non-default) keeps overriding the material colour.
        geom.material = ROBOT_MATERIAL


def _add_visuals(body, link: str, visuals: tuple[LinkVisual, ...], meshes: _MeshAssets,
                 options: SceneSettings, prefix: str = VISUAL_PREFIX,
                 group: int = ROBOT_GROUP) -> None:
    primitive = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
                 "sphere": mujoco.mjtGeom.mjGEOM_SPHERE}
    for v_index, visual in enumerate(visuals):
        pos, quat = visual.T_link_visual[:3, 3], _quat_wxyz(visual.T_link_visual[:3, :3])
        fallback = options.default_rgba if visual.rgba is None else visual.rgba
        if visual.kind != MESH:
            geom = body.add_geom(name=f"{prefix}{link}:{v_index}:0",
                                 type=primitive[visual.kind], size=visual.size, pos=pos,
                                 quat=quat)
            _geom_common(geom, fallback, group)
            continue
        for p_index, part in enumerate(load_mesh_parts(visual.mesh_path, visual.mesh_scale)):
            if len(part.vertices) < MIN_MESH_VERTICES:
                logger.debug("%s: skipping a part with %d vertices", visual.mesh_path,
                             len(part.vertices))
                continue
            geom = body.add_geom(name=f"{prefix}{link}:{v_index}:{p_index}",
                                 type=mujoco.mjtGeom.mjGEOM_MESH, pos=pos, quat=quat,
                                 meshname=meshes.add(part.vertices, part.faces))
            _geom_common(geom, fallback if part.rgba is None else part.rgba, group)


def _add_robot(spec: mujoco.MjSpec, robot: Robot,
               visuals: Mapping[str, tuple[LinkVisual, ...]], options: SceneSettings,
               meshes: _MeshAssets) -> None:
    tree = robot.tree
    spec.add_material(name=ROBOT_MATERIAL, rgba=list(ROBOT_MATERIAL_RGBA))
    keypoints = set(robot.keypoint_names) if options.keypoint_markers else set()
    bodies = {robot.base_link: _add_link_body(spec.worldbody, robot.base_link, np.eye(4),
                                              options)}
    children: dict[str, list] = {}
    for joint in tree.joints:
        children.setdefault(joint.parent, []).append(joint)
    stack = [robot.base_link]
    while stack:  # depth first from the base, children in URDF order
        link = stack.pop()
        body = bodies[link]
        _add_visuals(body, link, visuals.get(link, ()), meshes, options)
        if link in keypoints:
            geom = body.add_geom(name=MARKER_PREFIX + link, type=mujoco.mjtGeom.mjGEOM_SPHERE,
                                 size=[options.marker_radius_m, 0.0, 0.0])
            _geom_common(geom, MARKER_RGBA, MARKER_GROUP)
        for joint in children.get(link, ()):
            bodies[joint.child] = _add_link_body(body, joint.child, joint.origin, options)
            _add_joint(bodies[joint.child], joint)
        stack.extend(j.child for j in reversed(children.get(link, ())))


def _add_other_robot(spec: mujoco.MjSpec, visuals: Mapping[str, tuple[LinkVisual, ...]],
                     options: SceneSettings, meshes: _MeshAssets) -> None:
    """Another robot's visuals: one parked world body per link (no joints); the caller moves
    each body to its link's pose every frame."""
    for link, link_visuals in visuals.items():
        if not link_visuals:
            continue
        body = spec.worldbody.add_body(name=f"{OTHER_ROBOT_BODY}:{link}",
                                       pos=[0.0, 0.0, options.distractor_parking_z_m])
        _add_visuals(body, link, link_visuals, meshes, options, OTHER_PREFIX, DISTRACTOR_GROUP)


def _add_extras(spec: mujoco.MjSpec, options: SceneSettings) -> None:
    for i in range(options.num_lights):
        angle = 2.0 * math.pi * i / max(options.num_lights, 1)
        pos = np.array([options.light_radius_m * math.cos(angle),
                        options.light_radius_m * math.sin(angle), options.light_height_m])
        light = spec.worldbody.add_light(name=f"{LIGHT_PREFIX}{i}", pos=pos, dir=-pos,
                                         castshadow=False)
        light.type = mujoco.mjtLightType.mjLIGHT_SPOT
        light.diffuse = [options.light_diffuse] * 3
    for i in range(options.num_distractors):
        body = spec.worldbody.add_body(name=f"{DISTRACTOR_PREFIX}{i}",
                                       pos=[0.0, 0.0, options.distractor_parking_z_m])
        geom = body.add_geom(name=f"{DISTRACTOR_PREFIX}{i}", type=mujoco.mjtGeom.mjGEOM_BOX,
                             size=[options.distractor_half_size_m] * 3)
        _geom_common(geom, DISTRACTOR_RGBA, DISTRACTOR_GROUP)
    for i in range(options.num_textures):
        _add_textured_material(spec, f"{TEXTURE_PREFIX}{i}", f"{MATERIAL_PREFIX}{i}",
                               options.texture_size, TEXTURE_RGB1, TEXTURE_RGB2, 1.0)
    if options.floor:
        _add_textured_material(spec, FLOOR_NAME, FLOOR_NAME, options.floor_texture_size,
                               FLOOR_RGB1, FLOOR_RGB2, options.floor_texture_repeat)
        half = options.floor_half_size_m
        geom = spec.worldbody.add_geom(name=FLOOR_NAME, type=mujoco.mjtGeom.mjGEOM_PLANE,
                                       size=[half, half, FLOOR_GRID_SPACING_M],
                                       material=FLOOR_NAME)
        _geom_common(geom, FLOOR_RGBA, FLOOR_GROUP)


def _add_textured_material(spec: mujoco.MjSpec, texture: str, material: str, size: int,
                           rgb1: tuple, rgb2: tuple, repeat: float) -> None:
    spec.add_texture(name=texture, type=mujoco.mjtTexture.mjTEXTURE_2D,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, width=size, height=size,
                     rgb1=rgb1, rgb2=rgb2)
    mat = spec.add_material(name=material, texrepeat=[repeat, repeat])
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = texture


def build_spec(robot: Robot, visuals: Mapping[str, tuple[LinkVisual, ...]],
               options: SceneSettings,
               other_visuals: Mapping[str, tuple[LinkVisual, ...]] | None = None
               ) -> mujoco.MjSpec:
    """The MjSpec of `robot` below its base link with `visuals` and the extras of `options`,
    plus another robot's visuals (`other_visuals`, by link) as a distractor when given.

    Gravity and contacts are off (kinematics and rendering only); every geom has
    contype = conaffinity = 0.
    """
    spec = mujoco.MjSpec()
    spec.modelname = f"dream_scene_{robot.name}"
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    spec.compiler.autolimits = True
    spec.compiler.degree = False
    spec.option.gravity = [0.0, 0.0, 0.0]
    spec.option.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONTACT
                                 | mujoco.mjtDisableBit.mjDSBL_GRAVITY)
    spec.visual.global_.ipd = 0.0
    meshes = _MeshAssets(spec)
    _add_robot(spec, robot, visuals, options, meshes)
    _add_extras(spec, options)
    if other_visuals:
        _add_other_robot(spec, other_visuals, options, meshes)
    camera = spec.worldbody.add_camera(name=CAMERA_NAME)
    camera.mode = mujoco.mjtCamLight.mjCAMLIGHT_FIXED
    camera.ipd = 0.0
    return spec
