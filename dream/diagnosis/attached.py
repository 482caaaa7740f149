"""Something the URDF lacks, carried by a link: found by carving the images' unexplained motion.

A fixed camera sees the arm move in front of a still scene. Its motion masks (`dream.edges.motion`)
hold everything that moved; the fitted model's silhouette (dilated by a few pixels for the pose's
error) explains most of it. What is left over, frame after frame, is the arm's shadow, other
motion, and anything the arm carries that the URDF does not describe: a tool, a gripper, a held
board. Only the last moves rigidly with a link. So, for each rigid group of moving links (links
whose relative pose stays the same over the frames), a grid of points fixed in the group's link
frame is carved (space carving): a point is kept when it projects into moving pixels in most
frames where it is in the image, and into unexplained pixels in a good share of them. The most
distal group that keeps about as many points as the best group carries the attached geometry;
carved again with moving pixels asked for in almost every frame, its points' trimmed bounding
box in that link's frame becomes a `link_geometry` box (`dream.robot.link_geometry`). The
looser carving picks the link: the motion masks miss a carried object wherever it matches the
scene behind it in colour or is seen edge-on (a thin plate), and the stricter one then keeps
more of the swept object in the frame of a proximal link than in its own. The stricter one
shapes the box, which the looser one thickens. A single view cannot tell a plate's thickness
along the line of sight, so the box is a visual hull: too thick, rarely too small.

Pure except for reading the sequence's images.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from dream.camera import project
from dream.edges.motion import MotionSettings, sequence_motion_masks
from dream.errors import InputError
from dream.polish.objective import evenly_spaced
from dream.robot import Robot
from dream.robot.link_geometry import BOX_KIND, LinkGeometry
from dream.sequence import Sequence
from dream.settings_checks import check_fields
from dream.silhouette import load_robot_meshes, render_silhouette

MIN_DEPTH_M = 0.05   # grid points closer to the camera than this are not projected
RIGID_TOLERANCE_M = 1e-6   # links whose relative pose varies less than this are one body
WIDTH_REFERENCE_PX = 320.0  # dilate_px is per this many pixels of image width


@dataclass(frozen=True)
class AttachedSettings:
    """Every constant of the carving (module doc); set on rendered sequences.

    Attributes:
        frames: frames carved (evenly spaced).
        voxel_m, half_extent_m: the grid around each link origin: spacing and half size.
        dilate_px: the model silhouette grows by this (per 320 px of width) before it explains.
        min_seen_frames: a grid point must be in the image in at least this many frames.
        moving_share: ... and in moving or model pixels in at least this share of them, to
            shape the box (its points, where they are at least `box_share` of those of
            `link_moving_share`, else those),
        link_moving_share: the share that carves the points which choose the link (on
            rendered plate sequences a thin plate drops out of the motion masks in up to a
            quarter of the frames),
        unexplained_share: ... and in unexplained pixels in at least this share.
        min_points: fewer kept points: nothing attached.
        box_share: the stricter carving's points shape the box where they are at least this
            share of the looser one's (the object is then in almost every motion mask; where
            it drops out of some, the stricter carving keeps only a part of it).
        group_share: a more distal group wins when it keeps this share of the best group's
            points: a wrist joint that hardly moves makes the groups on both sides of it carve
            alike, and tools are attached at the distal end far more often.
        trim_percentile: the box spans these percentiles of the kept points (each axis).
        background_arm_share: pixels the model covers in at least this share of the carved
            frames are no evidence: the median background there is the arm itself.
        max_unexplained_share: nothing is looked for when more than this share of the moving
            pixels is unexplained: the model's pose or joints are then too far off for the
            leftover to be something carried (a majority; at most 0.34 on rendered sequences
            of an arm carrying a 30 x 22 cm plate).
    """

    frames: int = 30
    voxel_m: float = 0.02
    half_extent_m: float = 0.35
    dilate_px: float = 3.0
    min_seen_frames: int = 10
    moving_share: float = 0.9
    link_moving_share: float = 0.7
    unexplained_share: float = 0.3
    min_points: int = 20
    group_share: float = 0.4
    box_share: float = 0.4
    trim_percentile: float = 5.0
    max_unexplained_share: float = 0.5
    background_arm_share: float = 0.5

    def __post_init__(self) -> None:
        check_fields(self, "attached geometry",
                     positive_ints=("frames", "min_seen_frames", "min_points"),
                     positive=("voxel_m", "half_extent_m", "moving_share", "link_moving_share",
                               "unexplained_share", "group_share", "box_share",
                               "max_unexplained_share",
                               "background_arm_share"),
                     non_negative=("dilate_px", "trim_percentile"))
        if self.link_moving_share > self.moving_share:
            raise InputError(f"attached geometry: link_moving_share ({self.link_moving_share}) "
                             f"must not exceed moving_share ({self.moving_share}): the looser "
                             "carving picks the link, the stricter one shapes the box")


@dataclass(frozen=True)
class AttachedFinding:
    """The geometry found, the link it moves with, and the evidence: the carved points that
    shaped it (`points_link` (N, 3), in the link's frame)."""

    geometry: LinkGeometry
    points: int
    frames: int
    points_per_link: dict[str, int]
    points_link: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False,
                                    compare=False)

    def note(self) -> str:
        """The diagnosis note that names the finding."""
        g = self.geometry
        return (f"link_geometry: something the URDF lacks moves with {g.link} (about "
                f"{' x '.join(f'{100 * s:.0f}' for s in g.size_m)} cm, centred "
                f"{100 * float(np.linalg.norm(g.position_m)):.0f} cm from its origin; "
                f"{self.points} carved points over {self.frames} frames): a tool, gripper or "
                "held object; extended_model.yaml adds it as a box (a visual hull: thicker than "
                "it is along the camera's line of sight)")

    def to_dict(self) -> dict:
        return {**self.geometry.to_params(), "carved_points": self.points,
                "frames": self.frames, "carved_points_per_link": dict(self.points_per_link)}


