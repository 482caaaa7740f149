"""Model extensions: parametrised changes of the simulated robot and camera.

The nominal model is the URDF robot driven by the logged joint readings, seen by a pinhole
camera with the data's intrinsics. An extension corrects it where the real system differs
(the vocabulary of extended_model.yaml, docs/data_format.md, and `dream diagnose`):

- `joint_offset`: true joint = reading + offset (rad or m), per joint.
- `lens_distortion`: plumb_bob (k1, k2, p1, p2) of the real lens.
- `intrinsics_error`: the corrected fx, fy, cx, cy (pixels).
- `time_offset`: joint readings lag the images by `seconds`: the arm's state at image time t is
  the reading stamped t + seconds (readings interpolated in time).
- `link_length`: metres added along a joint's origin offset (its length), per joint.
- `camera_moved`: from frame `frame` on, T_cam_base(after) = dT @ T_cam_base(before), dT the
  rotation vector `rotation_rad` and translation `translation_m` in the camera frame.
- `keypoint_bias`: the keypoint is not its link's origin but this point of the link frame (m).

A `ModelExtension` reads and writes a small YAML file (`dream diagnose` writes it;
`dream calibrate --model-extension` and `dream synth --model-extension` read it). Applying an
extension is pure: `extended_camera`, `extended_robot`, `effective_joints`, `keypoint_points`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.robot import Robot
from dream.transforms import T_from_rotvec_t

EFFECT_NAMES = ("joint_offset", "lens_distortion", "intrinsics_error", "time_offset",
                "link_length", "camera_moved", "keypoint_bias")
DISTORTION_NAMES = ("k1", "k2", "p1", "p2")
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")
FORMAT = "dream-model-extension"
FORMAT_VERSION = 1


def _finite(value: Any, what: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise InputError(f"{what} is {x}", fix="give a finite number")
    return x


def _vector3(value: Any, what: str) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != 3:
        raise InputError(f"{what} must be 3 numbers [x, y, z], got {value!r}")
    return tuple(_finite(v, what) for v in value)  # type: ignore[return-value]


@dataclass(frozen=True)
class CameraMove:
    """The camera moved before frame `frame` (the first frame seen from the new pose).

    T_cam_base(after) = dT @ T_cam_base(before), dT = [R(rotation_rad) | translation_m]
    expressed in the camera frame before the move.
    """

    frame: str
    rotation_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not isinstance(self.frame, str) or not self.frame:
            raise InputError("camera_moved.frame must be a frame name, e.g. \"000120\"")
        object.__setattr__(self, "rotation_rad", _vector3(self.rotation_rad,
                                                          "camera_moved.rotation_rad"))
        object.__setattr__(self, "translation_m", _vector3(self.translation_m,
                                                           "camera_moved.translation_m"))

    @property
    def T_after_before(self) -> np.ndarray:
        """dT (4, 4): camera frame before the move -> camera frame after it."""
        return T_from_rotvec_t(np.array(self.rotation_rad), np.array(self.translation_m))

    @property
    def rotation_angle_rad(self) -> float:
        return float(np.linalg.norm(self.rotation_rad))

    @property
    def camera_displacement_m(self) -> float:
        """How far the camera centre moved, m."""
        dT = self.T_after_before
        return float(np.linalg.norm(dT[:3, :3].T @ dT[:3, 3]))


@dataclass(frozen=True)
class ModelExtension:
    """Corrections of the nominal robot and camera model (all optional; empty = nominal).

    Attributes:
        joint_offset_rad: joint name -> offset added to its readings (rad, or m if prismatic).
        link_length_m: joint name -> metres added along its origin offset.
        keypoint_bias_m: keypoint (link) name -> (3,) point of the link frame, m.
        distortion: (k1, k2, p1, p2) plumb_bob of the real lens, or None.
        intrinsics: corrected (fx, fy, cx, cy), pixels, or None.
        time_offset_s: joint readings lag the images by this, s (None: not modelled).
        camera_moved: the camera's move during the sequence, or None.
        robot: the robot the extension was fitted for (informative; checked when given).
    """

    joint_offset_rad: Mapping[str, float] = field(default_factory=dict)
    link_length_m: Mapping[str, float] = field(default_factory=dict)
    keypoint_bias_m: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    distortion: tuple[float, float, float, float] | None = None
    intrinsics: tuple[float, float, float, float] | None = None
    time_offset_s: float | None = None
    camera_moved: CameraMove | None = None
    robot: str | None = None

    def __post_init__(self) -> None:
        for name in ("joint_offset_rad", "link_length_m"):
            values = {str(k): _finite(v, f"{name}[{k}]") for k, v in
                      dict(getattr(self, name)).items()}
            object.__setattr__(self, name, values)
        bias = {str(k): _vector3(v, f"keypoint_bias[{k}]") for k, v in
                dict(self.keypoint_bias_m).items()}
        object.__setattr__(self, "keypoint_bias_m", bias)
        if self.distortion is not None:
            if len(self.distortion) != 4:
                raise InputError(f"lens_distortion needs k1, k2, p1, p2, got {self.distortion}")
            object.__setattr__(self, "distortion", tuple(
                _finite(v, "lens_distortion") for v in self.distortion))
        if self.intrinsics is not None:
            if len(self.intrinsics) != 4:
                raise InputError(f"intrinsics_error needs fx, fy, cx, cy, got {self.intrinsics}")
            values = tuple(_finite(v, "intrinsics_error") for v in self.intrinsics)
            if values[0] <= 0 or values[1] <= 0:
                raise InputError(f"intrinsics_error focal lengths must be > 0, got {values}")
            object.__setattr__(self, "intrinsics", values)
        if self.time_offset_s is not None:
            object.__setattr__(self, "time_offset_s", _finite(self.time_offset_s,
                                                              "time_offset.seconds"))
        if self.camera_moved is not None and not isinstance(self.camera_moved, CameraMove):
            raise InputError("camera_moved must be a CameraMove")

    # ----- what it holds ------------------------------------------------------------------

    @property
    def effects(self) -> tuple[str, ...]:
        """Names (extended_model.yaml vocabulary) of the effects this extension sets."""
        present = {
            "joint_offset": bool(self.joint_offset_rad),
            "lens_distortion": self.distortion is not None,
            "intrinsics_error": self.intrinsics is not None,
            "time_offset": self.time_offset_s is not None,
            "link_length": bool(self.link_length_m),
            "camera_moved": self.camera_moved is not None,
            "keypoint_bias": bool(self.keypoint_bias_m),
        }
        return tuple(n for n in EFFECT_NAMES if present[n])

    @property
    def is_empty(self) -> bool:
        return not self.effects

    def merged(self, other: ModelExtension) -> ModelExtension:
        """This extension with `other`'s effects added (other wins where both set one)."""
        return dataclasses.replace(
            self,
            joint_offset_rad={**self.joint_offset_rad, **other.joint_offset_rad},
            link_length_m={**self.link_length_m, **other.link_length_m},
            keypoint_bias_m={**self.keypoint_bias_m, **other.keypoint_bias_m},
            distortion=other.distortion if other.distortion is not None else self.distortion,
            intrinsics=other.intrinsics if other.intrinsics is not None else self.intrinsics,
            time_offset_s=other.time_offset_s if other.time_offset_s is not None
            else self.time_offset_s,
            camera_moved=other.camera_moved if other.camera_moved is not None
            else self.camera_moved,
            robot=self.robot or other.robot)

    # ----- effect parameters in the extended_model.yaml vocabulary -------------------------

    def effect_params(self, name: str) -> dict[str, Any]:
        """The `params` of one effect as `diagnosis.json` writes them."""
        if name == "joint_offset":
            return dict(self.joint_offset_rad)
        if name == "link_length":
            return dict(self.link_length_m)
        if name == "keypoint_bias":
            return {k: list(v) for k, v in self.keypoint_bias_m.items()}
        if name == "lens_distortion":
            return dict(zip(DISTORTION_NAMES, self.distortion or (0.0,) * 4, strict=True))
        if name == "intrinsics_error":
            if self.intrinsics is None:
                return {}
            return dict(zip(INTRINSIC_NAMES, self.intrinsics, strict=True))
        if name == "time_offset":
            return {"seconds": self.time_offset_s}
        if name == "camera_moved":
            move = self.camera_moved
            if move is None:
                return {}
            return {"frame": move.frame, "rotation_rad": list(move.rotation_rad),
                    "translation_m": list(move.translation_m),
                    "rotation_angle_rad": move.rotation_angle_rad,
                    "camera_displacement_m": move.camera_displacement_m}
        raise InputError(f"unknown effect '{name}'", fix=f"use one of {', '.join(EFFECT_NAMES)}")

    def to_dict(self) -> dict[str, Any]:
        doc: dict[str, Any] = {"format": FORMAT, "version": FORMAT_VERSION}
        if self.robot:
            doc["robot"] = self.robot
        doc["effects"] = {name: self.effect_params(name) for name in self.effects}
        return doc


