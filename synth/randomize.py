"""Per-frame domain-randomisation parameters: a pure function of (config, seed, frame index).

Every frame's randomness comes from `frame_rng(seed, index)`, so any frame can be regenerated
alone. In the sequence modes (`fixed_camera`, `trajectory`) the camera and the scene (lights,
colours, background, distractors) come from `sequence_rng(seed)` and stay fixed; only the joints
change, as in measured calibration data.
"""

from __future__ import annotations

import colorsys
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.robot import Robot
from dream.transforms import invert_T, look_at
from synth.cable import CableDraw, sample_cable
from synth.config import SynthConfig
from synth.hand import HandDraw, sample_hand
from synth.other_robot import OtherRobotDraw
from synth.person import PersonDraw, sample_person
from synth.realism import on_floor_or_above, with_realism

SEQUENCE_STREAM = 0x5E0     # spawn key of the per-sequence random stream
FRAME_STREAM = 0xF4A        # spawn key of the per-frame random streams
HELD_STREAM = 0x4E1D        # spawn key of the held object's stream (held_prob = 0 leaves the
                            # other draws, and so older data sets, unchanged)
CABLE_STREAM = 0xCAB1E      # spawn key of the cable's stream (cable_prob = 0: nothing drawn)
PERSON_STREAM = 0x9E450     # spawn key of the person's stream (person_prob = 0: nothing drawn)
HAND_STREAM = 0x4A4D        # spawn key of the dexterous hand's stream (hand_prob = 0: none)
FLOOR_REDRAWS = 20          # `joints.above_floor`: at most this many joint draws again
SHADOW_STREAM = 0x5AD0      # spawn key, with the scene's texture seed, of whether it has shadows
HELD_BOARD_THICKNESS_M = (0.004, 0.02)  # full thickness of a held plate
HELD_MIN_SIDE_FRACTION = 0.3           # a held object's other sides: 0.3-1 x its largest
HELD_PART_SCALE = (0.3, 0.7)           # a further part of an assembly, x the held size
HELD_PART_OVERLAP = 0.8                # parts' centres this fraction of their reach apart
CHECKER_RGBA = (1.0, 1.0, 1.0, 1.0)    # the texture alone gives a checkerboard's colours
DISTRACTOR_TYPES = ("box", "sphere", "cylinder", "capsule", "ellipsoid")
OCCLUDER_PATH_FRACTION = (0.4, 0.85)   # where on the camera -> robot segment an occluder sits
OCCLUDER_AIM_JITTER_M = 0.3            # the segment ends this far (per axis) around the target
OCCLUDER_MAX_HALF_ANGLE_RAD = 0.08     # an occluder's half-size, as seen from the camera
OCCLUDER_MAX_OFFSET = 2.0              # sideways shift from the segment, in occluder sizes
ANY_HUE_JITTER = 0.5                   # appearance.hue_jitter from which any hue is drawn
MIN_JITTERED_VALUE = 0.2               # a jittered colour's HSV value before scaling: at least
                                       # this, so that black parts do not stay black


def frame_rng(seed: int, index: int) -> np.random.Generator:
    return np.random.default_rng([seed, FRAME_STREAM, index])


def sequence_rng(seed: int) -> np.random.Generator:
    return np.random.default_rng([seed, SEQUENCE_STREAM])


@dataclass(frozen=True)
class LightDraw:
    position_m: np.ndarray      # (3,) base frame
    diffuse: np.ndarray         # (3,) RGB in [0, 1]
    specular: np.ndarray        # (3,)


@dataclass(frozen=True)
class DistractorDraw:
    kind: str                   # one of DISTRACTOR_TYPES
    size_m: np.ndarray          # (3,) MuJoCo geom size (half-extents / radius, half-length)
    position_m: np.ndarray      # (3,) base frame
    quaternion_wxyz: np.ndarray  # (4,) MuJoCo order
    rgba: np.ndarray            # (4,)
    texture: int                # index into the scene's textures, -1 for plain colour


@dataclass(frozen=True)
class HeldObjectDraw:
    """An assembly moving with `link`: each part's `position_m` and `quaternion_wxyz` are its
    pose in that link's frame. With `checkerboard`, the first part shows a black-and-white
    checkerboard (in its texture slot)."""

    link: str
    parts: tuple[DistractorDraw, ...]
    checkerboard: bool = False


