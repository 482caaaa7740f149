"""One mark on the end effector as a start: a point fixed to a link (`--mark-link`, at
`--mark-offset` in that link's frame), clicked in a few frames (`frame,u,v` rows), tracked
between the frames of a dense recording by pyramidal Lucas-Kanade checked forwards and
backwards, then one robust PnP over time: the fixed camera sees the point at its forward-
kinematics position in every frame, so the track and the point's 3D trajectory are the
correspondences of a single pose.

The pose is rough (a few clicked pixels, a trajectory a few decimetres wide): it is the centre
of the silhouette search (`dream.coarse.calibration`), searched around within a 1-sigma taken
from the PnP's own covariance, and the clicks are checked again at the pose found. A mark known
in fewer frames than a pose needs (the end effector seldom in view, frames too far apart to
track) still places cameras: with the orientation given, its clicks fix the position
(`placed_by_mark`), so each orientation of the automatic search becomes one camera that sees
the clicks where they were made.

    >>> import numpy as np
    >>> from dream.camera import CameraIntrinsics, project
    >>> from dream.transforms import look_at, transform_points
    >>> cam = CameraIntrinsics(500.0, 500.0, 320.0, 240.0, 640, 480)
    >>> T = look_at(np.array([1.5, 0.5, 1.0]), np.zeros(3))
    >>> P = np.random.default_rng(0).uniform(-0.4, 0.4, (12, 3))
    >>> fit = mark_pose(P, project(cam, transform_points(T, P)), cam)
    >>> bool(np.allclose(fit.T_cam_base, T, atol=1e-6))
    True
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dream.camera import CameraIntrinsics, pixels_to_normalized, project
from dream.errors import InputError
from dream.pnp import MIN_KEYPOINTS, NoSolution, PoseFit, solve_pnp
from dream.robot import Robot
from dream.sequence import Sequence
from dream.transforms import transform_points

MARK_COLUMNS = ("frame", "u", "v")
MIN_CLICK_SPREAD = 1e-3   # normalised image units: clicks nearer than this are one pixel
MIN_MARK_DEPTH_M = 0.05   # a placed camera sees every marked point at least this far ahead
NORMALISED_MAX = 1.0   # clicks all within [-1, 1] px: normalised image coordinates, not pixels
CACHED_IMAGES = 4   # the tracker steps between neighbours: a few images in memory suffice
FIX_MARKS = ("write one row per clicked frame: frame,u,v (the frame's name or index, the "
             "pixel with the origin at the top-left pixel's centre); dream mark writes it")


@dataclass(frozen=True)
class MarkSettings:
    """Tracking and the search's 1-sigma around the mark's pose. Pixels unless named."""

    window_px: int = 21               # Lucas-Kanade window (square)
    pyramid_levels: int = 3
    max_iterations: int = 30
    epsilon_px: float = 0.01
    max_round_trip_px: float = 1.0    # forwards then backwards must come back within this
    max_track_frames: int = 60        # frames tracked each way from one click
    max_step_m: float = 0.03          # the mark moves farther between two frames: not a dense
                                      # recording there, the track stops
    agree_px: float = 3.0             # two tracks into one frame: averaged within, else dropped
    sigma_factor: float = 3.0         # the search's 1-sigma: this many PnP sigmas ...
    min_sigma_m: float = 0.05         # ... at least this (a PnP of few clicks is optimistic)
    min_sigma_rad: float = math.radians(5.0)
    max_click_residual_px: float = 10.0   # at the pose found, clicks farther off: a finding
    max_offset_reach: float = 1.0     # a mark farther from its link than this times the link's
                                      # farthest distance from the base: not metres

    def __post_init__(self) -> None:
        if self.window_px < 3 or self.window_px % 2 == 0:
            raise InputError(f"window_px must be odd and >= 3, got {self.window_px}")
        for name in ("pyramid_levels", "max_iterations", "max_track_frames"):
            if getattr(self, name) < 0:
                raise InputError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("epsilon_px", "max_round_trip_px", "max_step_m", "agree_px", "sigma_factor",
                     "min_sigma_m", "min_sigma_rad", "max_click_residual_px",
                     "max_offset_reach"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise InputError(f"{name} must be positive, got {getattr(self, name)}")


@dataclass(frozen=True)
class Mark:
    """The mark: its link, its position in that link's frame (m), the clicked frames' indices
    into the sequence and their pixels (n, 2)."""

    link: str
    offset_link_m: np.ndarray
    frames: np.ndarray
    uv: np.ndarray

    def __post_init__(self) -> None:
        if np.shape(self.offset_link_m) != (3,) or not np.all(np.isfinite(self.offset_link_m)):
            raise InputError(f"the mark's offset must be 3 finite metres, got "
                             f"{self.offset_link_m}", fix="give --mark-offset X,Y,Z")
        if np.shape(self.uv) != (len(self.frames), 2):
            raise InputError(f"the mark needs one (u, v) per frame, got {np.shape(self.uv)} "
                             f"for {len(self.frames)} frames", fix=FIX_MARKS)
        if len(set(np.asarray(self.frames).tolist())) != len(self.frames):
            raise InputError("the mark was clicked twice in one frame", fix=FIX_MARKS)


def read_marks(path: str | Path, sequence: Sequence) -> tuple[np.ndarray, np.ndarray]:
    """The clicked frames' indices (sorted) and pixels (n, 2) of a `frame,u,v` CSV to
    calibrate from (`read_mark_rows`, at least one row, not all at the image's corner); a frame
    is named as the sequence names it, or by its index.

    Raises:
        InputError: as `read_mark_rows`; no rows; every click within `NORMALISED_MAX` px of
            the corner (normalised coordinates).
    """
    frames, uv = read_mark_rows(path, sequence)
    if not len(frames):
        raise InputError("the marks file has no rows", path, FIX_MARKS)
    if np.all(np.abs(uv) <= NORMALISED_MAX):
        raise InputError(f"every click lies within {NORMALISED_MAX:g} px of the image's corner: "
                         "normalised coordinates, not pixels?", path,
                         "give u, v in pixels of the data's images (origin at the top-left "
                         "pixel's centre)")
    return frames, uv


def read_mark_rows(path: str | Path, sequence: Sequence, digests: dict[Path, bytes] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a `frame,u,v` CSV as `read_marks` gives them, none or any (as `dream mark`
    goes on from the file it wrote). `digests`: image files' digests already read
    (`dream.io.marks.read_shared_files`; filled with those read here).

    Raises:
        InputError: no such file, another header, a frame not in the data, a pixel outside the
            image or not a number, a frame clicked twice, marks `dream mark` wrote for another
            recording's frames (`dream.io.marks`).
    """
    from dream.io.marks import COMMENT, check_marked_frames, stated_digests

    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise InputError(f"cannot read the marks ({exc.strerror})", path, FIX_MARKS) from None
    comments = [line for line in lines if line.startswith(COMMENT)]
    rows = list(csv.reader(line for line in lines if not line.startswith(COMMENT)))
    if not rows or tuple(c.strip() for c in rows[0]) != MARK_COLUMNS:
        raise InputError(f"the marks' header must be {','.join(MARK_COLUMNS)}", path, FIX_MARKS)
    names = {f.name: i for i, f in enumerate(sequence.frames)}
    cam = sequence.camera
    frames, uv = [], []
    for line, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != len(MARK_COLUMNS):
            raise InputError(f"line {line} has {len(row)} fields, not 3", path, FIX_MARKS)
        index = _frame_index(row[0].strip(), names, len(sequence))
        if index is None:
            raise InputError(f"line {line}: frame {row[0]!r} is not in {sequence.source}", path,
                             "name a frame of the data (its name or index)")
        try:
            u, v = float(row[1]), float(row[2])
        except ValueError:
            raise InputError(f"line {line}: u and v must be numbers, got {row[1:]}", path,
                             FIX_MARKS) from None
        if not cam.in_image(np.array([u, v])):
            raise InputError(f"line {line}: pixel ({u}, {v}) is outside the {cam.width}x"
                             f"{cam.height} image", path, "give pixels of the data's images")
        frames.append(index)
        uv.append((u, v))
    if len(set(frames)) != len(frames):
        raise InputError("a frame is marked twice", path, "keep one row per frame")
    check_marked_frames(path, stated_digests(comments), sequence, frames, digests)
    order = np.argsort(frames)
    return np.asarray(frames, int)[order], np.asarray(uv, float).reshape(-1, 2)[order]


def _frame_index(text: str, names: dict[str, int], count: int) -> int | None:
    if text in names:
        return names[text]
    if text.isdigit() and int(text) < count:
        return int(text)
    return None


def mark_points(robot: Robot, joints: np.ndarray, link: str, offset_link_m: np.ndarray
                ) -> np.ndarray:
    """(n, 3) the mark in the base frame at each row of `joints` (n, J)."""
    T_base_link = robot.link_poses(joints, (link,))[:, 0]
    return T_base_link[:, :3, :3] @ np.asarray(offset_link_m, float) + T_base_link[:, :3, 3]


def clicked_points(robot: Robot, joints: np.ndarray, mark: Mark) -> np.ndarray:
    """(clicks, 3) the mark in the base frame at its clicked frames (`mark.frames`), from
    `joints` (F, J): every frame's readings in the robot's order."""
    return mark_points(robot, np.asarray(joints)[mark.frames], mark.link, mark.offset_link_m)


def check_mark_offset(robot: Robot, joints: np.ndarray, link: str, offset_link_m: np.ndarray,
                      max_reach: float) -> None:
    """Refuse an offset that cannot be metres: the mark farther from its link than `max_reach`
    times the link's farthest distance from the base over `joints` (n, J) (millimetres given
    for metres)."""
    reach = float(np.linalg.norm(robot.link_poses(joints, (link,))[:, 0, :3, 3], axis=1).max())
    offset = float(np.linalg.norm(offset_link_m))
    if offset > max_reach * reach:
        raise InputError(f"the mark lies {offset:.3g} m from {link}, which lies at most "
                         f"{reach:.2f} m from the base", fix="give --mark-offset X,Y,Z in metres "
                         "in that link's frame (are these millimetres?)")


def track_mark(gray: Callable[[int], np.ndarray | None], frames: np.ndarray, uv: np.ndarray,
               P_base: np.ndarray, settings: MarkSettings | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """The clicked pixels and the mark tracked from each click forwards and backwards through
    the frames (`gray(i)`: frame i as (H, W) uint8, None without an image; `P_base` (count, 3):
    the mark in the base frame in every frame), each step kept only where tracking back returns
    within `max_round_trip_px`; a track stops at the next click, at a failed step, where the
    mark moves more than `max_step_m` between frames, or after `max_track_frames`. Where two
    tracks reach one frame they are averaged if they agree within `agree_px`, else dropped.
    Returns frames (sorted) and pixels."""
    settings = settings or MarkSettings()
    if np.shape(uv) != (len(frames), 2) or np.ndim(P_base) != 2 or np.shape(P_base)[1] != 3:
        raise InputError(f"track_mark needs (n, 2) pixels for n frames and (count, 3) points, "
                         f"got {np.shape(uv)} for {len(frames)} and {np.shape(P_base)}")
    count = len(P_base)
    clicked = {int(f): np.asarray(p, float) for f, p in zip(frames, uv, strict=True)}
    tracked: dict[int, list[np.ndarray]] = {}
    cache: dict[int, np.ndarray | None] = {}

    def image(i: int) -> np.ndarray | None:
        if i not in cache:
            if len(cache) >= CACHED_IMAGES:
                cache.clear()
            cache[i] = gray(i)
        return cache[i]

    for start, p in clicked.items():
        for step in (1, -1):
            point, i = p, start
            for _ in range(settings.max_track_frames):
                j = i + step
                if not 0 <= j < count or j in clicked \
                        or np.linalg.norm(P_base[j] - P_base[i]) > settings.max_step_m:
                    break
                point = _lk_step(image(i), image(j), point, settings)
                if point is None:
                    break
                tracked.setdefault(j, []).append(point)
                i = j
    out = dict(clicked)
    for j, points in tracked.items():
        if len(points) == 1 or np.linalg.norm(points[0] - points[1]) <= settings.agree_px:
            out[j] = np.mean(points, axis=0)
    keys = sorted(out)
    return np.asarray(keys, int), np.array([out[k] for k in keys]).reshape(-1, 2)


def _lk_step(a: np.ndarray | None, b: np.ndarray | None, point: np.ndarray,
             settings: MarkSettings) -> np.ndarray | None:
    """`point` of image `a` in image `b`, or None where the round trip does not return."""
    if a is None or b is None:
        return None
    params = {"winSize": (settings.window_px, settings.window_px),
              "maxLevel": settings.pyramid_levels,
              "criteria": (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
                           settings.max_iterations, settings.epsilon_px)}
    p0 = point.reshape(1, 1, 2).astype(np.float32)
    p1, ok1, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, **params)
    if not ok1[0, 0]:
        return None
    back, ok2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, None, **params)
    if not ok2[0, 0] or np.linalg.norm(back - p0) > settings.max_round_trip_px:
        return None
    q = p1.reshape(2).astype(float)
    h, w = b.shape[:2]
    return q if (-0.5 <= q[0] <= w - 0.5 and -0.5 <= q[1] <= h - 0.5) else None