# The parameter keys of the effects whose keys are fixed (the others are keyed by joint,
# link or keypoint name, checked against the robot when applied). camera_moved's last two are
# derived values that `to_dict` writes for the reader; they are read and ignored.
EFFECT_KEYS: dict[str, tuple[str, ...]] = {
    "lens_distortion": DISTORTION_NAMES,
    "intrinsics_error": INTRINSIC_NAMES,
    "time_offset": ("seconds",),
    "camera_moved": ("frame", "rotation_rad", "translation_m", "rotation_angle_rad",
                     "camera_displacement_m"),
}
FILE_KEYS = ("format", "version", "robot", "effects")


def _check_keys(name: str, params: Mapping[str, Any]) -> None:
    allowed = EFFECT_KEYS.get(name)
    if allowed is None:
        return
    unknown = [str(k) for k in params if k not in allowed]
    if unknown:
        raise InputError(f"effect '{name}' has unknown parameter '{unknown[0]}'",
                         fix=f"use the parameters of {name}: {', '.join(allowed)}")


def extension_from_effects(effects: Mapping[str, Mapping[str, Any]],
                           robot: str | None = None) -> ModelExtension:
    """A `ModelExtension` from {effect name: params} (the extended_model.yaml vocabulary); an
    unknown effect or parameter is an `InputError` naming it."""
    kwargs: dict[str, Any] = {"robot": robot}
    for name, params in effects.items():
        if name not in EFFECT_NAMES:
            raise InputError(f"unknown effect '{name}'",
                             fix=f"use one of {', '.join(EFFECT_NAMES)}")
        if not isinstance(params, Mapping):
            raise InputError(f"effect '{name}' needs a mapping of parameters, got {params!r}")
        _check_keys(name, params)
        if name == "joint_offset":
            kwargs["joint_offset_rad"] = dict(params)
        elif name == "link_length":
            kwargs["link_length_m"] = dict(params)
        elif name == "keypoint_bias":
            kwargs["keypoint_bias_m"] = dict(params)
        elif name == "lens_distortion":
            kwargs["distortion"] = tuple(params.get(k, 0.0) for k in DISTORTION_NAMES)
        elif name == "intrinsics_error":
            missing = [k for k in INTRINSIC_NAMES if k not in params]
            if missing:
                raise InputError(f"intrinsics_error lacks {', '.join(missing)}",
                                 fix="give the corrected fx, fy, cx, cy")
            kwargs["intrinsics"] = tuple(params[k] for k in INTRINSIC_NAMES)
        elif name == "time_offset":
            if "seconds" not in params:
                raise InputError("time_offset needs 'seconds'")
            kwargs["time_offset_s"] = params["seconds"]
        elif name == "camera_moved":
            if "frame" not in params:
                raise InputError("camera_moved needs 'frame' (the first frame after the move)")
            kwargs["camera_moved"] = CameraMove(str(params["frame"]),
                                                params.get("rotation_rad", (0.0, 0.0, 0.0)),
                                                params.get("translation_m", (0.0, 0.0, 0.0)))
    return ModelExtension(**kwargs)