@dataclass(frozen=True)
class CarvingOutcome:
    """What the carving looked at and kept, whether or not it names something.

    Attributes:
        frames: frames carved.
        unexplained_share: share of the moving pixels the model leaves unexplained (None when
            nothing moved).
        points_per_link: grid points kept per rigid group, by the link that names it.
        finding: the geometry named, or None.
        reason: why nothing is named ("" when something is).
    """

    frames: int
    unexplained_share: float | None
    points_per_link: dict[str, int]
    finding: AttachedFinding | None
    reason: str

    def note(self) -> str:
        """The diagnosis note: the finding, or why `link_geometry` is not named."""
        if self.finding is not None:
            return self.finding.note()
        counts = ", ".join(f"{k} {n}" for k, n in self.points_per_link.items())
        return (f"link_geometry: not named: {self.reason}"
                + (f" (points kept per link over {self.frames} frames: {counts})"
                   if counts else ""))

    def to_dict(self) -> dict:
        return {"frames": self.frames, "unexplained_share": self.unexplained_share,
                "carved_points_per_link": dict(self.points_per_link),
                "named": None if self.finding is None else self.finding.geometry.link,
                "reason": self.reason}


def rigid_groups(robot: Robot, joints: np.ndarray, links: tuple[str, ...]
                 ) -> list[tuple[str, ...]]:
    """`links` grouped by a constant relative pose over the joint vectors (F, J), in order."""
    T = robot.link_poses(joints, links)                           # (F, L, 4, 4)
    groups: list[list[int]] = []
    for i in range(len(links)):
        for group in groups:
            rel = np.linalg.inv(T[:, group[0]]) @ T[:, i]           # (F, 4, 4)
            if np.abs(rel - rel[0]).max() < RIGID_TOLERANCE_M:
                group.append(i)
                break
        else:
            groups.append([i])
    return [tuple(links[i] for i in g) for g in groups]


def unexplained_motion(sequence: Sequence, robot: Robot, joints: np.ndarray,
                       T_cam_base: np.ndarray, indices: np.ndarray,
                       settings: AttachedSettings) -> tuple[np.ndarray, np.ndarray, float]:
    """(moving or model, unexplained) (n, H, W) bool masks of the frames `indices`, and the
    share of the moving pixels left unexplained."""
    motion = sequence_motion_masks(sequence, indices, MotionSettings())
    return unexplained_pixels(load_robot_meshes(robot), np.asarray(joints)[indices], motion,
                              T_cam_base, sequence.camera, settings)


