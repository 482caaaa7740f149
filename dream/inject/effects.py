"""Random effects of the `dream diagnose` vocabulary with realistic magnitudes (`EFFECT_RANGES`)."""

from __future__ import annotations

import math
from collections.abc import Sequence as SequenceOf

import numpy as np

from dream.errors import InputError
from dream.extension import EFFECT_NAMES, CameraMove, HeldReadings, ModelExtension
from dream.inject.identifiability import (
    identifiable_joints,
    moving_keypoints,
    stretchable_joints,
)
from dream.inject.settings import InjectionSettings
from dream.robot import Robot

# ----- realistic effect magnitudes (drawn uniformly in these ranges, random sign/direction) ----
JOINT_OFFSET_RANGE_RAD = (math.radians(0.5), math.radians(3.0))  # on one identifiable joint
DISTORTION_K1_RANGE = (0.03, 0.2)                 # |k1| of plumb_bob; k2 = p1 = p2 = 0
FOCAL_ERROR_RANGE = (0.01, 0.05)                  # |true / nominal - 1| of fx and fy (same)
TIME_OFFSET_RANGE_S = (0.020, 0.150)              # |readings lag|, s
LINK_LENGTH_RANGE_M = (0.005, 0.020)              # |metres added| along one joint's origin
CAMERA_TRANSLATION_RANGE_M = (0.005, 0.020)       # camera_moved: translation, random direction
CAMERA_ROTATION_RANGE_RAD = (math.radians(0.5), math.radians(2.0))  # ... or rotation
CAMERA_MOVE_FRAME_FRACTION = (0.2, 0.8)           # the move happens in the middle 60 % of frames
CAMERA_MOVE_ROTATION_PROB = 0.5                   # chance that a camera move is a rotation
KEYPOINT_BIAS_RANGE_M = (0.010, 0.030)            # |offset| on one keypoint, random direction
HELD_PERIOD_RANGE_S = (0.1, 0.3)                  # a joint log's time between updates, s

EFFECT_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "joint_offset": {"offset_rad": JOINT_OFFSET_RANGE_RAD},
    "lens_distortion": {"abs_k1": DISTORTION_K1_RANGE},
    "intrinsics_error": {"abs_focal_error_fraction": FOCAL_ERROR_RANGE},
    "time_offset": {"abs_seconds": TIME_OFFSET_RANGE_S},
    "link_length": {"abs_metres": LINK_LENGTH_RANGE_M},
    "camera_moved": {"translation_m": CAMERA_TRANSLATION_RANGE_M,
                     "rotation_rad": CAMERA_ROTATION_RANGE_RAD,
                     "frame_fraction": CAMERA_MOVE_FRAME_FRACTION},
    "keypoint_bias": {"metres": KEYPOINT_BIAS_RANGE_M},
    "held_readings": {"period_s": HELD_PERIOD_RANGE_S},
}


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def _direction(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random unit vector (3,)."""
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _pick(rng: np.random.Generator, names: SequenceOf[str], what: str, robot: Robot) -> str:
    if not names:
        raise InputError(f"robot '{robot.name}' has no {what}",
                         fix="inject another effect for this robot")
    return names[int(rng.integers(len(names)))]


def random_effect(effect_name: str, rng: np.random.Generator, robot: Robot,
                  spec: InjectionSettings) -> ModelExtension:
    """One effect of the vocabulary with a random magnitude in `EFFECT_RANGES`, random sign or
    direction, for `robot` seen as `spec` describes (camera_moved: a frame in the middle of
    `spec`'s frames; intrinsics_error: `spec`'s focal lengths scaled)."""
    if effect_name not in EFFECT_NAMES:
        raise InputError(f"unknown effect '{effect_name}'",
                         fix=f"use one of {', '.join(EFFECT_NAMES)}")
    if not isinstance(robot, Robot):
        raise InputError("random_effect needs a dream Robot (dream.robot.load_robot)")
    name = robot.name
    if effect_name == "joint_offset":
        joint = _pick(rng, identifiable_joints(robot), "identifiable joint", robot)
        value = _sign(rng) * rng.uniform(*JOINT_OFFSET_RANGE_RAD)
        return ModelExtension(joint_offset_rad={joint: value}, robot=name)
    if effect_name == "lens_distortion":
        k1 = _sign(rng) * rng.uniform(*DISTORTION_K1_RANGE)
        return ModelExtension(distortion=(k1, 0.0, 0.0, 0.0), robot=name)
    if effect_name == "intrinsics_error":
        scale = 1.0 + _sign(rng) * rng.uniform(*FOCAL_ERROR_RANGE)
        camera = spec.camera
        return ModelExtension(intrinsics=(camera.fx * scale, camera.fy * scale, camera.cx,
                                          camera.cy), robot=name)
    if effect_name == "time_offset":
        if spec.motion != "trajectory":
            raise InputError("a time offset needs a continuous motion",
                             fix="use motion='trajectory' to inject time_offset")
        return ModelExtension(time_offset_s=_sign(rng) * rng.uniform(*TIME_OFFSET_RANGE_S),
                              robot=name)
    if effect_name == "held_readings":
        if spec.motion != "trajectory":
            raise InputError("held readings need a continuous motion",
                             fix="use motion='trajectory' to inject held_readings")
        return ModelExtension(held_readings=HeldReadings(rng.uniform(*HELD_PERIOD_RANGE_S)),
                              robot=name)
    if effect_name == "link_length":
        joint = _pick(rng, stretchable_joints(robot), "joint with a stretchable offset", robot)
        value = _sign(rng) * rng.uniform(*LINK_LENGTH_RANGE_M)
        return ModelExtension(link_length_m={joint: value}, robot=name)
    if effect_name == "camera_moved":
        first, last = CAMERA_MOVE_FRAME_FRACTION
        lo = max(1, math.ceil(first * spec.num_frames))
        hi = min(spec.num_frames - 1, max(lo, math.floor(last * spec.num_frames)))
        frame = spec.frame_names[int(rng.integers(lo, hi + 1))]
        if rng.random() < CAMERA_MOVE_ROTATION_PROB:
            move = CameraMove(frame, rotation_rad=_direction(rng)
                              * rng.uniform(*CAMERA_ROTATION_RANGE_RAD))
        else:
            move = CameraMove(frame, translation_m=_direction(rng)
                              * rng.uniform(*CAMERA_TRANSLATION_RANGE_M))
        return ModelExtension(camera_moved=move, robot=name)
    # keypoint_bias
    keypoint = _pick(rng, moving_keypoints(robot), "moving keypoint", robot)
    offset = _direction(rng) * rng.uniform(*KEYPOINT_BIAS_RANGE_M)
    return ModelExtension(keypoint_bias_m={keypoint: offset}, robot=name)


def random_effects(names: SequenceOf[str], rng: np.random.Generator, robot: Robot,
                   spec: InjectionSettings) -> ModelExtension:
    """Several effects (each drawn by `random_effect`, in order) merged into one extension."""
    if isinstance(names, str):
        names = (names,)
    names = tuple(names)
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InputError(f"effects repeat: {', '.join(repeated)}", fix="name each effect once")
    out = ModelExtension(robot=robot.name)
    for effect in names:
        out = out.merged(random_effect(effect, rng, robot, spec))
    return out
