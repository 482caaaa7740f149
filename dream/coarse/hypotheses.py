"""Camera hypotheses of the detector-free start: around a rough guess, or on a shell around the
robot, each aimed so that the robot's centre lands where the images show it (pure).

A rotation of the camera about its own centre moves the whole image, so a hypothesis is first
chosen by where the camera is and how it is rolled, then turned (`aim`) so that the robot's
centre in the base frame projects onto the centre of the robot's pixels in the images. What
is left for the score to decide is the camera position and roll.

    >>> from dream.camera import CameraIntrinsics
    >>> camera = CameraIntrinsics(100.0, 100.0, 31.5, 23.5, 64, 48)
    >>> T = guess_pose(np.array([2.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.5]))
    >>> aimed = aim(T[None], np.array([0.0, 0.0, 0.5]), np.array([40.0, 20.0]), camera)[0]
    >>> from dream.camera import project
    >>> project(camera, aimed[:3, :3] @ [0.0, 0.0, 0.5] + aimed[:3, 3]).round(6).tolist()
    [40.0, 20.0]
"""

from __future__ import annotations

import numpy as np

from dream.camera import CameraIntrinsics, pixels_to_normalized
from dream.errors import InputError
from dream.transforms import R_from_rotvec, invert_T, look_at

BASE_X = np.array([1.0, 0.0, 0.0])
NEAR_VERTICAL_COS = 0.99      # a camera looking this close to straight up or down
MIN_LOOK_DISTANCE_M = 0.05    # the look-at point must lie at least this far from the camera


def guess_pose(position_base_m: np.ndarray, target_base_m: np.ndarray,
               roll_rad: float = 0.0) -> np.ndarray:
    """T_cam_base of a camera at `position_base_m` (3,) aimed at `target_base_m` (3,): the
    image x axis level, or for a camera looking (nearly) straight down or up, the image up
    along base x; then rolled by `roll_rad` about the optical axis.

    Raises:
        InputError: the two points coincide.
    """
    position = np.asarray(position_base_m, float)
    target = np.asarray(target_base_m, float)
    distance = np.linalg.norm(target - position)
    if not distance >= MIN_LOOK_DISTANCE_M:
        raise InputError(f"the camera at {position.tolist()} and the point it looks at "
                         f"{target.tolist()} coincide",
                         fix="give --look-at a point on the robot, metres in the base frame")
    vertical = abs((target - position)[2]) / distance > NEAR_VERTICAL_COS
    return look_at(position, target, roll_rad, up_base=BASE_X) if vertical else \
        look_at(position, target, roll_rad)


def around(T_cam_base: np.ndarray, sigma_m: float, sigma_rad: float, count: int,
           rng: np.random.Generator) -> np.ndarray:
    """(count, 4, 4) hypotheses around `T_cam_base`: the camera centre moved by N(0, sigma_m)
    per base axis, the camera turned by a rotation vector N(0, sigma_rad) per axis; the first
    is `T_cam_base` itself."""
    T_base_cam = invert_T(np.asarray(T_cam_base, float))
    out = np.empty((count, 4, 4))
    out[0] = T_cam_base
    for i in range(1, count):
        T = T_base_cam.copy()
        T[:3, :3] = T_base_cam[:3, :3] @ R_from_rotvec(rng.normal(0.0, sigma_rad, 3))
        T[:3, 3] += rng.normal(0.0, sigma_m, 3)
        out[i] = invert_T(T)
    return out


def fibonacci_directions(count: int, min_elevation_sin: float) -> np.ndarray:
    """(n, 3) unit directions spread evenly over the sphere's part with z >=
    `min_elevation_sin` (a Fibonacci lattice of `count` points there).

    >>> d = fibonacci_directions(50, 0.0)
    >>> d.shape, bool(np.all(d[:, 2] >= 0)), bool(np.allclose(np.linalg.norm(d, axis=1), 1))
    ((50, 3), True, True)
    """
    i = np.arange(count) + 0.5
    z = 1.0 - (1.0 - min_elevation_sin) * i / count
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def shell(centre_base_m: np.ndarray, size_m: float, directions: np.ndarray,
          distances: tuple[float, ...], rolls: int) -> np.ndarray:
    """(n, 4, 4) cameras on a shell around `centre_base_m`: along each of `directions`, at
    each of `distances` x `size_m`, looking at the centre, with `rolls` rolls evenly spaced
    over a full turn."""
    centre = np.asarray(centre_base_m, float)
    out = []
    for direction in np.asarray(directions, float):
        for distance in distances:
            for roll in np.arange(rolls) * 2.0 * np.pi / rolls:
                out.append(guess_pose(centre + distance * size_m * direction, centre, roll))
    return np.array(out)


def aim(T_cam_base: np.ndarray, centre_base_m: np.ndarray, uv_target: np.ndarray,
        camera: CameraIntrinsics) -> np.ndarray:
    """(n, 4, 4) hypotheses (n, 4, 4) turned about their camera centres so that
    `centre_base_m` (3,) projects onto `uv_target` (2,) (module doc); a hypothesis with the
    centre behind it is turned the shortest way too."""
    T = np.array(T_cam_base, dtype=float)
    ray = np.append(pixels_to_normalized(camera, np.asarray(uv_target, float)), 1.0)
    ray /= np.linalg.norm(ray)
    P_cam = np.einsum("nij,j->ni", T[:, :3, :3], np.asarray(centre_base_m, float)) + T[:, :3, 3]
    a = P_cam / np.linalg.norm(P_cam, axis=1, keepdims=True)
    for i, a_i in enumerate(a):
        R = _rotation_between(a_i, ray)
        T[i, :3, :3] = R @ T[i, :3, :3]
        T[i, :3, 3] = R @ T[i, :3, 3]
    return T


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit vector a onto unit vector b."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        other = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        axis = np.cross(a, other)
        return R_from_rotvec(np.pi * axis / np.linalg.norm(axis))
    return R_from_rotvec(axis / s * np.arctan2(s, c))
