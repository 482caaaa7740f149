"""Randomisation aimed at what real recordings show, beyond the DREAM-style scene draws.

- close-up cameras: the camera near one keypoint, so links leave the frame
  (`camera.closeup_prob`, `camera.closeup_radius_m`);
- robot materials: glossy white plastic or brushed metal (`appearance.white_plastic_prob`,
  `appearance.metal_prob`);
- the hand's visuals hidden, so that the flange carries only what the recipe attaches there
  (`appearance.hide_hand_prob`);
- another robot in the scene, unlabelled (`distractors.robot_*`), or loose parts of it: the
  end of its chain (a hand, a wrist) lying or standing near the arm (`distractors.loose_*`).

Each draw comes from its own random stream, keyed by the seed (and the frame index in `random`
mode; per sequence otherwise), so a recipe that leaves them at 0 renders what it rendered
before they existed. Pure functions of (config, random generator, arrays).
"""

from __future__ import annotations

import colorsys
import dataclasses

import cv2
import numpy as np

from dream.robot import Robot
from dream.transforms import R_from_quaternion_xyzw, invert_T, look_at, make_T
from synth.config import SynthConfig
from synth.other_robot import OtherRobotDraw

CLOSEUP_STREAM = 0xC105
MATERIAL_STREAM = 0x3A7
HIDE_HAND_STREAM = 0x41DE
OTHER_ROBOT_STREAM = 0x07E2
LOOSE_PARTS_STREAM = 0x1005E
OTHER_MOTION_STREAM = 0x07E3   # the other robot's joints per frame (`distractors.robot_moves`)
SENSOR_STREAM = 0xE7905

LIGHT_PART_VALUE = 0.5                 # a part this light (HSV value) turns white plastic
WHITE_PLASTIC_VALUE = (0.85, 1.0)
WHITE_PLASTIC_SATURATION = (0.0, 0.05)
WHITE_PLASTIC_SPECULAR = (0.4, 0.9)
WHITE_PLASTIC_SHININESS = (0.5, 1.0)   # tight, bright highlights
METAL_VALUE = (0.45, 0.8)
METAL_SATURATION = (0.0, 0.08)
METAL_SPECULAR = (0.6, 1.0)
METAL_SHININESS = (0.1, 0.5)           # broad highlights, as on a brushed surface
OTHER_ROBOT_AZIMUTH_SPREAD_RAD = 1.0   # around the direction from the camera through the base
FLOOR_Z_M = 0.0                        # the floor's plane (`synth.scene_spec`), base frame
FLOOR_TOLERANCE_M = 0.01               # a link origin this little below it lies in a link
                                       # resting on it
CLOSEUP_MIN_HEIGHT_M = 0.05            # a close-up camera at least this high above the floor
LOOSE_AZIMUTH_SPREAD_RAD = 1.0         # loose parts: around the direction from the base to the
                                       # camera


def stream(seed: int, key: int, index: int, mode: str) -> np.random.Generator:
    """The random stream of one kind of draw: per frame in `random` mode, else per sequence."""
    return np.random.default_rng([seed, key] + ([index] if mode == "random" else []))


def on_floor_or_above(z_base_m: np.ndarray) -> np.ndarray:
    """Whether points at heights `z_base_m` (base frame, m) lie on the floor or above it
    (at most `FLOOR_TOLERANCE_M` under it).

    >>> on_floor_or_above(np.array([0.2, -0.005, -0.05])).tolist()
    [True, True, False]
    """
    return np.asarray(z_base_m, float) >= FLOOR_Z_M - FLOOR_TOLERANCE_M


def closeup_pose(rng: np.random.Generator, config: SynthConfig,
                 P_base_keypoints: np.ndarray) -> np.ndarray | None:
    """With `camera.closeup_prob`, T_cam_base aimed at one of the keypoints (K, 3) from
    `camera.closeup_radius_m`, on the shell's elevation range; else None. A keypoint below
    the floor (z = 0) is not aimed at (another is drawn among those above it), and the camera
    stays `CLOSEUP_MIN_HEIGHT_M` above the floor (its elevation drawn again, above that
    height's bound, where the first draw lies below): a real camera stands on the floor or a
    table, not under them. None where no keypoint is above the floor."""
    s = config.camera
    if rng.random() >= s.closeup_prob:
        return None
    P = np.asarray(P_base_keypoints, float)
    target = P[int(rng.integers(len(P)))]
    if not on_floor_or_above(target[2]):
        above = P[on_floor_or_above(P[:, 2])]
        if not len(above):
            return None
        target = above[int(rng.integers(len(above)))]
    radius = rng.uniform(*s.closeup_radius_m)
    azimuth, elevation = rng.uniform(-np.pi, np.pi), rng.uniform(*s.elevation_rad)
    if target[2] + radius * np.sin(elevation) < FLOOR_Z_M + CLOSEUP_MIN_HEIGHT_M:
        lowest = np.arcsin(np.clip((FLOOR_Z_M + CLOSEUP_MIN_HEIGHT_M - target[2]) / radius,
                                   -1.0, 1.0))
        elevation = rng.uniform(min(lowest, s.elevation_rad[1]), s.elevation_rad[1])
    position = target + radius * np.array([np.cos(elevation) * np.cos(azimuth),
                                           np.cos(elevation) * np.sin(azimuth),
                                           np.sin(elevation)])
    return look_at(position, target, rng.uniform(*s.roll_rad))