@dataclass(frozen=True)
class SceneDraw:
    """What stays fixed along a sequence (and is redrawn per frame in `random` mode)."""

    camera: CameraIntrinsics
    T_cam_base: np.ndarray
    lights: tuple[LightDraw, ...]
    ambient: np.ndarray         # (3,)
    robot_rgba: np.ndarray | None   # (n_robot_geoms, 4), None = real colours
    robot_specular: float
    robot_shininess: float
    floor: bool
    distractors: tuple[DistractorDraw, ...]
    texture_seed: int           # textures (floor, distractors) are drawn from this
    background_seed: int        # the 2D background is drawn from this
    held: HeldObjectDraw | None = None
    hide_hand: bool = False     # the hand's visuals are not drawn (synth.realism)
    other_robot: OtherRobotDraw | None = None
    shadows: bool = False       # the first light casts shadows (`Lights.shadow_prob`)
    cable: CableDraw | None = None  # a cable clipped along the arm (`synth.cable`)
    person: PersonDraw | None = None  # a person guiding the arm by hand (`synth.person`)
    hand: HandDraw | None = None      # a dexterous hand the URDF lacks (`synth.hand`)


@dataclass(frozen=True)
class FrameDraw:
    index: int
    scene: SceneDraw
    joints: np.ndarray          # (J,) in robot.joint_names order
    timestamp: float | None


def sample_intrinsics(rng: np.random.Generator, config: SynthConfig) -> CameraIntrinsics:
    c = config.intrinsics
    if c.fixed:
        return CameraIntrinsics(c.fx, c.fy, c.cx, c.cy, c.width, c.height, c.distortion)
    f = (c.width / 2) / np.tan(rng.uniform(*c.hfov_rad) / 2)
    return CameraIntrinsics(f, f, (c.width - 1) / 2, (c.height - 1) / 2, c.width, c.height,
                            c.distortion)


def sample_camera_pose(rng: np.random.Generator, config: SynthConfig) -> np.ndarray:
    """T_cam_base on the configured shell, aimed near the target; `camera.T_cam_base` where
    it fixes the camera."""
    s = config.camera
    if s.T_cam_base is not None:
        return np.array(s.T_cam_base)
    radius = rng.uniform(*s.radius_m)
    azimuth = rng.uniform(*s.azimuth_rad)
    elevation = rng.uniform(*s.elevation_rad)
    target = np.asarray(s.target_m) + rng.uniform(-1, 1, 3) * s.target_jitter_m
    position = target + radius * np.array([np.cos(elevation) * np.cos(azimuth),
                                           np.cos(elevation) * np.sin(azimuth),
                                           np.sin(elevation)])
    return look_at(position, target, rng.uniform(*s.roll_rad))


def _jitter_color(rng: np.random.Generator, rgba: np.ndarray, config: SynthConfig) -> np.ndarray:
    a = config.appearance
    h, _, v = colorsys.rgb_to_hsv(*np.clip(rgba[:3], 0, 1))
    jitter, spin = rng.uniform(-a.hue_jitter, a.hue_jitter), rng.random()
    # half the circle or more: any hue (the spin makes it uniform; always drawn, so that a
    # seed renders what it rendered before `hue_jitter` below 0.5 was honoured)
    h = (h + jitter + (spin if a.hue_jitter >= ANY_HUE_JITTER else 0.0)) % 1.0
    s = rng.uniform(*a.saturation)
    v = np.clip(max(v, MIN_JITTERED_VALUE) * rng.uniform(*a.value_scale), 0, 1)
    return np.array([*colorsys.hsv_to_rgb(h, s, v), rgba[3]])