def mark_pose(P_base: np.ndarray, uv: np.ndarray, camera: CameraIntrinsics) -> PoseFit:
    """The fixed camera's pose from the mark's 3D trajectory `P_base` (n, 3) and its pixels `uv`
    (n, 2): one robust PnP over time (`dream.pnp.solve_pnp`).

    Raises:
        InputError: fewer than 4 marked frames, or a trajectory that fixes no pose (a line).
    """
    if len(P_base) < MIN_KEYPOINTS:
        raise InputError(f"the mark is known in {len(P_base)} frames and a pose needs at least "
                         f"{MIN_KEYPOINTS}", fix="click the mark in more frames, where the "
                         "end effector is in different places")
    fit = solve_pnp(P_base, uv, camera)
    if isinstance(fit, NoSolution):
        raise InputError(f"the mark's track fixes no camera pose: {fit.reason}",
                         fix="click the mark in frames where the end effector is in places "
                             "that do not lie on one line")
    return fit


def placed_by_mark(R_cam_base: np.ndarray, P_base: np.ndarray, uv: np.ndarray,
                   camera: CameraIntrinsics) -> np.ndarray:
    """(m, 4, 4) cameras, one per orientation `R_cam_base` (n, 3, 3), each at the position
    that puts the mark's points `P_base` (k, 3; k >= 2) nearest their pixels `uv` (k, 2): with
    the orientation fixed, the projection's equations x (R P + t)_z = (R P + t)_x and
    y (R P + t)_z = (R P + t)_y are linear in t, so the position is their least-squares
    solution. Too few clicks for a pose of their own (`mark_pose` needs 4) still place each
    orientation of the automatic search. Cameras that see a point behind them are dropped.

    >>> from dream.transforms import look_at
    >>> cam = CameraIntrinsics(500.0, 500.0, 320.0, 240.0, 640, 480)
    >>> T = look_at(np.array([1.5, 0.5, 1.0]), np.zeros(3))
    >>> P = np.array([[0.3, 0.1, 0.4], [0.1, -0.2, 0.6]])
    >>> placed = placed_by_mark(T[None, :3, :3], P, project(cam, transform_points(T, P)), cam)
    >>> bool(np.allclose(placed[0], T))
    True

    Raises:
        InputError: fewer than 2 clicks, or clicks at one pixel (they place no camera).
    """
    R = np.asarray(R_cam_base, float)
    P = np.asarray(P_base, float)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or P.ndim != 2 or P.shape[1] != 3 \
            or np.shape(uv) != (len(P), 2):
        raise InputError(f"placed_by_mark needs (n, 3, 3) rotations, (k, 3) points and (k, 2) "
                         f"pixels, got {R.shape}, {P.shape}, {np.shape(uv)}")
    xy = pixels_to_normalized(camera, uv)
    A = np.zeros((2 * len(P), 3))
    A[0::2, 0], A[1::2, 1] = 1.0, 1.0
    A[0::2, 2], A[1::2, 2] = -xy[:, 0], -xy[:, 1]
    if len(P) < 2 or np.linalg.matrix_rank(A, tol=MIN_CLICK_SPREAD) < 3:
        raise InputError(f"the mark is known in {len(P)} frame(s), all at one pixel: that "
                         "places no camera", fix="click the mark in 2 or more frames where the "
                                                 "end effector is in different places")
    RP = np.einsum("nij,kj->nki", R, P)                       # (n, k, 3)
    b = -np.stack([RP[..., 0] - xy[:, 0] * RP[..., 2],
                   RP[..., 1] - xy[:, 1] * RP[..., 2]], axis=2).reshape(len(R), -1)
    t = b @ np.linalg.pinv(A).T                                # (n, 3)
    in_front = np.all(RP[..., 2] + t[:, None, 2] > MIN_MARK_DEPTH_M, axis=1)
    out = np.tile(np.eye(4), (int(in_front.sum()), 1, 1))
    out[:, :3, :3], out[:, :3, 3] = R[in_front], t[in_front]
    return out


