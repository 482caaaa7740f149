"""The data a diagnosis fits, and the parameters of the effects fitted to it.

`Problem` holds the measured data of one fixed camera; `Param` is one scalar parameter of an
effect of the catalog (`dream.extension`), `candidate_params` lists every parameter of an effect
for a robot and data, and `build_extension` turns parameter values into a `ModelExtension`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.extension import CameraMove, ModelExtension
from dream.robot import Robot

POINT_EFFECTS = ("joint_offset", "link_length", "keypoint_bias", "time_offset")
VIEW_EFFECTS = ("lens_distortion", "intrinsics_error", "camera_moved")


@dataclass(frozen=True)
class Problem:
    """Measured data of one fixed camera: what every fit of a diagnosis is made from.

    Attributes:
        robot, camera: the nominal robot and camera.
        joints: (F, J) joint readings in the robot's joint order.
        times_s: (F,) image times, s, increasing; None when the data has none.
        uv: (F, K, 2) observed keypoints, px, NaN where not observed.
        frame_names: F names.
    """

    robot: Robot
    camera: CameraIntrinsics
    joints: np.ndarray
    times_s: np.ndarray | None
    uv: np.ndarray
    frame_names: tuple[str, ...]

    def __post_init__(self) -> None:
        F, K, J = len(self.frame_names), self.robot.num_keypoints, self.robot.num_joints
        joints = np.asarray(self.joints, dtype=float)
        uv = np.asarray(self.uv, dtype=float)
        if joints.shape != (F, J):
            raise InputError(f"joints have shape {joints.shape}, expected ({F}, {J})")
        if uv.shape != (F, K, 2):
            raise InputError(f"observations have shape {uv.shape}, expected ({F}, {K}, 2)")
        object.__setattr__(self, "joints", joints)
        object.__setattr__(self, "uv", uv)
        if self.times_s is not None:
            t = np.asarray(self.times_s, dtype=float)
            if t.shape != (F,) or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
                raise InputError("frame timestamps must be F finite, strictly increasing "
                                 "seconds", fix="sort the frames by time or drop timestamps")
            object.__setattr__(self, "times_s", t)

    @property
    def observed(self) -> np.ndarray:
        """(F, K) True where a keypoint was observed."""
        return np.all(np.isfinite(self.uv), axis=-1)

    @property
    def num_frames(self) -> int:
        return len(self.frame_names)


@dataclass(frozen=True)
class Param:
    """One scalar parameter of an effect.

    Attributes:
        effect: effect name (`dream.extension.EFFECT_NAMES`).
        group: parameters tested for significance together (a joint, a keypoint, ...).
        name: its label, e.g. "panda_joint2", "panda_hand.x", "k1".
        typical: a realistic magnitude (rad, m, s, or a fraction): sets the finite-difference
            step and the scale of the identifiability test.
    """

    effect: str
    group: str
    name: str
    typical: float


def candidate_params(effect: str, problem: Problem) -> list[Param]:
    """Every parameter of `effect` for this robot and data (before identifiability checks)."""
    robot = problem.robot
    if effect == "joint_offset":
        return [Param(effect, j, j, np.deg2rad(1.0)) for j in robot.joint_names]
    if effect == "link_length":
        return [Param(effect, j, j, 0.01) for j in offset_joints(robot)]
    if effect == "keypoint_bias":
        return [Param(effect, k, f"{k}.{axis}", 0.01) for k in robot.keypoint_names
                for axis in "xyz"]
    if effect == "lens_distortion":
        return [Param(effect, "k1", "k1", 0.05), Param(effect, "k2", "k2", 0.05),
                Param(effect, "tangential", "p1", 0.005),
                Param(effect, "tangential", "p2", 0.005)]
    if effect == "intrinsics_error":  # relative corrections: fx(1+a), cx + c fx
        return [Param(effect, "fx", "fx", 0.01), Param(effect, "fy", "fy", 0.01),
                Param(effect, "principal_point", "cx", 0.005),
                Param(effect, "principal_point", "cy", 0.005)]
    if effect == "time_offset":
        return [Param(effect, "seconds", "seconds", 0.05)]
    if effect == "camera_moved":
        return [Param(effect, "move", f"move.{n}", s) for n, s in
                (("rx", 0.01), ("ry", 0.01), ("rz", 0.01), ("tx", 0.01), ("ty", 0.01),
                 ("tz", 0.01))]
    raise InputError(f"unknown effect '{effect}'")


def offset_joints(robot: Robot) -> tuple[str, ...]:
    """Joints on the chains from the base to the keypoints whose origin has a length (the
    candidates of `link_length`; `dream.inject.stretchable_joints` keeps only those whose
    change the extrinsic cannot absorb)."""
    return tuple(j.name for j in robot.chain_joints if np.linalg.norm(j.origin[:3, 3]) > 1e-9)


def build_extension(params: tuple[Param, ...], values: np.ndarray, problem: Problem,
                    change_index: int | None) -> ModelExtension:
    """The `ModelExtension` of parameter values (inactive effects: nominal)."""
    joint_offset: dict[str, float] = {}
    link_length: dict[str, float] = {}
    bias: dict[str, list[float]] = {}
    distortion = {"k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}
    intrinsics = {"fx": 0.0, "fy": 0.0, "cx": 0.0, "cy": 0.0}
    move = np.zeros(6)
    has = set()
    time_offset = None
    for p, v in zip(params, values, strict=True):
        has.add(p.effect)
        if p.effect == "joint_offset":
            joint_offset[p.name] = float(v)
        elif p.effect == "link_length":
            link_length[p.name] = float(v)
        elif p.effect == "keypoint_bias":
            bias.setdefault(p.group, [0.0, 0.0, 0.0])["xyz".index(p.name[-1])] = float(v)
        elif p.effect == "lens_distortion":
            distortion[p.name] = float(v)
        elif p.effect == "intrinsics_error":
            intrinsics[p.name] = float(v)
        elif p.effect == "time_offset":
            time_offset = float(v)
        elif p.effect == "camera_moved":
            move["rx ry rz tx ty tz".split().index(p.name.split(".")[1])] = float(v)
    cam = problem.camera
    if "lens_distortion" in has:  # the parameters are changes of the data's own coefficients
        nominal = cam.distortion or (0.0,) * 5
        for i, k in enumerate(("k1", "k2", "p1", "p2")):
            distortion[k] += nominal[i]
    corrected = None
    if "intrinsics_error" in has:
        corrected = (cam.fx * (1 + intrinsics["fx"]), cam.fy * (1 + intrinsics["fy"]),
                     cam.cx + cam.fx * intrinsics["cx"], cam.cy + cam.fy * intrinsics["cy"])
    camera_moved = None
    if "camera_moved" in has:
        if change_index is None:
            raise InputError("camera_moved needs the frame of the move")
        camera_moved = CameraMove(problem.frame_names[change_index], tuple(move[:3]),
                                  tuple(move[3:]))
    return ModelExtension(
        joint_offset_rad=joint_offset, link_length_m=link_length, keypoint_bias_m=bias,
        distortion=tuple(distortion[k] for k in ("k1", "k2", "p1", "p2"))
        if "lens_distortion" in has else None,
        intrinsics=corrected, time_offset_s=time_offset, camera_moved=camera_moved,
        robot=problem.robot.name)
