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
- `held_readings`: the joint log updates every `period_s` (slower than the camera) and repeats
  its last reading in between; the arm's state at an image is interpolated in time between the
  updates (`dream.readings.interpolated_joints`). `joints` names the held joints (empty: all);
  `phase_s` is when the updates were sampled relative to where `dream.readings.update_times`
  places them (on the log's clock, or the middle of the frame interval in which they first
  appear), as `time_offset` counts. With
  `time_offset` as well, the updates also lag the images by its seconds.
- `link_geometry`: the visible geometry of a link differs from the URDF (a tool, a gripper, a
  held board): a box attached to it, its visuals scaled, or its outline excluded from image
  comparisons (`dream.robot.link_geometry`); per link. Keypoints stay link origins.

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

from dream.errors import InputError
from dream.robot.link_geometry import LinkGeometry, parse_link_geometry
from dream.transforms import T_from_rotvec_t

# the effects keypoint data shows (the diagnosis search, dream.inject), and those only images show
EFFECT_NAMES = ("joint_offset", "lens_distortion", "intrinsics_error", "time_offset",
                "link_length", "camera_moved", "keypoint_bias", "held_readings")
IMAGE_EFFECT_NAMES = ("link_geometry",)
VOCABULARY = EFFECT_NAMES + IMAGE_EFFECT_NAMES
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
class HeldReadings:
    """A joint log that updates every `period_s` and repeats its last reading in between;
    `joints`: the held joints (empty: all); `phase_s`: the updates' sampling phase (module
    doc)."""

    period_s: float
    joints: tuple[str, ...] = ()
    phase_s: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "phase_s", _finite(self.phase_s, "held_readings.phase_s"))
        period = _finite(self.period_s, "held_readings.period_s")
        if period <= 0:
            raise InputError(f"held_readings.period_s must be > 0, got {period}")
        object.__setattr__(self, "period_s", period)
        if isinstance(self.joints, str) or not all(isinstance(j, str) for j in self.joints):
            raise InputError(f"held_readings.joints must be a list of joint names, got "
                             f"{self.joints!r}")
        object.__setattr__(self, "joints", tuple(self.joints))

    def columns(self, joint_names: tuple[str, ...]) -> list[int]:
        """Indices of the held joints among `joint_names` (all of them when `joints` is empty).

        Raises:
            InputError: a held joint that is not among `joint_names`.
        """
        unknown = [j for j in self.joints if j not in joint_names]
        if unknown:
            raise InputError(f"held_readings names unknown joints {', '.join(unknown)}",
                             fix=f"use joints of the robot: {', '.join(joint_names)}")
        return [joint_names.index(j) for j in self.joints] or list(range(len(joint_names)))


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
        held_readings: the joint log's updates, or None (readings as logged).
        link_geometry: links whose visible geometry differs from the URDF (one entry each).
        robot: the robot the extension was fitted for (informative; checked when given).
    """

    joint_offset_rad: Mapping[str, float] = field(default_factory=dict)
    link_length_m: Mapping[str, float] = field(default_factory=dict)
    keypoint_bias_m: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    distortion: tuple[float, float, float, float] | None = None
    intrinsics: tuple[float, float, float, float] | None = None
    time_offset_s: float | None = None
    camera_moved: CameraMove | None = None
    held_readings: HeldReadings | None = None
    link_geometry: tuple[LinkGeometry, ...] = ()
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
        if self.held_readings is not None and not isinstance(self.held_readings, HeldReadings):
            raise InputError("held_readings must be a HeldReadings")
        geometry = tuple(self.link_geometry)
        if not all(isinstance(g, LinkGeometry) for g in geometry):
            raise InputError("link_geometry must hold dream.robot.link_geometry.LinkGeometry")
        if len({g.link for g in geometry}) != len(geometry):
            raise InputError("link_geometry names a link twice", fix="give one entry per link")
        object.__setattr__(self, "link_geometry", geometry)

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
            "held_readings": self.held_readings is not None,
            "link_geometry": bool(self.link_geometry),
        }
        return tuple(n for n in VOCABULARY if present[n])

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
            held_readings=other.held_readings if other.held_readings is not None
            else self.held_readings,
            link_geometry=tuple({g.link: g for g in (*self.link_geometry,
                                                     *other.link_geometry)}.values()),
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
        if name == "held_readings":
            held = self.held_readings
            return {} if held is None else {"period_s": held.period_s,
                                            "joints": list(held.joints),
                                            "phase_s": held.phase_s}
        if name == "link_geometry":
            return {g.link: g.to_params() for g in self.link_geometry}
        raise InputError(f"unknown effect '{name}'", fix=f"use one of {', '.join(VOCABULARY)}")

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
    "held_readings": ("period_s", "joints", "phase_s"),
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
        if name not in VOCABULARY:
            raise InputError(f"unknown effect '{name}'",
                             fix=f"use one of {', '.join(VOCABULARY)}")
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
        elif name == "held_readings":
            if "period_s" not in params:
                raise InputError("held_readings needs 'period_s' (the time between updates)")
            kwargs["held_readings"] = HeldReadings(params["period_s"],
                                                   tuple(params.get("joints") or ()),
                                                   params.get("phase_s", 0.0))
        elif name == "link_geometry":
            kwargs["link_geometry"] = parse_link_geometry(params)
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
    from dream.extension_limits import check_plausible

    try:
        extension = extension_from_effects(doc.get("effects") or {}, robot)
    except InputError as exc:
        raise InputError(exc.problem, path, exc.fix or f"correct the file, or {fix}") from None
    check_plausible(extension, path)
    return extension


def extension_yaml(extension: ModelExtension) -> str:
    header = ("# Model extension written by dream diagnose: corrections of the simulated robot "
              "and camera.\n# Read by: dream calibrate --model-extension FILE, dream synth "
              "--model-extension FILE.\n# Units: metres, radians, seconds, pixels.\n")
    return header + yaml.safe_dump(extension.to_dict(), sort_keys=False)