def read_extension(path: str | Path) -> ModelExtension:
    """Read a model-extension YAML (as written by `dream diagnose`)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("model extension file not found", path,
                         "give the extended_model.yaml written by dream diagnose")
    try:
        doc = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot parse the model extension ({type(exc).__name__})", path,
                         "give a YAML file written by dream diagnose") from None
    fix = "give a YAML file written by dream diagnose"
    if not isinstance(doc, dict) or not isinstance(doc.get("effects", {}), (dict, type(None))):
        raise InputError("not a model extension (expected a mapping with 'effects')", path, fix)
    unknown = [str(k) for k in doc if k not in FILE_KEYS]
    if unknown:
        raise InputError(f"unknown key '{unknown[0]}' in the model extension", path,
                         f"use only {', '.join(FILE_KEYS)}")
    if "format" in doc and doc["format"] != FORMAT:
        raise InputError(f"format is {doc['format']!r}, not '{FORMAT}'", path, fix)
    version = doc.get("version", FORMAT_VERSION)
    if isinstance(version, bool) or version != FORMAT_VERSION:
        raise InputError(f"version {version!r} of the model extension format is not supported "
                         f"(this dream reads version {FORMAT_VERSION})", path, fix)
    robot = doc.get("robot")
    if robot is not None and (not isinstance(robot, str) or not robot):
        raise InputError(f"robot must be a robot name, got {robot!r}", path, fix)
    try:
        return extension_from_effects(doc.get("effects") or {}, robot)
    except InputError as exc:
        raise InputError(exc.problem, path, exc.fix or f"correct the file, or {fix}") from None


def extension_yaml(extension: ModelExtension) -> str:
    header = ("# Model extension written by dream diagnose: corrections of the simulated robot "
              "and camera.\n# Read by: dream calibrate --model-extension FILE, dream synth "
              "--model-extension FILE.\n# Units: metres, radians, seconds, pixels.\n")
    return header + yaml.safe_dump(extension.to_dict(), sort_keys=False)


# ----- applying an extension (pure) ----------------------------------------------------------

def extended_camera(camera: CameraIntrinsics, extension: ModelExtension) -> CameraIntrinsics:
    """The camera with corrected intrinsics and distortion (others kept)."""
    fx, fy, cx, cy = extension.intrinsics or (camera.fx, camera.fy, camera.cx, camera.cy)
    distortion = camera.distortion
    if extension.distortion is not None:
        k3 = camera.distortion[4] if camera.distortion else 0.0
        distortion = tuple(extension.distortion) + (k3,)
    return CameraIntrinsics(fx, fy, cx, cy, camera.width, camera.height, distortion)


def extended_robot(robot: Robot, extension: ModelExtension) -> Robot:
    """The robot with the link length changes applied (unknown joint -> RobotError)."""
    if extension.robot and extension.robot != robot.name:
        raise InputError(f"the model extension was fitted for robot '{extension.robot}', not "
                         f"'{robot.name}'", fix="use the extension of this robot")
    return robot.with_link_length_changes(extension.link_length_m) \
        if extension.link_length_m else robot


def joint_offset_vector(robot: Robot, offsets: Mapping[str, float]) -> np.ndarray:
    """(J,) offsets in the robot's joint order from joint name -> offset."""
    out = np.zeros(robot.num_joints)
    for name, value in offsets.items():
        if name not in robot.joint_names:
            raise InputError(f"joint offset for unknown joint '{name}'",
                             fix=f"use joints of {robot.name}: {', '.join(robot.joint_names)}")
        out[robot.joint_names.index(name)] = value
    return out


