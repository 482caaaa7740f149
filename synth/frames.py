"""One synthetic frame: apply its randomisation to the MuJoCo scene, render, label.

`FrameMaker.make(index)` depends only on (seed, index): every randomised model field is set
for every frame, so the order in which a process renders frames does not matter.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from dream.extended import extended_robot, joint_offset_vector
from dream.extension import ModelExtension
from dream.robot import Robot, load_robot
from dream.transforms import R_from_quaternion_xyzw, invert_T, quaternion_xyzw_from_R
from synth.cable import cable_in_base
from synth.config import SynthConfig
from synth.exposure import exposure_times, mean_exposure
from synth.extension import (
    held_reading_time,
    normalised,
    true_camera,
    true_keypoints_cam,
    true_pose,
)
from synth.gl import mujoco
from synth.hand import SLOTS as HAND_SLOTS
from synth.hand import hand_shapes
from synth.labels import keypoint_labels
from synth.nominal import nominal_camera
from synth.other_robot import OtherRobotGeoms
from synth.person import SLOTS as PERSON_SLOTS
from synth.person import person_shapes
from synth.randomize import (
    DistractorDraw,
    FrameDraw,
    load_joint_log,
    sample_frame,
    trajectory_joints_at,
)
from synth.rays import keypoint_ray_hits
from synth.realism import sensor_effects
from synth.render import BACKGROUND_GEOM, RenderOutput, RenderSettings, SceneRenderer
from synth.rendered import RenderedFrame
from synth.scene import RobotScene, build_scene
from synth.scene_settings import MAX_LIGHTS, SceneSettings
from synth.scene_spec import ROBOT_GROUP
from synth.textures import calibration_board, list_photos, random_texture, read_plate

log = logging.getLogger(__name__)

NUM_TEXTURES = 4                # randomisable distractor textures in the scene
FLOOR_TEXTURE_PX = 64           # redrawn and uploaded every frame, so kept small (tiled)
FLOOR_MIN_CAMERA_HEIGHT_M = 0.02  # below this the floor is hidden (it would hide the robot)
HEADLIGHT_DIFFUSE = 0.15        # a little light from the camera, so no frame is black
PARKED_Z_M = -100.0             # unused distractors wait here, out of every view
GEOM_TYPES = {"box": mujoco.mjtGeom.mjGEOM_BOX, "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
              "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
              "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
              "ellipsoid": mujoco.mjtGeom.mjGEOM_ELLIPSOID}


def _primitive_size(kind: str, size: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """MuJoCo size (3,), bounding radius and half-extents of the axis-aligned box in the
    geom frame, for a primitive drawn with half-sizes `size`."""
    a, b, c = size
    if kind == "sphere":
        return np.array([a, 0, 0]), a, np.full(3, a)
    if kind in ("cylinder", "capsule"):
        cap = a if kind == "capsule" else 0.0
        return np.array([a, b, 0]), float(np.hypot(a, b) + cap), np.array([a, a, b + cap])
    return np.array([a, b, c]), float(np.linalg.norm(size)), np.array([a, b, c])


def other_robot_of(robot: Robot, config: SynthConfig) -> Robot | None:
    """The robot drawn as a distractor (`distractors.robot_name`; None: `robot` itself), or None
    when the recipe never shows one, whole or in loose parts."""
    dc = config.distractors
    if dc.robot_prob <= 0 and dc.loose_prob <= 0:
        return None
    return robot if dc.robot_name is None else load_robot(dc.robot_name)


def hand_geoms(scene: RobotScene) -> np.ndarray:
    """The robot geoms of the last keypoint's link and of every link below it."""
    tree, hand = scene.robot.tree, scene.robot.keypoint_names[-1]
    links = [i + 1 for i, link in enumerate(scene.link_names)
             if link == hand or tree.is_ancestor(hand, link)]
    return scene.robot_geom_ids[np.isin(scene.geom_link_index[scene.robot_geom_ids], links)]


