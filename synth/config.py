"""Domain-randomisation recipe: every range a named field, loaded from YAML (`configs/synth/`).

Units: metres, radians, pixels. A range is a `[low, high]` pair drawn uniformly.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dream.errors import InputError
from dream.recipe import load_recipe, plain, recipe_from_dict
from synth.config_fields import (
    Range,
    finite_number,
    image_side,
    non_negative,
    probability,
    rigid_rows,
    value_range,
    whole_number,
)
from synth.scene_settings import MAX_LIGHTS

DISTORTION_COEFFS = ("k1", "k2", "p1", "p2", "k3")  # plumb_bob order
CLOSEUP_AIMS = ("middle", "start")   # `CameraShell.closeup_aim`
CABLE_MIN_RADIUS_M = 1e-4   # a thinner cable is not drawn by any camera


@dataclass(frozen=True)
class CameraShell:
    """Camera on a spherical shell around the robot, aimed near `target_m`."""

    radius_m: Range = (1.0, 2.0)
    azimuth_rad: Range = (-np.pi, np.pi)
    elevation_rad: Range = (-0.1, 1.1)          # above the base's horizontal plane
    target_m: tuple[float, float, float] = (0.0, 0.0, 0.4)
    target_jitter_m: float = 0.15               # aim point uniform in a cube of this half-size
    roll_rad: Range = (-0.3, 0.3)
    # A close-up: with this probability the camera is `closeup_radius_m` from one keypoint,
    # aimed at it, so that links leave the frame (as when the flange fills a real view).
    closeup_prob: float = 0.0
    closeup_radius_m: Range = (0.3, 0.8)
    # Where a sequence's close-up aims (the `random` mode aims at each frame's own joints):
    # `middle`, the keypoints at the middle of the joint ranges; `start`, those at the
    # sequence's first frame (where a `trajectory` starts, so that its arm is in view).
    closeup_aim: str = "middle"
    # One camera pose for every frame instead of the shell (4x4 rows, the base frame into the
    # camera frame), e.g. a calibrated camera whose own scene the renders show.
    T_cam_base: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius_m", value_range("camera.radius_m", self.radius_m, 1e-3))
        object.__setattr__(self, "closeup_radius_m",
                           value_range("camera.closeup_radius_m", self.closeup_radius_m, 1e-3))
        probability("camera.closeup_prob", self.closeup_prob)
        if self.closeup_aim not in CLOSEUP_AIMS:
            raise InputError(f"camera.closeup_aim '{self.closeup_aim}' must be one of "
                             f"{', '.join(CLOSEUP_AIMS)}",
                             fix="set camera.closeup_aim: start to aim at the first frame's arm")
        object.__setattr__(self, "azimuth_rad", value_range("camera.azimuth_rad", self.azimuth_rad))
        object.__setattr__(self, "elevation_rad",
                           value_range("camera.elevation_rad", self.elevation_rad, -1.5, 1.5))
        object.__setattr__(self, "roll_rad", value_range("camera.roll_rad", self.roll_rad))
        fix = "give camera.target_m as [x, y, z] in metres in the robot base frame"
        if isinstance(self.target_m, str) or not hasattr(self.target_m, "__len__") or \
                len(self.target_m) != 3:
            raise InputError(f"camera.target_m must be 3 numbers, got {self.target_m!r}",
                             fix=fix)
        object.__setattr__(self, "target_m",
                           tuple(finite_number(f"camera.target_m[{i}]", v, fix)
                                 for i, v in enumerate(self.target_m)))
        non_negative("camera.target_jitter_m", self.target_jitter_m)
        if self.T_cam_base is not None:
            object.__setattr__(self, "T_cam_base", rigid_rows("camera.T_cam_base", self.T_cam_base))
            if self.closeup_prob > 0:
                raise InputError("camera.T_cam_base fixes the camera, so camera.closeup_prob "
                                 f"{self.closeup_prob} cannot move it to a close-up",
                                 fix="set camera.closeup_prob: 0")


@dataclass(frozen=True)
class Intrinsics:
    """Fixed target camera (fx, fy, cx, cy; optional plumb_bob), or a random horizontal field of
    view (`hfov_rad`, square pixels, centred principal point) when `fx` is None."""

    width: int = 320
    height: int = 240
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    distortion: tuple[float, float, float, float, float] | None = None
    hfov_rad: Range = (0.9, 1.3)

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            object.__setattr__(self, name, image_side(f"intrinsics.{name}", getattr(self, name)))
        fixed = [self.fx, self.fy, self.cx, self.cy]
        if any(v is not None for v in fixed) and any(v is None for v in fixed):
            raise InputError("intrinsics: give all of fx, fy, cx, cy (fixed camera) or none "
                             "(random field of view)")
        if self.fixed:
            for name in ("fx", "fy"):
                key = f"intrinsics.{name}"
                value = finite_number(key, getattr(self, name),
                                      f"set {key} to the focal length in pixels")
                if value <= 0:
                    raise InputError(f"{key} must be a focal length > 0 (pixels), got {value}",
                                     fix=f"set {key} to the camera's focal length in pixels")
                object.__setattr__(self, name, value)
            for name in ("cx", "cy"):
                key = f"intrinsics.{name}"
                object.__setattr__(self, name, finite_number(
                    key, getattr(self, name), f"set {key} to the principal point in pixels"))
        object.__setattr__(self, "hfov_rad",
                           value_range("intrinsics.hfov_rad", self.hfov_rad, 0.05, 3.0))
        if self.distortion is not None:
            try:
                coeffs = tuple(float(c) for c in self.distortion)
            except (TypeError, ValueError):
                coeffs = ()
            if len(coeffs) != len(DISTORTION_COEFFS) or not np.all(np.isfinite(coeffs)):
                raise InputError(f"intrinsics.distortion must be {len(DISTORTION_COEFFS)} finite "
                                 f"plumb_bob coefficients, got {self.distortion!r}",
                                 fix=f"give [{', '.join(DISTORTION_COEFFS)}] or null")
            object.__setattr__(self, "distortion", coeffs)

    @property
    def fixed(self) -> bool:
        return self.fx is not None


@dataclass(frozen=True)
class Joints:
    """Joint configurations: uniform within the limits (`range_fraction` of each range, centred),
    or around configurations of a joint log (`log`: a file of one joint vector a line, rad)."""

    range_fraction: float = 1.0
    log: str | None = None
    log_noise_rad: float = 0.05
    extra: float = 0.0                  # value of joints that move no keypoint (e.g. fingers)
    # a draw that puts a keypoint under the floor (the base frame's z = 0) is drawn again, as a
    # real arm never reaches through its table (a trajectory's waypoints; the path between
    # two may still dip)
    above_floor: bool = False

    def __post_init__(self) -> None:
        if not 0.0 < self.range_fraction <= 1.0:
            raise InputError("joints.range_fraction must be in (0, 1]")
        non_negative("joints.log_noise_rad", self.log_noise_rad)
        if not isinstance(self.above_floor, bool):
            raise InputError(f"joints.above_floor must be true or false, got {self.above_floor!r}")


@dataclass(frozen=True)
class Lights:
    count: tuple[int, int] = (1, 4)
    radius_m: Range = (1.0, 3.0)         # distance of each light from the robot
    elevation_rad: Range = (0.2, 1.4)
    intensity: Range = (0.3, 1.0)        # diffuse level of each light
    color_jitter: float = 0.2            # per-channel multiplicative jitter of white
    ambient: Range = (0.05, 0.4)
    specular: Range = (0.0, 0.3)
    shadow_prob: float = 0.0             # the first light casts shadows (on the floor, the
    #                                      robot, distractors; not on a 2D background)

    def __post_init__(self) -> None:
        if not 0.0 <= self.shadow_prob <= 1.0:
            raise InputError(f"lights.shadow_prob must lie in [0, 1], got {self.shadow_prob}")
        lo, hi = self.count
        if not 1 <= lo <= hi <= MAX_LIGHTS:
            raise InputError(f"lights.count must be [low, high] with 1 <= low <= high <= "
                             f"{MAX_LIGHTS}, got {list(self.count)}")
        object.__setattr__(self, "count", (int(lo), int(hi)))
        for name, lo_limit, hi_limit in (("radius_m", 1e-3, np.inf),
                                         ("elevation_rad", -np.pi / 2, np.pi / 2),
                                         ("intensity", 0.0, np.inf), ("ambient", 0.0, 1.0),
                                         ("specular", 0.0, 1.0)):
            object.__setattr__(self, name, value_range(f"lights.{name}", getattr(self, name),
                                                       lo_limit, hi_limit))
        non_negative("lights.color_jitter", self.color_jitter)


@dataclass(frozen=True)
class Appearance:
    """Robot colours: the real ones with `keep_real_colors_prob`, else jittered per part (each
    visual geom): the hue moved by up to `hue_jitter` of the circle (0.5 or more: any hue),
    saturation drawn, value scaled. Then, with `white_plastic_prob`, the light parts become
    glossy white plastic, or with `metal_prob` every part brushed metal (grey, strong broad
    highlights); with `hide_hand_prob` the visuals of the last keypoint's link and the links
    below it (a gripper's fingers) are not drawn, as where a real arm carries another tool."""

    keep_real_colors_prob: float = 0.5
    hue_jitter: float = 0.5              # fraction of the hue circle, each way
    saturation: Range = (0.0, 0.8)
    value_scale: Range = (0.5, 1.2)
    specular: Range = (0.0, 0.8)
    shininess: Range = (0.0, 1.0)
    white_plastic_prob: float = 0.0
    metal_prob: float = 0.0
    hide_hand_prob: float = 0.0

    def __post_init__(self) -> None:
        probability("appearance.keep_real_colors_prob", self.keep_real_colors_prob)
        for name in ("white_plastic_prob", "metal_prob", "hide_hand_prob"):
            probability(f"appearance.{name}", getattr(self, name))
        if self.white_plastic_prob + self.metal_prob > 1.0:
            raise InputError("appearance.white_plastic_prob + metal_prob must be at most 1, got "
                             f"{self.white_plastic_prob} + {self.metal_prob}")
        non_negative("appearance.hue_jitter", self.hue_jitter)
        for name, hi_limit in (("saturation", 1.0), ("value_scale", np.inf), ("specular", 1.0),
                               ("shininess", 1.0)):
            object.__setattr__(self, name, value_range(f"appearance.{name}",
                                                       getattr(self, name), 0.0, hi_limit))


@dataclass(frozen=True)
class Background:
    """Procedural backgrounds (weights per kind) and, when `photos` is a folder, photos; or,
    when `plate` is an image of the camera's size, that image as it is behind every frame (the
    user's scene without the robot, seen from `camera.T_cam_base`)."""

    kinds: dict[str, float] = field(default_factory=lambda: {
        "noise": 1.0, "checkers": 1.0, "stripes": 1.0, "gradient": 1.0, "shapes": 1.0,
        "photo": 0.0})
    photos: str | None = None
    floor_prob: float = 0.5
    texture_size: int = 64
    plate: str | None = None

    def __post_init__(self) -> None:
        known = {"noise", "checkers", "stripes", "gradient", "shapes", "photo"}
        unknown = set(self.kinds) - known
        if unknown:
            raise InputError(f"background.kinds has unknown kinds {sorted(unknown)}; use "
                             f"{sorted(known)}")
        if any(w < 0 for w in self.kinds.values()) or sum(self.kinds.values()) <= 0:
            raise InputError("background.kinds weights must be >= 0 with a positive sum")
        photo = self.kinds.get("photo", 0.0)
        if self.photos and not photo > 0:
            raise InputError("background.photos is set but background.kinds.photo is 0, so no "
                             "photo would be drawn", fix="set background.kinds.photo (e.g. 1.0)")
        if photo > 0 and not self.photos:
            raise InputError("background.kinds.photo > 0 needs background.photos (a folder of "
                             "photos)", fix="set background.photos: DIR or kinds.photo: 0")
        probability("background.floor_prob", self.floor_prob)
        if self.plate is not None and self.floor_prob > 0:
            raise InputError(f"background.plate shows the scene's own floor, so "
                             f"background.floor_prob {self.floor_prob} would draw another over it",
                             fix="set background.floor_prob: 0")


@dataclass(frozen=True)
class Distractors:
    count: tuple[int, int] = (0, 6)
    size_m: Range = (0.03, 0.25)
    distance_m: Range = (0.4, 1.5)        # from the robot's aim point
    occluder_prob: float = 0.3            # per distractor: placed between camera and robot
    textured_prob: float = 0.5
    # A held object: per frame (per sequence in the sequence modes), one more object that moves
    # with the last keypoint link (the hand or flange), as a tool, a part or a calibration board
    # held by the arm. It occludes the wrist and puts textures next to the hand keypoints.
    held_prob: float = 0.0
    held_size_m: Range = (0.06, 0.3)      # full extent of its largest side
    held_offset_m: Range = (0.03, 0.15)   # its centre from the link origin, any direction
    held_board_prob: float = 0.5          # a thin plate (like a board) instead of a primitive
    held_textured_prob: float = 0.8
    held_parts: tuple[int, int] = (1, 1)  # parts of the held assembly (a tool, a fixture)
    held_checker_prob: float = 0.0        # the held assembly shows a black-and-white checkerboard
    # Another robot, unlabelled: with `robot_prob`, `robot_name` (built-in or URDF; None: this
    # one) `robot_distance_m` beyond the base, in random joints (`robot_moves`: in every frame).
    robot_prob: float = 0.0
    robot_name: str | None = None
    robot_distance_m: Range = (0.8, 2.0)
    robot_moves: bool = False
    # Loose parts of that robot, unlabelled: in a frame without the whole robot, with
    # `loose_prob`, its links from one of its last `loose_keypoints` keypoint links to the end of
    # the chain (a hand, a wrist with its hand) in random joints and a random orientation,
    # `loose_distance_m` from the base on the camera's side, `loose_height_m` above the floor, as a
    # spare gripper or tool on a table.
    loose_prob: float = 0.0
    loose_keypoints: int = 3
    loose_distance_m: Range = (0.4, 1.0)
    loose_height_m: Range = (0.0, 0.5)
    # A cable the URDF lacks, clipped along the arm (`synth.cable`): with `cable_prob` per
    # sequence (per frame in `random` mode), from the floor `cable_start_m` from the base through
    # a clip on each of some keypoint links, `cable_clip_offset_m` from their origins, sagging
    # between clips (`cable_slack`: length over distance), drawn as `cable_segments` capsules of
    # radius `cable_radius_m`.
    cable_prob: float = 0.0
    cable_radius_m: Range = (0.004, 0.012)
    cable_slack: Range = (1.02, 1.25)
    cable_clip_offset_m: Range = (0.03, 0.08)
    cable_start_m: Range = (0.1, 0.3)
    cable_segments: int = 24
    # A person guiding the arm by hand (`synth.person`): with `person_prob` per sequence (per
    # frame in `random` mode), a hand gripping the last keypoint link, an arm, a torso and a
    # head, standing `person_distance_m` from the base (horizontally, not on the camera's side)
    # with the shoulder `person_shoulder_height_m` above the floor (z = 0), leaning towards the
    # hand where it is out of reach.
    person_prob: float = 0.0
    person_distance_m: Range = (0.6, 1.0)
    person_shoulder_height_m: Range = (1.2, 1.5)
    # A dexterous hand the URDF lacks at the last keypoint link (`synth.hand`): with `hand_prob`
    # per sequence (per frame in `random` mode), its fingers opening and closing on their own.
    hand_prob: float = 0.0

    def __post_init__(self) -> None:
        lo, hi = self.count
        if not 0 <= lo <= hi:
            raise InputError("distractors.count must be [low, high] with 0 <= low <= high")
        object.__setattr__(self, "count", (int(lo), int(hi)))
        object.__setattr__(self, "size_m", value_range("distractors.size_m", self.size_m, 1e-3))
        object.__setattr__(self, "distance_m",
                           value_range("distractors.distance_m", self.distance_m, 0.0))
        lo, hi = self.held_parts
        if not 1 <= lo <= hi:
            raise InputError("distractors.held_parts must be [low, high] with 1 <= low <= high")
        object.__setattr__(self, "held_parts", (int(lo), int(hi)))
        for name, low in (("robot_distance_m", 0.0), ("loose_distance_m", 0.0),
                          ("loose_height_m", 0.0), ("cable_radius_m", CABLE_MIN_RADIUS_M),
                          ("cable_slack", 1.0), ("cable_clip_offset_m", 0.0),
                          ("cable_start_m", 0.0), ("person_distance_m", 0.0),
                          ("person_shoulder_height_m", 0.0)):
            object.__setattr__(self, name, value_range(f"distractors.{name}",
                                                       getattr(self, name), low))
        whole_number("distractors.loose_keypoints", self.loose_keypoints,
                     "set how many of the last keypoint links a loose part may start at (e.g. 3)")
        whole_number("distractors.cable_segments", self.cable_segments,
                     "set how many capsules draw a cable (e.g. 24)")
        for name in ("occluder_prob", "textured_prob", "held_prob", "held_board_prob",
                     "held_textured_prob", "held_checker_prob", "robot_prob", "loose_prob",
                     "cable_prob", "person_prob", "hand_prob"):
            probability(f"distractors.{name}", getattr(self, name))
        for name in ("held_size_m", "held_offset_m"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise InputError(f"distractors.{name} must be [low, high] metres with "
                                 f"0 <= low <= high")


@dataclass(frozen=True)
class SequenceConfig:
    """`random`: independent frames. `fixed_camera`: one camera, N joint configurations.
    `trajectory`: one camera and a smooth timed joint trajectory through random waypoints."""

    mode: str = "random"
    fps: float = 30.0
    waypoint_period_s: float = 1.5

    def __post_init__(self) -> None:
        if self.mode not in ("random", "fixed_camera", "trajectory"):
            raise InputError(f"sequence.mode '{self.mode}' must be random, fixed_camera or "
                             f"trajectory")
        if not (self.fps > 0 and self.waypoint_period_s > 0):
            raise InputError("sequence.fps and sequence.waypoint_period_s must be positive")


@dataclass(frozen=True)
class Sensor:
    """What a real camera adds to each frame (0, the default: nothing). `gain_sigma`: automatic
    exposure, the 8-bit channels times one gain whose log has this standard deviation (in linear
    light the same gain). `noise_std`: read noise, Gaussian, this standard deviation in 8-bit
    levels, anew for every pixel and frame. `blur_px`: the lens's and demosaicing's blur, a
    Gaussian of this standard deviation in pixels, before the gain and noise. `exposure_s`
    (sequence mode `trajectory` only): the shutter's exposure, the arm smeared along its path
    over it, drawn as the mean of `exposure_samples` renders (`synth.exposure`). Clipped 0-255."""

    gain_sigma: float = 0.0
    noise_std: float = 0.0
    blur_px: float = 0.0
    exposure_s: float = 0.0
    exposure_samples: int = 7

    def __post_init__(self) -> None:
        for name in ("gain_sigma", "noise_std", "blur_px", "exposure_s"):
            non_negative(f"sensor.{name}", getattr(self, name))
        whole_number("sensor.exposure_samples", self.exposure_samples,
                     "set how many renders draw one exposure (e.g. 7)")


@dataclass(frozen=True)
class Output:
    image_format: str = "png"
    jpeg_quality: int = 95
    depth: bool = False                    # also write NNNNNN.depth.png (uint16 millimetres)

    def __post_init__(self) -> None:
        if self.image_format not in ("png", "jpg"):
            raise InputError("output.image_format must be png or jpg")
        if not 1 <= self.jpeg_quality <= 100:
            raise InputError(f"output.jpeg_quality must be 1-100, got {self.jpeg_quality}")


@dataclass(frozen=True)
class SynthConfig:
    camera: CameraShell = field(default_factory=CameraShell)
    intrinsics: Intrinsics = field(default_factory=Intrinsics)
    joints: Joints = field(default_factory=Joints)
    lights: Lights = field(default_factory=Lights)
    appearance: Appearance = field(default_factory=Appearance)
    background: Background = field(default_factory=Background)
    distractors: Distractors = field(default_factory=Distractors)
    sequence: SequenceConfig = field(default_factory=SequenceConfig)
    sensor: Sensor = field(default_factory=Sensor)
    output: Output = field(default_factory=Output)

    def __post_init__(self) -> None:
        exposure, sequence = self.sensor.exposure_s, self.sequence
        if exposure and sequence.mode != "trajectory":
            raise InputError(f"sensor.exposure_s needs sequence.mode trajectory (the arm's "
                             f"joints over time), not '{sequence.mode}'",
                             fix="set sequence.mode=trajectory, or sensor.exposure_s=0")
        if exposure > 1.0 / sequence.fps:
            raise InputError(f"sensor.exposure_s {exposure} s is longer than a frame at "
                             f"{sequence.fps} frames/s", fix="give the exposure in seconds, at "
                             "most 1 / sequence.fps (e.g. 0.01)")

    def to_dict(self) -> dict[str, Any]:
        return plain(dataclasses.asdict(self))


def config_from_dict(values: dict[str, Any] | None) -> SynthConfig:
    return recipe_from_dict(SynthConfig, values or {})


def load_config(path: str | Path | None, overrides: Sequence[str] = ()) -> SynthConfig:
    """The recipe in a YAML file (None: the defaults) with `KEY=VALUE` overrides."""
    return load_recipe(SynthConfig, path, overrides, "a YAML recipe from configs/synth/")
