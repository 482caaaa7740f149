"""Camera hypotheses of the detector-free start: around a rough guess, or on a shell around the
robot, each aimed so that the robot's centre lands where the images show it (pure).

A rotation of the camera about its own centre moves the whole image, so a hypothesis is first
chosen by where the camera is and how it is rolled, then turned (`aim`) so that the robot's
centre in the base frame projects onto the centre of the robot's pixels in the images. What
is left for the score to decide is the camera position and roll. Where a hypothesis sees part
of the robot outside the image (a close-up), the images' pixels centre on the part in view, so
`aim_in_view` turns it further until the centre of that part lands there.

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

from dream.camera import CameraIntrinsics, pixels_to_normalized, project
from dream.errors import InputError
from dream.silhouette import MIN_DEPTH_M
from dream.transforms import R_from_rotvec, camera_coordinates, invert_T, look_at

BASE_X = np.array([1.0, 0.0, 0.0])
NEAR_VERTICAL_COS = 0.99      # a camera looking this close to straight up or down
MIN_LOOK_DISTANCE_M = 0.05    # the look-at point must lie at least this far from the camera
AIM_IN_VIEW_ROUNDS = 3        # turns of `aim_in_view`: each moves the part in view by less
AIM_IN_VIEW_BATCH = 256       # hypotheses projected at once by `aim_in_view`
AIM_IN_VIEW_POINTS = 1000     # at most about this many of the robot's points centre a view


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


def aim_in_view(T_cam_base: np.ndarray, points_base_m: np.ndarray, centre_base_m: np.ndarray,
                uv_target: np.ndarray, camera: CameraIntrinsics,
                rounds: int = AIM_IN_VIEW_ROUNDS) -> np.ndarray:
    """(n, 4, 4) hypotheses aimed by `aim` (n, 4, 4) turned further, `rounds` times, by as
    much as the centre of the robot's points (..., 3, base frame) that each sees inside the
    image lies off `uv_target` (2,): the images' pixels centre on the part of the robot in
    view, which is not all of it where the image border cuts it (a close-up). A hypothesis
    that sees none of the points is returned as given.

    >>> camera = CameraIntrinsics(100.0, 100.0, 31.5, 23.5, 64, 48)
    >>> z = np.linspace(0.0, 1.0, 101)                 # a robot 1 m tall, seen from 1 m
    >>> points, centre = np.stack([0 * z, 0 * z, z], axis=1), np.array([0.0, 0.0, 0.5])
    >>> target = np.array([31.5, 35.0])                # the images' pixels centre low
    >>> T = aim(guess_pose(np.array([1.0, 0.0, 0.2]), 0 * centre)[None], centre, target, camera)
    >>> from dream.camera import project
    >>> def seen(T):
    ...     v = project(camera, points @ T[0, :3, :3].T + T[0, :3, 3])[:, 1]
    ...     inside = (v >= -0.5) & (v <= 47.5)
    ...     return round(float(v[inside].mean()), 1), bool(not inside.all())
    >>> seen(T)                                        # the top cut off, the rest centred high
    (21.8, True)
    >>> seen(aim_in_view(T, points, centre, target, camera))
    (33.0, True)
    """
    T = np.array(T_cam_base, dtype=float)
    P = np.asarray(points_base_m, float).reshape(-1, 3)
    P = P[::max(1, len(P) // AIM_IN_VIEW_POINTS)]
    centre = np.asarray(centre_base_m, float)
    target = np.asarray(uv_target, float)
    for _ in range(rounds):
        for i in range(0, len(T), AIM_IN_VIEW_BATCH):
            batch = T[i:i + AIM_IN_VIEW_BATCH]     # a view: turning it turns T
            seen, some = _in_view_centre(batch, P, camera)
            C = np.einsum("nij,j->ni", batch[:, :3, :3], centre) + batch[:, :3, 3]
            some &= C[:, 2] >= MIN_DEPTH_M
            uv = _pixels(camera, C[some, 0], C[some, 1], C[some, 2])
            batch[some] = _turned(batch[some], C[some], uv + target - seen[some], camera)
    return T


def _in_view_centre(T: np.ndarray, P: np.ndarray, camera: CameraIntrinsics
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) the centre of the pixels of the points P (m, 3) that hypotheses T (n, 4, 4) see
    inside the image (NaN where none), and (n,) whether they see any."""
    X, Y, Z = camera_coordinates(P, T)
    front = Z >= MIN_DEPTH_M
    uv = _pixels(camera, X, Y, np.where(front, Z, 1.0))
    u, v = uv[..., 0], uv[..., 1]
    inside = front & (u >= -0.5) & (u <= camera.width - 0.5) & (v >= -0.5) & (
        v <= camera.height - 0.5)
    count = inside.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        seen = np.stack([(u * inside).sum(axis=1), (v * inside).sum(axis=1)], axis=1) \
            / count[:, None]
    return seen, count > 0