def _grey(rng: np.random.Generator, value: tuple[float, float],
          saturation: tuple[float, float], alpha: float) -> np.ndarray:
    rgb = colorsys.hsv_to_rgb(rng.random(), rng.uniform(*saturation), rng.uniform(*value))
    return np.array([*rgb, alpha])


def sample_material(rng: np.random.Generator, config: SynthConfig, real_rgba: np.ndarray
                    ) -> tuple[np.ndarray, float, float] | None:
    """With `appearance.white_plastic_prob`: the light parts of `real_rgba` (G, 4) white, the
    rest as they are; with `appearance.metal_prob`: every part grey metal. Returns (rgba (G, 4),
    specular, shininess), or None to keep the scene's draw."""
    a = config.appearance
    draw = rng.random()
    if draw < a.white_plastic_prob:
        light = np.array([colorsys.rgb_to_hsv(*np.clip(c[:3], 0, 1))[2] > LIGHT_PART_VALUE
                          for c in real_rgba])
        white = _grey(rng, WHITE_PLASTIC_VALUE, WHITE_PLASTIC_SATURATION, 1.0)
        rgba = np.where(light[:, None], white, real_rgba)
        rgba[:, 3] = real_rgba[:, 3]
        return rgba, rng.uniform(*WHITE_PLASTIC_SPECULAR), rng.uniform(*WHITE_PLASTIC_SHININESS)
    if draw < a.white_plastic_prob + a.metal_prob:
        metal = _grey(rng, METAL_VALUE, METAL_SATURATION, 1.0)
        rgba = np.tile(metal, (len(real_rgba), 1))
        rgba[:, 3] = real_rgba[:, 3]
        return rgba, rng.uniform(*METAL_SPECULAR), rng.uniform(*METAL_SHININESS)
    return None


def sample_other_robot(rng: np.random.Generator, config: SynthConfig, other: Robot,
                       T_cam_base: np.ndarray) -> OtherRobotDraw | None:
    """With `distractors.robot_prob`, the other robot on the floor `robot_distance_m` from the
    base, beyond it as the camera sees it (within +-`OTHER_ROBOT_AZIMUTH_SPREAD_RAD`), turned
    at random, in random joints within its limits; real colours with
    `appearance.keep_real_colors_prob`, else one random colour."""
    dc = config.distractors
    if rng.random() >= dc.robot_prob:
        return None
    camera = invert_T(T_cam_base)[:3, 3]
    away = np.arctan2(-camera[1], -camera[0])
    azimuth = away + rng.uniform(-OTHER_ROBOT_AZIMUTH_SPREAD_RAD, OTHER_ROBOT_AZIMUTH_SPREAD_RAD)
    distance, yaw = rng.uniform(*dc.robot_distance_m), rng.uniform(-np.pi, np.pi)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0],
                 [0.0, 0.0, 1.0]]
    T[:2, 3] = distance * np.array([np.cos(azimuth), np.sin(azimuth)])
    joints = rng.uniform(other.joint_lower, other.joint_upper)
    return OtherRobotDraw(T, joints, _other_robot_rgba(rng, config))


def _other_robot_rgba(rng: np.random.Generator, config: SynthConfig) -> np.ndarray | None:
    """The other robot's colour: None (its real colours) with
    `appearance.keep_real_colors_prob`, else one random flat colour (4,)."""
    if rng.random() < config.appearance.keep_real_colors_prob:
        return None
    return np.array([*rng.random(3), 1.0])


def loose_links(other: Robot, start: str) -> tuple[str, ...]:
    """`start` and every link below it in `other`'s tree."""
    return tuple(link for link in other.link_names if other.tree.is_ancestor(start, link))