def unexplained_pixels(meshes, joints: np.ndarray, motion: np.ndarray, T_cam_base: np.ndarray,
                       camera, settings: AttachedSettings
                       ) -> tuple[np.ndarray, np.ndarray, float]:
    """(moving or model, unexplained) (n, H, W) bool masks of the frames at `joints` (n, J)
    whose motion masks are `motion` (n, H, W), and the share of the moving pixels the model's
    silhouettes (`meshes` at `T_cam_base`, dilated by `dilate_px`) leave unexplained."""
    radius = max(1, int(round(settings.dilate_px * camera.width / WIDTH_REFERENCE_PX)))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    model = np.stack([cv2.dilate(render_silhouette(meshes, q, T_cam_base, camera)
                                 .astype(np.uint8), disk) > 0 for q in joints])
    # where the arm stays, the median background holds the arm itself, and the frames in which
    # it has moved away "move" there: ghosts, no evidence of anything carried
    ghost = model.mean(axis=0) >= settings.background_arm_share
    unexplained = motion & ~model & ~ghost
    return motion | model, unexplained, float(unexplained.sum() / max(int(motion.sum()), 1))


@dataclass(frozen=True)
class GridVotes:
    """A link frame's grid points and, for each, the carved frames that see it and how many of
    them put it on moving and on unexplained pixels: what the carving thresholds."""

    grid: np.ndarray
    seen: np.ndarray
    on_moving: np.ndarray
    on_unexplained: np.ndarray

    def kept(self, settings: AttachedSettings, moving_share: float) -> np.ndarray:
        """(N, 3) the points on moving pixels in at least `moving_share` of the frames that
        see them (module doc)."""
        keep = ((self.seen >= settings.min_seen_frames)
                & (self.on_moving >= moving_share * self.seen)
                & (self.on_unexplained >= settings.unexplained_share * self.seen))
        return self.grid[keep]


def carve(robot: Robot, link: str, joints: np.ndarray, T_cam_base: np.ndarray, camera,
          moving: np.ndarray, unexplained: np.ndarray, settings: AttachedSettings,
          moving_share: float | None = None) -> np.ndarray:
    """(N, 3) the grid points in `link`'s frame kept by the carving (module doc), on moving
    pixels in at least `moving_share` of the frames that see them (default: the settings')."""
    votes = grid_votes(robot, link, joints, T_cam_base, camera, moving, unexplained, settings)
    return votes.kept(settings, settings.moving_share if moving_share is None else moving_share)


def grid_votes(robot: Robot, link: str, joints: np.ndarray, T_cam_base: np.ndarray, camera,
               moving: np.ndarray, unexplained: np.ndarray, settings: AttachedSettings
               ) -> GridVotes:
    """The votes of the frames `joints` (n, J) with masks `moving`, `unexplained` (n, H, W)
    for the grid around `link`'s origin."""
    axis = np.arange(-settings.half_extent_m, settings.half_extent_m + 1e-9, settings.voxel_m)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    T_base_link = robot.link_poses(joints, [link])[:, 0]
    seen, on_moving, on_unexplained = (np.zeros(len(grid)) for _ in range(3))
    for f, T_link in enumerate(T_base_link):
        T = T_cam_base @ T_link
        P = grid @ T[:3, :3].T + T[:3, 3]
        front = P[:, 2] > MIN_DEPTH_M
        uv = np.full((len(P), 2), -1.0)
        uv[front] = project(camera, P[front])
        u, v = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
        ok = front & (u >= 0) & (v >= 0) & (u < camera.width) & (v < camera.height)
        seen += ok
        on_moving[ok] += moving[f][v[ok], u[ok]]
        on_unexplained[ok] += unexplained[f][v[ok], u[ok]]
    return GridVotes(grid, seen, on_moving, on_unexplained)