def distinct_readings(times_s: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The readings at which the joint vector changed (a logger that repeats the last reading
    between updates writes stale copies: the time of a reading is when its value appeared).

    Args:
        times_s: (F,) increasing times; joints: (F, J).
    Returns:
        (times (M,), joints (M, J)) with M >= 1.
    """
    times_s = np.asarray(times_s, dtype=float)
    joints = np.asarray(joints, dtype=float)
    if times_s.ndim != 1 or joints.shape[:1] != times_s.shape:
        raise InputError(f"times {times_s.shape} and joints {joints.shape} do not match")
    keep = np.ones(len(times_s), bool)
    keep[1:] = np.any(joints[1:] != joints[:-1], axis=1)
    return times_s[keep], joints[keep]


def interpolate_joints(times_s: np.ndarray, joints: np.ndarray,
                       query_s: np.ndarray) -> np.ndarray:
    """Joint readings (M,) / (M, J) interpolated at `query_s` (Q,): shape-preserving cubic
    (PCHIP) between readings, held constant outside them. Returns (Q, J)."""
    from scipy.interpolate import PchipInterpolator

    times_s = np.asarray(times_s, dtype=float)
    joints = np.asarray(joints, dtype=float)
    query = np.clip(np.asarray(query_s, dtype=float), times_s[0], times_s[-1])
    if len(times_s) == 1:
        return np.broadcast_to(joints[0], (len(query), joints.shape[1])).copy()
    if np.any(np.diff(times_s) <= 0):
        raise InputError("joint reading times must increase strictly",
                         fix="sort frames by timestamp")
    return PchipInterpolator(times_s, joints, axis=0, extrapolate=False)(query)


def effective_joints(joints: np.ndarray, times_s: np.ndarray | None,
                     time_offset_s: float | None) -> np.ndarray:
    """(F, J) joint values at the image times: the readings shifted by the time offset."""
    joints = np.asarray(joints, dtype=float)
    if time_offset_s is None:  # not modelled: the readings as logged
        return joints  # (a modelled offset of 0 still interpolates: one model for every value)
    if times_s is None:
        raise InputError("a time offset needs frame timestamps",
                         fix="give data with timestamps or drop the time_offset effect")
    t, q = distinct_readings(times_s, joints)
    return interpolate_joints(t, q, np.asarray(times_s, dtype=float) + time_offset_s)


def keypoint_points(robot: Robot, joints: np.ndarray, joint_offsets: np.ndarray | None,
                    keypoint_bias_m: Mapping[str, Any]) -> np.ndarray:
    """(F, K, 3) keypoints in the base frame: link origins, or biased points of the links."""
    if not keypoint_bias_m:
        return robot.forward_kinematics(joints, joint_offsets)
    for name in keypoint_bias_m:
        if name not in robot.keypoint_names:
            raise InputError(f"keypoint bias for unknown keypoint '{name}'",
                             fix=f"use keypoints of {robot.name}: "
                                 f"{', '.join(robot.keypoint_names)}")
    T = robot.link_poses(joints, robot.keypoint_names, joint_offsets)
    bias = np.array([keypoint_bias_m.get(k, (0.0, 0.0, 0.0)) for k in robot.keypoint_names],
                    dtype=float)
    return np.einsum("...kij,kj->...ki", T[..., :3, :3], bias) + T[..., :3, 3]


def frames_after_move(frame_names: tuple[str, ...], extension: ModelExtension) -> np.ndarray:
    """(F,) bool: frames at or after the camera move (all False without one)."""
    after = np.zeros(len(frame_names), bool)
    if extension.camera_moved is None:
        return after
    if extension.camera_moved.frame not in frame_names:
        raise InputError(f"camera_moved names frame '{extension.camera_moved.frame}', which "
                         f"the data does not have", fix="use the extension of this data")
    after[frame_names.index(extension.camera_moved.frame):] = True
    return after


def extended_points(robot: Robot, joints: np.ndarray, times_s: np.ndarray | None,
                    extension: ModelExtension) -> np.ndarray:
    """(F, K, 3) keypoints in the base frame under the extension's kinematic effects
    (time offset, joint offsets, link lengths, keypoint bias)."""
    robot_x = extended_robot(robot, extension)
    q = effective_joints(joints, times_s, extension.time_offset_s)
    offsets = joint_offset_vector(robot_x, extension.joint_offset_rad) \
        if extension.joint_offset_rad else None
    return keypoint_points(robot_x, q, offsets, extension.keypoint_bias_m)