def sample_scene(rng: np.random.Generator, config: SynthConfig, default_rgba: np.ndarray,
                 num_lights_max: int, num_distractors_max: int,
                 num_textures: int) -> SceneDraw:
    """Camera, lights, appearance, floor and distractors. `default_rgba` (n_robot_geoms, 4)."""
    camera = sample_intrinsics(rng, config)
    T_cam_base = sample_camera_pose(rng, config)
    lc = config.lights
    n_lights = min(int(rng.integers(lc.count[0], lc.count[1] + 1)), num_lights_max)
    lights = []
    for _ in range(n_lights):
        r, az, el = rng.uniform(*lc.radius_m), rng.uniform(-np.pi, np.pi), \
            rng.uniform(*lc.elevation_rad)
        pos = np.asarray(config.camera.target_m) + r * np.array(
            [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        tint = 1.0 + rng.uniform(-lc.color_jitter, lc.color_jitter, 3)
        lights.append(LightDraw(pos, np.clip(rng.uniform(*lc.intensity) * tint, 0, 1),
                                np.full(3, rng.uniform(*lc.specular))))
    ambient = np.full(3, rng.uniform(*lc.ambient))
    ap = config.appearance
    robot_rgba = None
    if rng.random() >= ap.keep_real_colors_prob:
        robot_rgba = np.stack([_jitter_color(rng, c, config) for c in default_rgba])
    specular, shininess = rng.uniform(*ap.specular), rng.uniform(*ap.shininess)
    floor = bool(rng.random() < config.background.floor_prob)
    dc = config.distractors
    n_dis = min(int(rng.integers(dc.count[0], dc.count[1] + 1)), num_distractors_max)
    target = np.asarray(config.camera.target_m)
    camera_position = -T_cam_base[:3, :3].T @ T_cam_base[:3, 3]
    distractors = []
    for _ in range(n_dis):
        kind = DISTRACTOR_TYPES[int(rng.integers(len(DISTRACTOR_TYPES)))]
        size = rng.uniform(*dc.size_m, 3) / 2
        if rng.random() < dc.occluder_prob:
            position, size = _occluder_placement(rng, camera_position, target, size)
        else:
            direction = rng.normal(size=3)
            position = target + direction / np.linalg.norm(direction) * rng.uniform(*dc.distance_m)
        q = rng.normal(size=4)
        rgba = np.array([*rng.random(3), 1.0])
        texture = int(rng.integers(num_textures)) if num_textures and \
            rng.random() < dc.textured_prob else -1
        distractors.append(DistractorDraw(kind, size, position, q / np.linalg.norm(q), rgba,
                                          texture))
    texture_seed, background_seed = int(rng.integers(2 ** 31)), int(rng.integers(2 ** 31))
    # a stream of its own, so that every other draw is that of the same seed without shadows
    shadows = bool(np.random.default_rng([texture_seed, SHADOW_STREAM]).random()
                   < lc.shadow_prob)
    return SceneDraw(camera, T_cam_base, tuple(lights), ambient, robot_rgba, float(specular),
                     float(shininess), floor, tuple(distractors), texture_seed, background_seed,
                     shadows=shadows)


def _random_shape(rng: np.random.Generator, half_sides: np.ndarray, position: np.ndarray,
                  textured_prob: float, num_textures: int, kind: str | None = None
                  ) -> DistractorDraw:
    kind = kind or DISTRACTOR_TYPES[int(rng.integers(len(DISTRACTOR_TYPES)))]
    q = rng.normal(size=4)
    rgba = np.array([*rng.random(3), 1.0])
    texture = int(rng.integers(num_textures)) if num_textures and \
        rng.random() < textured_prob else -1
    return DistractorDraw(kind, half_sides, position, q / np.linalg.norm(q), rgba, texture)


def sample_held_object(rng: np.random.Generator, config: SynthConfig, link: str,
                       num_textures: int) -> HeldObjectDraw | None:
    """With probability `distractors.held_prob`, an assembly held at `link`: a thin plate or a
    random primitive, its centre `held_offset_m` from the link origin in a random direction,
    randomly turned and coloured, then `held_parts` - 1 smaller primitives, each attached to the
    part before; with `held_checker_prob` the first part is a checkerboard."""
    dc = config.distractors
    if rng.random() >= dc.held_prob:
        return None
    largest = rng.uniform(*dc.held_size_m) / 2
    sides = largest * rng.uniform(HELD_MIN_SIDE_FRACTION, 1.0, 3)
    sides[0] = largest
    if rng.random() < dc.held_board_prob:
        kind = "box"
        sides[2] = rng.uniform(*HELD_BOARD_THICKNESS_M) / 2
    else:
        kind = DISTRACTOR_TYPES[int(rng.integers(len(DISTRACTOR_TYPES)))]
    direction = rng.normal(size=3)
    position = direction / np.linalg.norm(direction) * rng.uniform(*dc.held_offset_m)
    parts = [_random_shape(rng, sides, position, dc.held_textured_prob, num_textures, kind)]
    for _ in range(int(rng.integers(dc.held_parts[0], dc.held_parts[1] + 1)) - 1):
        previous = parts[-1]
        half = rng.uniform(*dc.held_size_m) / 2 * rng.uniform(*HELD_PART_SCALE, 3)
        direction = rng.normal(size=3)
        reach = (float(previous.size_m.max()) + float(half.max())) * HELD_PART_OVERLAP
        parts.append(_random_shape(rng, half, previous.position_m + direction /
                                   np.linalg.norm(direction) * reach, dc.held_textured_prob,
                                   num_textures))
    checkerboard = bool(rng.random() < dc.held_checker_prob) and num_textures > 0
    if checkerboard:
        slot = parts[0].texture if parts[0].texture >= 0 else int(rng.integers(num_textures))
        parts[0] = dataclasses.replace(parts[0], rgba=np.array(CHECKER_RGBA), texture=slot)
    return HeldObjectDraw(link, tuple(parts), checkerboard)


def sample_scene_cable(rng: np.random.Generator, config: SynthConfig, robot: Robot
                       ) -> CableDraw | None:
    """With probability `distractors.cable_prob`, a cable clipped along the arm
    (`synth.cable.sample_cable`)."""
    dc = config.distractors
    if rng.random() >= dc.cable_prob:
        return None
    return sample_cable(rng, tuple(robot.keypoint_names), dc.cable_radius_m, dc.cable_slack,
                        dc.cable_clip_offset_m, dc.cable_start_m)


def sample_scene_person(rng: np.random.Generator, config: SynthConfig, robot: Robot,
                        scene: SceneDraw) -> PersonDraw | None:
    """With probability `distractors.person_prob`, a person gripping the last keypoint link
    (`synth.person.sample_person`), not on the camera's side of the base."""
    dc = config.distractors
    if rng.random() >= dc.person_prob:
        return None
    camera_position = invert_T(scene.T_cam_base)[:3, 3]
    return sample_person(rng, robot.keypoint_names[-1], camera_position, dc.person_distance_m,
                         dc.person_shoulder_height_m)


def sample_scene_hand(rng: np.random.Generator, config: SynthConfig, robot: Robot
                      ) -> HandDraw | None:
    """With probability `distractors.hand_prob`, a dexterous hand at the last keypoint link
    (`synth.hand.sample_hand`)."""
    if rng.random() >= config.distractors.hand_prob:
        return None
    return sample_hand(rng, robot.keypoint_names[-1])


def _occluder_placement(rng: np.random.Generator, camera_position: np.ndarray,
                        target: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A distractor part-way between the camera and a point of the robot, small enough and
    offset sideways so that it hides part of the robot, not all of it."""
    aim = target + rng.uniform(-1, 1, 3) * OCCLUDER_AIM_JITTER_M
    line = aim - camera_position
    fraction = rng.uniform(*OCCLUDER_PATH_FRACTION)
    distance = fraction * np.linalg.norm(line)
    size = np.minimum(size, OCCLUDER_MAX_HALF_ANGLE_RAD * distance)
    side = np.cross(line, rng.normal(size=3))
    side /= np.linalg.norm(side)
    offset = rng.uniform(0.0, OCCLUDER_MAX_OFFSET) * float(size.max()) * side
    return camera_position + fraction * line + offset, size


def load_joint_log(path: str | Path, robot: Robot) -> np.ndarray:
    """(M, J) joint vectors, one a line (whitespace or comma separated), rad."""
    path = Path(path)
    try:
        rows = [line.replace(",", " ").split() for line in path.read_text().splitlines()
                if line.strip() and not line.lstrip().startswith("#")]
        q = np.array(rows, dtype=float)
    except FileNotFoundError:
        raise InputError("joint log not found", path, "give joints.log as a text file") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"unreadable joint log ({exc})", path,
                         f"write one line of {len(robot.joint_names)} numbers per "
                         f"configuration") from None
    if q.ndim != 2 or q.shape[1] != len(robot.joint_names) or not np.all(np.isfinite(q)):
        raise InputError(f"the joint log must hold rows of {len(robot.joint_names)} finite "
                         f"numbers ({', '.join(robot.joint_names)})", path)
    return q


def sample_joints(rng: np.random.Generator, robot: Robot, config: SynthConfig,
                  joint_log: np.ndarray | None) -> np.ndarray:
    """(J,) joints uniform within limits, or around a random configuration of the log. With
    `joints.above_floor`, a draw with a keypoint under the floor (not
    `synth.realism.on_floor_or_above`) is drawn again, up to `FLOOR_REDRAWS` times (the draw
    whose lowest keypoint is highest kept); a first draw above it is the draw without the
    option."""
    q = _joint_draw(rng, robot, config, joint_log)
    if not config.joints.above_floor:
        return q
    lowest = robot.forward_kinematics(q)[:, 2].min()
    for _ in range(FLOOR_REDRAWS):
        if on_floor_or_above(lowest):
            break
        again = _joint_draw(rng, robot, config, joint_log)
        low = robot.forward_kinematics(again)[:, 2].min()
        if low > lowest:
            q, lowest = again, low
    return q


def _joint_draw(rng: np.random.Generator, robot: Robot, config: SynthConfig,
                joint_log: np.ndarray | None) -> np.ndarray:
    lo, hi = robot.joint_lower, robot.joint_upper
    if joint_log is not None:
        q = joint_log[int(rng.integers(len(joint_log)))]
        return np.clip(q + rng.normal(0, config.joints.log_noise_rad, q.shape), lo, hi)
    mid, half = (lo + hi) / 2, (hi - lo) / 2 * config.joints.range_fraction
    return rng.uniform(mid - half, mid + half)


def trajectory_joints(seed: int, index: int, robot: Robot, config: SynthConfig,
                      joint_log: np.ndarray | None) -> np.ndarray:
    """Joints at frame `index` of a smooth trajectory through random waypoints (cosine blend,
    zero velocity at each waypoint, so the path stays inside the joint limits)."""
    return trajectory_joints_at(seed, index / config.sequence.fps, robot, config, joint_log)


def trajectory_joints_at(seed: int, t: float, robot: Robot, config: SynthConfig,
                         joint_log: np.ndarray | None) -> np.ndarray:
    """Joints of the trajectory at time `t`, s (frame i is at i / fps). Before t = 0 the arm
    rests at the first waypoint (the blend starts there with zero velocity)."""
    t = max(float(t), 0.0)
    k = int(t // config.sequence.waypoint_period_s)
    s = (t - k * config.sequence.waypoint_period_s) / config.sequence.waypoint_period_s
    a = sample_joints(np.random.default_rng([seed, SEQUENCE_STREAM, k]), robot, config, joint_log)
    b = sample_joints(np.random.default_rng([seed, SEQUENCE_STREAM, k + 1]), robot, config,
                      joint_log)
    return a + (b - a) * (1 - np.cos(np.pi * s)) / 2


def closeup_aim_joints(seed: int, robot: Robot, config: SynthConfig,
                       joint_log: np.ndarray | None) -> np.ndarray:
    """(J,) joints whose keypoints a sequence's close-up aims at (`camera.closeup_aim`): the
    middle of the joint ranges, or the joints of the sequence's first frame."""
    if config.camera.closeup_aim == "middle":
        return (robot.joint_lower + robot.joint_upper) / 2
    if config.sequence.mode == "trajectory":
        return trajectory_joints(seed, 0, robot, config, joint_log)
    return sample_joints(frame_rng(seed, 0), robot, config, joint_log)


def sample_frame(seed: int, index: int, robot: Robot, config: SynthConfig,
                 default_rgba: np.ndarray, num_lights_max: int, num_distractors_max: int,
                 num_textures: int, joint_log: np.ndarray | None = None,
                 other_robot: Robot | None = None) -> FrameDraw:
    """All randomness of frame `index`. `other_robot`: the robot drawn as a distractor where
    the recipe asks for one (`synth.realism`)."""
    mode = config.sequence.mode
    rng = frame_rng(seed, index)
    limits = (default_rgba, num_lights_max, num_distractors_max, num_textures)
    held_key = [seed, HELD_STREAM] + ([index] if mode == "random" else [])
    held = sample_held_object(np.random.default_rng(held_key), config, robot.keypoint_names[-1],
                              num_textures)
    cable = sample_scene_cable(np.random.default_rng(
        [seed, CABLE_STREAM] + ([index] if mode == "random" else [])), config, robot)
    timestamp = None if mode == "random" else index / config.sequence.fps
    if mode == "random":
        scene = sample_scene(rng, config, *limits)
        joints = sample_joints(rng, robot, config, joint_log)
    else:
        scene = sample_scene(sequence_rng(seed), config, *limits)
        joints = sample_joints(rng, robot, config, joint_log) if mode == "fixed_camera" else \
            trajectory_joints(seed, index, robot, config, joint_log)
    aim = joints if mode == "random" else closeup_aim_joints(seed, robot, config, joint_log)
    scene = with_realism(dataclasses.replace(scene, held=held, cable=cable), seed, index,
                         config, robot, aim, default_rgba, other_robot)
    person = sample_scene_person(np.random.default_rng(
        [seed, PERSON_STREAM] + ([index] if mode == "random" else [])), config, robot, scene)
    hand = sample_scene_hand(np.random.default_rng(
        [seed, HAND_STREAM] + ([index] if mode == "random" else [])), config, robot)
    return FrameDraw(index, dataclasses.replace(scene, person=person, hand=hand), joints,
                     timestamp)