def find_attached_geometry(sequence: Sequence, robot: Robot, joints: np.ndarray,
                           T_cam_base: np.ndarray, settings: AttachedSettings | None = None,
                           usable: np.ndarray | None = None) -> CarvingOutcome:
    """What the carving finds a moving link carrying that the model lacks (module doc): the
    geometry, or why nothing is named.

    Args:
        sequence: a fixed-camera sequence with images (motion masks need them).
        robot: the robot; joints: (F, J) its joints at the image times (the fitted model's).
        T_cam_base: (4, 4) the fitted extrinsic.
        usable: (F,) bool, the frames whose joints are known (default: all); the carving
            keeps a point seen in almost every frame, so a few frames drawn at the wrong
            joints (a held log's last reading past its last update) undo it.

    Raises:
        InputError: no images, too few frames, or an arm that hardly moves (motion masks).
    """
    settings = settings or AttachedSettings()
    usable = np.ones(len(sequence), bool) if usable is None else np.asarray(usable, bool)
    if usable.shape != (len(sequence),):
        raise InputError(f"usable must be ({len(sequence)},) bool, got {usable.shape}")
    indices = evenly_spaced(np.flatnonzero(usable), settings.frames)
    q = np.asarray(joints, dtype=float)[indices]
    moving_links = _moving_links(robot, q)
    if not moving_links:
        return CarvingOutcome(len(indices), None, {}, None, "no link moves over the frames")
    moving, unexplained, share = unexplained_motion(sequence, robot, joints, T_cam_base,
                                                    indices, settings)
    return carve_masks(robot, q, T_cam_base, sequence.camera, moving, unexplained, share,
                       settings)


def _moving_links(robot: Robot, q: np.ndarray) -> tuple[str, ...]:
    """The links whose origins travel more than the motion masks' `static_link_m` over the
    joint vectors `q` (n, J)."""
    origins = robot.link_poses(q, robot.link_names)[..., :3, 3]            # (n, L, 3)
    return tuple(name for name, travel in zip(
        robot.link_names, np.ptp(origins, axis=0).max(axis=1), strict=True)
        if travel > MotionSettings().static_link_m)


def carve_masks(robot: Robot, q: np.ndarray, T_cam_base: np.ndarray, camera,
                moving: np.ndarray, unexplained: np.ndarray, share: float,
                settings: AttachedSettings | None = None) -> CarvingOutcome:
    """`find_attached_geometry` on masks already made (pure): the frames' joints `q` (n, J),
    their (moving or model, unexplained) masks (n, H, W) and the unexplained share
    (`unexplained_pixels`)."""
    settings = settings or AttachedSettings()
    moving_links = _moving_links(robot, q)
    if not moving_links:
        return CarvingOutcome(len(q), None, {}, None, "no link moves over the frames")
    if share > settings.max_unexplained_share:
        return CarvingOutcome(len(q), share, {}, None, (
            f"the fitted model leaves {share:.0%} of the moving pixels unexplained (more than "
            f"{settings.max_unexplained_share:.0%}): its pose or joints are too far off to tell "
            "what the arm carries"))
    votes = {link: grid_votes(robot, link, q, T_cam_base, camera, moving, unexplained,
                              settings)
             for link in (_representative(robot, g) for g in rigid_groups(robot, q, moving_links))}
    kept = [(link, v.kept(settings, settings.link_moving_share)) for link, v in votes.items()]
    counts = {k: int(len(p)) for k, p in kept}
    best = max(counts.values())
    if best < settings.min_points:
        strongest = max(counts, key=counts.get)
        return CarvingOutcome(len(q), share, counts, None, (
            f"the most points kept, {best} in the frame of {strongest}, are fewer than the "
            f"{settings.min_points} that name a carried shape" if best else
            "no point near a moving link falls on unexplained motion in enough frames"))
    link, points = [(k, p) for k, p in kept if len(p) >= settings.group_share * best][-1]
    strict = votes[link].kept(settings, settings.moving_share)
    points = strict if len(strict) >= max(settings.box_share * len(points),
                                          settings.min_points) else points
    low, high = np.percentile(points, [settings.trim_percentile,
                                       100 - settings.trim_percentile], axis=0)
    size = np.maximum(high - low, 0.0) + settings.voxel_m
    box = LinkGeometry(link, BOX_KIND, size_m=tuple(size), position_m=tuple((low + high) / 2))
    return CarvingOutcome(len(q), share, counts,
                          AttachedFinding(box, len(points), len(q), counts, points), "")


def _representative(robot: Robot, group: tuple[str, ...]) -> str:
    """The link that names a rigid group: its last keypoint link (base to tip), else its last
    link in the URDF's order."""
    keypoints = [k for k in robot.keypoint_names if k in group]
    return keypoints[-1] if keypoints else group[-1]
