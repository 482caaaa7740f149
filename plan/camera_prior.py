"""What the planner knows about the camera before a calibration: a rough extrinsic, its
uncertainty, the intrinsics.

The extrinsic comes from an earlier calibration's RESULT.json (its camera and 1-sigma with it)
or from a camera position and a point it looks at, both in the base frame.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.hypotheses import around, guess_pose
from dream.errors import InputError
from dream.io import fields
from dream.result import FIX_RESULT, read_result
from dream.robot.identity import same_robot_name
from dream.transforms import check_pose, invert_T

# a rough position guess: 1-sigma per axis when none is given
DEFAULT_POSITION_SIGMA_M = 0.05
DEFAULT_ROTATION_SIGMA_RAD = float(np.deg2rad(3.0))


@dataclass(frozen=True, eq=False)
class CameraPrior:
    """A camera known roughly.

    Attributes:
        camera: intrinsics and image size.
        T_cam_base: (4, 4) the stated extrinsic.
        position_sigma_m: 1-sigma of the camera position along each base axis.
        rotation_sigma_rad: 1-sigma of its orientation about each axis.
        source: where it came from, for the plan's record.
    """

    camera: CameraIntrinsics
    T_cam_base: np.ndarray
    position_sigma_m: float = DEFAULT_POSITION_SIGMA_M
    rotation_sigma_rad: float = DEFAULT_ROTATION_SIGMA_RAD
    source: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.camera, CameraIntrinsics):
            raise InputError("CameraPrior.camera must be dream.camera.CameraIntrinsics")
        object.__setattr__(self, "T_cam_base", check_pose(self.T_cam_base, "T_cam_base"))
        for name in ("position_sigma_m", "rotation_sigma_rad"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise InputError(f"the camera's {name} must be a finite number >= 0, got "
                                 f"{value}")

    @property
    def position_base_m(self) -> np.ndarray:
        """(3,) the stated camera centre in the base frame."""
        return invert_T(self.T_cam_base)[:3, 3]

    def samples(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """(count, 4, 4) extrinsics drawn from the uncertainty; the first is the stated one."""
        if count < 1:
            raise InputError(f"need at least one camera sample, got {count}")
        return around(self.T_cam_base, self.position_sigma_m, self.rotation_sigma_rad, count,
                      rng)


def prior_from_look_at(position_base_m: np.ndarray, target_base_m: np.ndarray,
                       camera: CameraIntrinsics,
                       position_sigma_m: float = DEFAULT_POSITION_SIGMA_M,
                       rotation_sigma_rad: float = DEFAULT_ROTATION_SIGMA_RAD) -> CameraPrior:
    """A camera at `position_base_m` (3,) aimed at `target_base_m` (3,): the image x axis
    level, or for a camera looking (nearly) straight down or up, the image up along base x."""
    position = np.asarray(position_base_m, float)
    target = np.asarray(target_base_m, float)
    T = guess_pose(position, target)
    return CameraPrior(camera, T, position_sigma_m, rotation_sigma_rad,
                       f"position {position.tolist()} looking at {target.tolist()}")


def prior_from_result(path: str | Path, camera: CameraIntrinsics | None = None,
                      position_sigma_m: float | None = None,
                      rotation_sigma_rad: float | None = None,
                      robot_names: Collection[str] = ()) -> CameraPrior:
    """The extrinsic of a RESULT.json, its camera (unless `camera` is given) and its 1-sigma
    (unless given): the largest of its camera-position and rotation sigmas. A result that
    names a robot not among `robot_names` (by name, URDF path or its stem) is refused."""
    path = Path(path)
    doc = read_result(path)
    named = doc.get("robot")
    if robot_names and named is not None and not any(same_robot_name(named, name)
                                                     for name in robot_names):
        raise InputError(f"the result calibrated robot '{named}', not "
                         f"'{sorted(robot_names)[0]}'", path,
                         f"give the result of a calibration of this robot, or --robot {named}")
    if camera is None:
        camera = _result_camera(doc, path)
    if position_sigma_m is None:
        sigma = doc.get("sigma_camera_position_base_m")
        position_sigma_m = DEFAULT_POSITION_SIGMA_M if sigma is None else float(max(
            fields.as_vector(sigma, "sigma_camera_position_base_m", path, 3, FIX_RESULT)))
    if rotation_sigma_rad is None:
        sigma = doc.get("sigma_rotation_rad")
        rotation_sigma_rad = DEFAULT_ROTATION_SIGMA_RAD if sigma is None else float(max(
            fields.as_vector(sigma, "sigma_rotation_rad", path, 3, FIX_RESULT)))
    return CameraPrior(camera, doc["T_cam_base"], position_sigma_m, rotation_sigma_rad,
                       str(path))


def _result_camera(doc: dict, path: Path) -> CameraIntrinsics:
    fix = "give --intrinsics fx,fy,cx,cy,width,height (this result does not record its camera)"
    data = doc.get("data")
    if not isinstance(data, dict) or not isinstance(data.get("camera"), dict):
        raise InputError("the result does not record its camera", path, fix)
    c = data["camera"]
    try:
        distortion = c.get("distortion")
        return CameraIntrinsics(float(c["fx"]), float(c["fy"]), float(c["cx"]), float(c["cy"]),
                                int(c["width"]), int(c["height"]),
                                tuple(distortion) if distortion else None)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"the result's data.camera is incomplete ({exc})", path, fix) from None