def _turned(T: np.ndarray, C_cam: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics
            ) -> np.ndarray:
    """Hypotheses T (n, 4, 4) turned about their camera centres, each the least, so that a
    point in front of it at C_cam (n, 3) projects onto uv (n, 2)."""
    b = np.concatenate([pixels_to_normalized(camera, uv), np.ones((len(uv), 1))], axis=1)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    a = C_cam / np.linalg.norm(C_cam, axis=1, keepdims=True)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.arctan2(s, np.sum(a * b, axis=1, keepdims=True))
    R = R_from_rotvec(np.where(s > 0, axis / np.where(s > 0, s, 1.0) * angle, 0.0))
    out = T.copy()
    out[:, :3, :3] = R @ T[:, :3, :3]
    out[:, :3, 3] = np.einsum("nij,nj->ni", R, T[:, :3, 3])
    return out


def _pixels(camera: CameraIntrinsics, X: np.ndarray, Y: np.ndarray, Z: np.ndarray
            ) -> np.ndarray:
    """(..., 2) pixels of camera-frame coordinates X, Y, Z (...) in front of the camera; one
    coordinate array at a time where the camera has no distortion."""
    if camera.distortion is not None:
        return project(camera, np.stack([X, Y, Z], axis=-1))
    return np.stack([camera.fx * X / Z + camera.cx, camera.fy * Y / Z + camera.cy], axis=-1)


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


def camera_distance(T_cam_base: np.ndarray, P_base: np.ndarray) -> float:
    """The distance (m) from the camera's centre to the base-frame point `P_base` (3,).

    >>> T = look_at(np.array([3.0, 0.0, 1.0]), np.zeros(3))   # the camera at (3, 0, 1)
    >>> round(camera_distance(T, np.array([0.0, 4.0, 1.0])), 6)
    5.0
    """
    return float(np.linalg.norm(invert_T(T_cam_base)[:3, 3] - np.asarray(P_base, float)))


GUESS_SIGMA_FIX = ("give --guess-sigma METRES,DEGREES (e.g. 0.3,20: are the two swapped?), or "
                   "leave --camera-guess out for the automatic search")


def check_guess_scale(T_cam_base: np.ndarray, sigma_m: float, centre_base_m: np.ndarray,
                      reach_m: float, max_distance: float, max_sigma: float,
                      description: str, look_at_base_m: np.ndarray | None = None,
                      sigma_fix: str = GUESS_SIGMA_FIX) -> None:
    """Refuse a guess whose numbers cannot be metres for this robot: its camera, or the point
    it looks at `look_at_base_m` (3,) where given, farther from the robot's centre
    `centre_base_m` (3,) than `max_distance` times the robot's reach `reach_m` (how far its
    moving parts get from the base origin; millimetres or centimetres given for metres), or a
    1-sigma `sigma_m` above `max_sigma` times it (`--guess-sigma METRES,DEGREES` swapped;
    `sigma_fix` says what to give instead).

    >>> T = look_at(np.array([700.0, 500.0, 600.0]), np.zeros(3))   # millimetres
    >>> check_guess_scale(T, 0.3, np.zeros(3), 0.9, 20.0, 5.0, "a camera at [700, 500, 600]")
    ... # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    dream.errors.InputError: a camera at [700, 500, 600]: the camera lies 1048.8 m from ...
    """
    distance = camera_distance(T_cam_base, centre_base_m)
    if distance > max_distance * reach_m:
        raise InputError(f"{description}: the camera lies {distance:.1f} m from the robot, "
                         f"{distance / reach_m:.0f} times the robot's reach ({reach_m:.2f} m), "
                         f"where a camera that sees it lies within {max_distance:g} times",
                         fix="give the camera guess in metres in the robot's base frame (are "
                             "these millimetres?)")
    if look_at_base_m is not None:
        away = float(np.linalg.norm(np.asarray(look_at_base_m, float) - centre_base_m))
        if away > max_distance * reach_m:
            raise InputError(f"{description}: the point looked at lies {away:.1f} m from the "
                             f"robot, {away / reach_m:.0f} times its reach ({reach_m:.2f} m)",
                             fix="give --look-at in metres in the robot's base frame, a point "
                                 "on the robot (are these millimetres?)")
    if sigma_m > max_sigma * reach_m:
        raise InputError(f"a guess's 1-sigma of {sigma_m:g} m is {sigma_m / reach_m:.0f} times "
                         f"the robot's reach ({reach_m:.2f} m); a guess that rough is no guess",
                         fix=sigma_fix)