class FrameMaker:
    """Renders and labels frames of one robot under one recipe and seed.

    With a model extension (`synth.extension`) the scene, the camera and the labels are those
    of the true world it describes, and the written joints and camera the nominal ones.
    """

    def __init__(self, robot: Robot, config: SynthConfig, seed: int,
                 extension: ModelExtension | None = None) -> None:
        self.robot, self.config, self.seed = robot, config, seed
        self.extension = normalised(extension)
        self.true_robot = robot if self.extension is None else \
            extended_robot(robot, self.extension)
        self.joint_offsets = np.zeros(robot.num_joints) if self.extension is None else \
            joint_offset_vector(robot, self.extension.joint_offset_rad)
        dc = config.distractors
        # the distractor slots: the recipe's own, then the held assembly's parts, then the
        # cable's capsules, then the person's shapes, then the dexterous hand's
        self.regular_slots = dc.count[1]
        self.held_slots = dc.held_parts[1] if dc.held_prob > 0 else 0
        self.cable_slots = dc.cable_segments if dc.cable_prob > 0 else 0
        self.person_slots = PERSON_SLOTS if dc.person_prob > 0 else 0
        self.hand_slots = HAND_SLOTS if dc.hand_prob > 0 else 0
        options = SceneSettings(num_lights=min(MAX_LIGHTS, config.lights.count[1]),
                                num_distractors=self.regular_slots + self.held_slots
                                + self.cable_slots + self.person_slots + self.hand_slots,
                                num_textures=NUM_TEXTURES,
                                texture_size=config.background.texture_size, floor=True,
                                floor_texture_size=FLOOR_TEXTURE_PX)
        self.other_robot = other_robot_of(robot, config)
        self.scene: RobotScene = build_scene(
            self.true_robot, options, other_robot=self.other_robot,
            link_geometry=() if self.extension is None else self.extension.link_geometry)
        self.other_geoms = None if self.other_robot is None else \
            OtherRobotGeoms.from_model(self.scene.model, self.other_robot)
        self.nominal_camera = nominal_camera(config, seed)
        self.renderer = SceneRenderer(self.scene, self.nominal_camera, RenderSettings(
            shadows=config.lights.shadow_prob > 0))
        self.joint_log = load_joint_log(config.joints.log, robot) if config.joints.log else None
        self.photos = list_photos(config.background.photos) if config.background.photos else ()
        self.plate = None if config.background.plate is None else read_plate(config)
        model = self.scene.model
        self.default_rgba = self.scene.default_geom_rgba[self.scene.robot_geom_ids].copy()
        self.distractor_set = set(self.scene.distractor_geom_ids.tolist())
        if self.scene.floor_geom_id >= 0:
            self.distractor_set.add(int(self.scene.floor_geom_id))
        if self.other_geoms is not None:
            self.distractor_set.update(self.other_geoms.geom_ids.tolist())
        self.hand_geoms = hand_geoms(self.scene)
        self.floor_group = int(model.geom_group[self.scene.floor_geom_id])
        self.hidden_group = int(np.flatnonzero(self.renderer.options.geom_groups() == 0)[-1])
        self.ray_groups = np.asarray(self.renderer.options.geom_groups(), np.uint8)

    def close(self) -> None:
        self.renderer.close()

    def params(self, index: int) -> FrameDraw:
        return sample_frame(self.seed, index, self.robot, self.config, self.default_rgba,
                            len(self.scene.light_ids),
                            self.regular_slots,
                            len(self.scene.texture_ids), self.joint_log, self.other_robot)

    # ----- applying the randomisation --------------------------------------------------------

    def _apply_lights(self, p: FrameDraw) -> None:
        model = self.scene.model
        for slot, light_id in enumerate(self.scene.light_ids):
            on = slot < len(p.scene.lights)
            model.light_active[light_id] = on
            if on:
                light = p.scene.lights[slot]
                model.light_pos[light_id] = light.position_m
                aim = np.asarray(self.config.camera.target_m) - light.position_m
                model.light_dir[light_id] = aim / np.linalg.norm(aim)
                model.light_diffuse[light_id] = light.diffuse
                model.light_specular[light_id] = light.specular
                model.light_ambient[light_id] = 0.0
            model.light_castshadow[light_id] = on and slot == 0 and p.scene.shadows
        model.vis.headlight.ambient[:] = p.scene.ambient
        model.vis.headlight.diffuse[:] = HEADLIGHT_DIFFUSE
        model.vis.headlight.specular[:] = 0.0

    def _apply_robot(self, p: FrameDraw) -> None:
        model, scene = self.scene.model, self.scene
        rgba = self.default_rgba if p.scene.robot_rgba is None else p.scene.robot_rgba
        model.geom_rgba[scene.robot_geom_ids] = rgba
        model.mat_specular[scene.robot_material_id] = p.scene.robot_specular
        model.mat_shininess[scene.robot_material_id] = p.scene.robot_shininess
        model.geom_group[self.hand_geoms] = self.hidden_group if p.scene.hide_hand else \
            ROBOT_GROUP
        if self.other_geoms is not None:
            self.other_geoms.apply(model, p.scene.other_robot)

    def _apply_textures(self, p: FrameDraw) -> None:
        model, scene = self.scene.model, self.scene
        rng = np.random.default_rng(p.scene.texture_seed)
        kinds = {k: w for k, w in self.config.background.kinds.items() if k != "photo"}
        held = p.scene.held
        shapes = p.scene.distractors + (held.parts if held else ())
        used = {d.texture for d in shapes if d.texture >= 0}
        board = held.parts[0].texture if held is not None and held.checkerboard else None
        textures = [(t, int(scene.texture_ids[t])) for t in sorted(used)]
        if p.scene.floor and scene.floor_texture_id >= 0:
            textures.append((-1, int(scene.floor_texture_id)))
        for slot, tex in textures:
            h, w = int(model.tex_height[tex]), int(model.tex_width[tex])
            n = int(model.tex_nchannel[tex])
            image = calibration_board(rng, h, w) if slot == board else \
                random_texture(rng, h, w, kinds)
            adr = int(model.tex_adr[tex])
            model.tex_data[adr:adr + h * w * n] = image[..., :n].reshape(-1)
            self.renderer.upload_texture(tex)

    def _held_shapes(self, p: FrameDraw, q_true: np.ndarray) -> list[DistractorDraw | None]:
        """The held assembly's parts with their poses moved from the link's frame to the base
        frame, None for each unused slot."""
        held = p.scene.held
        if held is None:
            return [None] * self.held_slots
        T_base_link = self.true_robot.link_poses(q_true, held.link)[0]
        shapes: list[DistractorDraw | None] = []
        for part in held.parts:
            R_link_object = R_from_quaternion_xyzw(np.roll(part.quaternion_wxyz, -1))
            R_base_object = T_base_link[:3, :3] @ R_link_object
            shapes.append(dataclasses.replace(
                part, position_m=T_base_link[:3, :3] @ part.position_m + T_base_link[:3, 3],
                quaternion_wxyz=np.roll(quaternion_xyzw_from_R(R_base_object), 1)))
        return shapes + [None] * (self.held_slots - len(shapes))

    def _cable_shapes(self, p: FrameDraw, q_true: np.ndarray) -> list[DistractorDraw | None]:
        """The cable's capsules in the base frame at joints `q_true`, None for each slot
        without one."""
        cable = p.scene.cable
        if cable is None:
            return [None] * self.cable_slots
        T_base_links = self.true_robot.link_poses(q_true, cable.links)
        return [DistractorDraw("capsule", np.array([cable.radius_m, half, 0.0]), centre,
                               quaternion, cable.rgba, -1)
                for centre, quaternion, half in cable_in_base(cable, T_base_links,
                                                              self.cable_slots)]

    def _person_shapes(self, p: FrameDraw, q_true: np.ndarray) -> list[DistractorDraw | None]:
        """The person's shapes in the base frame at joints `q_true`, None for each slot
        without one."""
        person = p.scene.person
        if person is None:
            return [None] * self.person_slots
        T_base_link = self.true_robot.link_poses(q_true, person.link)[0]
        return [DistractorDraw(kind, size, centre, quaternion, rgba, -1)
                for kind, size, centre, quaternion, rgba in person_shapes(person, T_base_link)]

    def _hand_shapes(self, p: FrameDraw, q_true: np.ndarray) -> list[DistractorDraw | None]:
        """The dexterous hand's shapes in the base frame at joints `q_true` and the frame's
        time, None for each slot without one."""
        hand = p.scene.hand
        if hand is None:
            return [None] * self.hand_slots
        T_base_link = self.true_robot.link_poses(q_true, hand.link)[0]
        return [DistractorDraw(kind, size, centre, quaternion, rgba, -1)
                for kind, size, centre, quaternion, rgba in
                hand_shapes(hand, T_base_link, p.timestamp or 0.0)]

    def _apply_distractors(self, p: FrameDraw, q_true: np.ndarray) -> None:
        model, scene = self.scene.model, self.scene
        shapes: list[DistractorDraw | None] = list(p.scene.distractors)
        shapes += [None] * (self.regular_slots - len(shapes))
        shapes += self._held_shapes(p, q_true)
        shapes += self._cable_shapes(p, q_true)
        shapes += self._person_shapes(p, q_true)
        shapes += self._hand_shapes(p, q_true)
        for body, geom, d in zip(scene.distractor_body_ids, scene.distractor_geom_ids, shapes,
                                 strict=True):
            if d is None:
                model.body_pos[body] = [0.0, 0.0, PARKED_Z_M]
                continue
            size, rbound, half = _primitive_size(d.kind, d.size_m)
            model.body_pos[body] = d.position_m
            model.body_quat[body] = d.quaternion_wxyz
            model.geom_type[geom] = GEOM_TYPES[d.kind]
            model.geom_size[geom] = size
            model.geom_rbound[geom] = rbound
            model.geom_aabb[geom] = np.concatenate([np.zeros(3), half])
            model.geom_rgba[geom] = d.rgba
            model.geom_matid[geom] = scene.material_ids[d.texture] if d.texture >= 0 else -1

    def _apply_floor(self, p: FrameDraw) -> None:
        if self.scene.floor_geom_id < 0:
            return
        camera_z = invert_T(p.scene.T_cam_base)[2, 3]
        show = p.scene.floor and camera_z > FLOOR_MIN_CAMERA_HEIGHT_M
        self.scene.model.geom_group[self.scene.floor_geom_id] = \
            self.floor_group if show else self.hidden_group

    # ----- rendering and labels ------------------------------------------------------------------

    def _true_state(self, p: FrameDraw) -> tuple[FrameDraw, np.ndarray, np.ndarray]:
        """(the parameters with the true extrinsic, the true joints (J,), the written joint
        readings (J,)) of a frame; without an extension the parameters as drawn."""
        if self.extension is None:
            return p, p.joints, p.joints
        T_true = true_pose(p.scene.T_cam_base, p.index, self.extension)
        readings = p.joints
        tau = self.extension.time_offset_s or 0.0
        held = self.extension.held_readings
        if tau or held is not None:  # the readings lag the images, or are held (trajectory)
            readings = trajectory_joints_at(self.seed, p.timestamp - tau, self.robot,
                                            self.config, self.joint_log)
        if held is not None:
            sampled = trajectory_joints_at(
                self.seed, held_reading_time(p.timestamp, self.extension) - tau, self.robot,
                self.config, self.joint_log)
            columns = held.columns(self.robot.joint_names)
            readings = readings.copy()
            readings[columns] = sampled[columns]
        p = dataclasses.replace(p, scene=dataclasses.replace(p.scene, T_cam_base=T_true))
        return p, p.joints + self.joint_offsets, readings

    def _joints_at(self, t: float) -> np.ndarray:
        """The true joints (J,) of the trajectory at time `t`, s."""
        return trajectory_joints_at(self.seed, t, self.robot, self.config,
                                    self.joint_log) + self.joint_offsets

    def _pose_scene(self, p: FrameDraw, q_true: np.ndarray) -> None:
        """The arm at joints `q_true`, the held, carried and attached shapes with it."""
        self._apply_distractors(p, q_true)
        extra = {name: self.config.joints.extra for name in self.scene.extra_joint_names}
        self.renderer.set_state(q_true, p.scene.T_cam_base, extra)

    def _render_rgb(self, p: FrameDraw, q_true: np.ndarray,
                    depth: bool = False) -> tuple[RenderOutput, np.ndarray]:
        """Render at joints `q_true` (`_pose_scene`): the output and its (H, W, 3) colours
        with the background filled in."""
        self._pose_scene(p, q_true)
        out = self.renderer.render(rgb=True, segmentation=True, depth=depth)
        rgb = out.rgb.copy()
        background = out.geom_ids == BACKGROUND_GEOM
        if background.any():
            camera = p.scene.camera
            bg = self.plate if self.plate is not None else random_texture(
                np.random.default_rng(p.scene.background_seed), camera.height, camera.width,
                self.config.background.kinds, self.photos)
            rgb[background] = bg[background]
        return out, rgb

    def _exposed(self, p: FrameDraw, q_true: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        """The frame's colours over the shutter's exposure (`synth.exposure`): `rgb`, rendered
        at the middle, where the recipe sets no exposure."""
        sensor = self.config.sensor
        if not sensor.exposure_s:
            return rgb
        times = exposure_times(float(p.timestamp), sensor.exposure_s, sensor.exposure_samples)
        images = [rgb if t == p.timestamp else self._render_rgb(p, self._joints_at(t))[1]
                  for t in times]
        self._pose_scene(p, q_true)   # back at the middle, where the labels' rays are cast
        return mean_exposure(images)

    def make(self, index: int) -> RenderedFrame:
        p, q_true, readings = self._true_state(self.params(index))
        self._apply_lights(p)
        self._apply_robot(p)
        self._apply_textures(p)
        self._apply_floor(p)
        camera = p.scene.camera                       # the written (nominal) intrinsics
        render_camera = true_camera(camera, self.extension)
        self.renderer.set_camera(render_camera)
        out, rgb = self._render_rgb(p, q_true, depth=self.config.output.depth)
        rgb = sensor_effects(self._exposed(p, q_true, rgb), self.seed, index, self.config)
        P_cam = true_keypoints_cam(self.true_robot, q_true, p.scene.T_cam_base, self.extension)
        hits = keypoint_ray_hits(self.scene, self.renderer.data, P_cam, p.scene.T_cam_base,
                                 self.ray_groups, self.distractor_set)
        labels = keypoint_labels(self.robot, P_cam, render_camera, *hits)
        return RenderedFrame(index=index, rgb=rgb, link_ids=out.link_ids, depth=out.depth,
                             camera=camera, T_cam_base=p.scene.T_cam_base, joints=readings,
                             P_cam=labels.P_cam, uv=labels.uv, in_frame=labels.in_frame,
                             occlusion=labels.occlusion, timestamp=p.timestamp)