def mark_sigma(fit: PoseFit, settings: MarkSettings, max_m: float, max_rad: float
               ) -> tuple[float, float]:
    """The search's 1-sigma (m, rad) around the mark's pose: `sigma_factor` x the PnP's own
    largest sigma of the camera centre and of the rotation, within [`min_sigma_*`, the
    guess's default]."""
    from dream.transforms import camera_position_covariance

    if not np.all(np.isfinite(fit.covariance)):
        return max_m, max_rad
    centre = camera_position_covariance(fit.T_cam_base, fit.covariance)
    rad = settings.sigma_factor * math.sqrt(max(float(np.diag(fit.covariance)[:3].max()), 0.0))
    m = settings.sigma_factor * math.sqrt(max(float(np.linalg.eigvalsh(centre)[-1]), 0.0))
    return (min(max(m, settings.min_sigma_m), max_m),
            min(max(rad, settings.min_sigma_rad), max_rad))


def click_residuals(T_cam_base: np.ndarray, mark: Mark, P_base: np.ndarray,
                    camera: CameraIntrinsics) -> np.ndarray:
    """(n,) pixel distances of the clicks from the mark projected at `T_cam_base` (`P_base`:
    the mark in the base frame at the clicked frames)."""
    return np.linalg.norm(project(camera, transform_points(T_cam_base, P_base)) - mark.uv,
                          axis=1)