def sample_loose_parts(rng: np.random.Generator, config: SynthConfig, other: Robot,
                       T_cam_base: np.ndarray) -> OtherRobotDraw | None:
    """With `distractors.loose_prob`, the links of `other` from one of its last
    `loose_keypoints` keypoint links down, in random joints within its limits, turned at random,
    their link origins centred `loose_distance_m` (horizontally) from the base towards the camera
    (within +-`LOOSE_AZIMUTH_SPREAD_RAD`) and `loose_height_m` above the floor; colours as
    `sample_other_robot`'s."""
    dc = config.distractors
    if rng.random() >= dc.loose_prob:
        return None
    starts = other.keypoint_names[-dc.loose_keypoints:]
    links = loose_links(other, starts[int(rng.integers(len(starts)))])
    joints = rng.uniform(other.joint_lower, other.joint_upper)
    centre = other.link_poses(joints, links)[:, :3, 3].mean(axis=0)
    camera = invert_T(T_cam_base)[:3, 3]
    azimuth = np.arctan2(camera[1], camera[0]) + rng.uniform(-LOOSE_AZIMUTH_SPREAD_RAD,
                                                             LOOSE_AZIMUTH_SPREAD_RAD)
    distance, height = rng.uniform(*dc.loose_distance_m), rng.uniform(*dc.loose_height_m)
    R = R_from_quaternion_xyzw(rng.normal(size=4))   # uniform over rotations
    place = np.array([distance * np.cos(azimuth), distance * np.sin(azimuth), height])
    return OtherRobotDraw(make_T(R, place - R @ centre), joints, _other_robot_rgba(rng, config),
                          links)


def with_realism(scene, seed: int, index: int, config: SynthConfig, robot: Robot,
                 aim_joints: np.ndarray, real_rgba: np.ndarray, other: Robot | None):
    """`scene` (a `synth.randomize.SceneDraw`) with this module's draws applied. `aim_joints`
    (J,) place the keypoints a close-up aims at."""
    mode = config.sequence.mode
    changes = {}
    if config.camera.closeup_prob > 0:
        T_closeup = closeup_pose(stream(seed, CLOSEUP_STREAM, index, mode), config,
                                 robot.forward_kinematics(aim_joints))
        if T_closeup is not None:
            changes["T_cam_base"] = T_closeup
    material = sample_material(stream(seed, MATERIAL_STREAM, index, mode), config, real_rgba)
    if material is not None:
        changes.update(zip(("robot_rgba", "robot_specular", "robot_shininess"),
                           (material[0], float(material[1]), float(material[2])), strict=True))
    hide = stream(seed, HIDE_HAND_STREAM, index, mode).random() < \
        config.appearance.hide_hand_prob
    changes["hide_hand"] = bool(hide)
    if other is not None:
        T_cam_base = changes.get("T_cam_base", scene.T_cam_base)
        drawn = sample_other_robot(stream(seed, OTHER_ROBOT_STREAM, index, mode), config,
                                   other, T_cam_base)
        if drawn is not None and config.distractors.robot_moves and mode != "random":
            rng = np.random.default_rng([seed, OTHER_MOTION_STREAM, index])
            drawn = dataclasses.replace(drawn, joints=rng.uniform(other.joint_lower,
                                                                  other.joint_upper))
        changes["other_robot"] = drawn or sample_loose_parts(
            stream(seed, LOOSE_PARTS_STREAM, index, mode), config, other, T_cam_base)
    return dataclasses.replace(scene, **changes)


def sensor_effects(rgb: np.ndarray, seed: int, index: int, config: SynthConfig) -> np.ndarray:
    """Frame `index`'s (H, W, 3) uint8 image as `config.sensor` writes it: blurred, times its
    exposure gain, plus read noise, clipped (drawn anew for every frame, in every sequence
    mode; the image itself where all three are 0).

    >>> from synth.config import config_from_dict
    >>> rgb = np.full((2, 2, 3), 100, np.uint8)
    >>> sensor_effects(rgb, 0, 0, config_from_dict({})) is rgb
    True
    >>> bright = sensor_effects(rgb, 0, 0, config_from_dict({"sensor": {"gain_sigma": 0.1}}))
    >>> bool(np.all(bright == bright[0, 0, 0])), bool(bright[0, 0, 0] != 100)
    (True, True)
    """
    sensor = config.sensor
    if sensor.blur_px:
        rgb = cv2.GaussianBlur(rgb, (0, 0), sensor.blur_px)
    if not (sensor.gain_sigma or sensor.noise_std):
        return rgb
    rng = np.random.default_rng([seed, SENSOR_STREAM, index])
    gain = np.exp(sensor.gain_sigma * rng.normal())
    noise = sensor.noise_std * rng.standard_normal(rgb.shape, np.float32) \
        if sensor.noise_std else 0.0
    return np.clip(np.rint(rgb.astype(np.float32) * np.float32(gain) + noise), 0,
                   255).astype(np.uint8)
