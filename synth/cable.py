"""A cable that the URDF lacks: a hose or wire bundle clipped along the arm (a gripper's or a
hand's supply, a camera's cable), sagging between its clips and moving with the links.

It starts on the floor beside the base, passes one clip on each of some consecutive keypoint
links (each at a fixed offset in that link's frame) and ends at the last of them; between two
clips it hangs as a parabola whose length is `slack` times the distance between them. It is
drawn as `segments` capsules of equal length along that curve, in distractor slots, so it is in
no robot mask and in no label: a thin moving object beside the links, which a motion mask
holds and a silhouette of the URDF does not.

    >>> import numpy as np
    >>> clips = np.array([[0.0, 0.0, 0.5], [1.0, 0.0, 0.5]])
    >>> p = cable_points(clips, slack=1.0, samples_per_span=5)
    >>> p.shape, bool(np.allclose(p[:, 2], 0.5))
    ((5, 3), True)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.errors import InputError
from dream.transforms import R_from_rotvec, quaternion_xyzw_from_R

SAMPLES_PER_SPAN = 24         # points of each clip-to-clip parabola before the resampling
PARABOLA_SLACK = 3.0 / 8.0    # a level parabola of sag d over chord L is about L (1 + 8/3 (d/L)^2)
SAG_SAMPLES = 200             # points of a parabola whose length the sag's bisection measures
SAG_ITERATIONS = 40
Z_AXIS = np.array([0.0, 0.0, 1.0])
VALUE_RANGE = (0.1, 1.0)      # a cable's colour: a random hue scaled by this (dark to light)
PARALLEL = 1e-12              # below this sine a direction is taken as along z


@dataclass(frozen=True)
class CableDraw:
    """A cable's fixed draw along a sequence (module doc).

    Attributes:
        start_m: (3,) where it leaves the floor, base frame.
        links: the links it is clipped to, in order from the base.
        clips_m: (len(links), 3) each clip in its link's frame.
        radius_m: its radius.
        slack: its length between two clips over their distance (>= 1).
        rgba: (4,) its colour.
    """

    start_m: np.ndarray
    links: tuple[str, ...]
    clips_m: np.ndarray
    radius_m: float
    slack: float
    rgba: np.ndarray

    def __post_init__(self) -> None:
        if np.shape(self.clips_m) != (len(self.links), 3) or not self.links:
            raise InputError(f"a cable needs one (3,) clip per link, got {len(self.links)} "
                             f"links and clips of shape {np.shape(self.clips_m)}")
        if not self.radius_m > 0 or not self.slack >= 1:
            raise InputError(f"a cable needs radius_m > 0 and slack >= 1, got "
                             f"{self.radius_m} and {self.slack}")


def cable_points(clips_base: np.ndarray, slack: float,
                 samples_per_span: int = SAMPLES_PER_SPAN) -> np.ndarray:
    """(M, 3) points along a cable through `clips_base` (N, 3; base frame, z up), hanging as a
    parabola between each two clips whose length is about `slack` times their distance (pure).

    Raises:
        InputError: fewer than two clips, or `slack` below 1.
    """
    clips_base = np.asarray(clips_base, float)
    if clips_base.ndim != 2 or clips_base.shape[1] != 3 or len(clips_base) < 2:
        raise InputError(f"a cable needs at least two (3,) clips, got shape {clips_base.shape}")
    if slack < 1:
        raise InputError(f"a cable's slack must be at least 1, got {slack}")
    s = np.linspace(0.0, 1.0, samples_per_span)[:, None]
    spans = []
    for a, b in zip(clips_base[:-1], clips_base[1:], strict=True):
        span = _parabola(a, b, _sag(a, b, slack), s)
        spans.append(span if not spans else span[1:])
    return np.concatenate(spans)


def _parabola(a: np.ndarray, b: np.ndarray, sag: float, s: np.ndarray) -> np.ndarray:
    """Points at parameters `s` (K, 1) of the parabola from `a` to `b` hanging `sag` below the
    chord's middle."""
    return a + s * (b - a) - 4.0 * sag * s * (1.0 - s) * Z_AXIS


def _sag(a: np.ndarray, b: np.ndarray, slack: float) -> float:
    """The sag of the parabola from `a` to `b` whose length is `slack` times their distance
    (bisection: the length grows with the sag)."""
    chord = float(np.linalg.norm(b - a))
    if chord == 0.0 or slack == 1.0:
        return 0.0
    s = np.linspace(0.0, 1.0, SAG_SAMPLES)[:, None]

    def short(sag: float) -> bool:
        points = _parabola(a, b, sag, s)
        return np.linalg.norm(np.diff(points, axis=0), axis=1).sum() < slack * chord

    lo, hi = 0.0, chord * np.sqrt(PARABOLA_SLACK * (slack - 1.0))
    while short(hi):                  # a sloping chord needs more sag than a level one
        lo, hi = hi, 2 * hi
    for _ in range(SAG_ITERATIONS):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if short(mid) else (lo, mid)
    return (lo + hi) / 2


def cable_segments(points: np.ndarray, count: int, floor_z: float
                   ) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """`count` pieces of equal length along the polyline `points` (M, 3), each as (centre (3,),
    quaternion_wxyz (4,) turning z onto it, half-length); the curve kept above `floor_z`
    (pure)."""
    points = np.asarray(points, float).copy()
    points[:, 2] = np.maximum(points[:, 2], floor_z)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    ends = np.stack([np.interp(np.linspace(0.0, along[-1], count + 1), along, points[:, k])
                     for k in range(3)], axis=1)
    pieces = []
    for a, b in zip(ends[:-1], ends[1:], strict=True):
        direction = b - a
        length = float(np.linalg.norm(direction))
        pieces.append(((a + b) / 2, z_onto(direction / length if length > 0 else Z_AXIS),
                       length / 2))
    return pieces


def z_onto(direction: np.ndarray) -> np.ndarray:
    """The quaternion (w, x, y, z) of a rotation that turns the z axis onto unit `direction`."""
    axis = np.cross(Z_AXIS, direction)
    sin, cos = float(np.linalg.norm(axis)), float(direction @ Z_AXIS)
    if sin < PARALLEL:                # along z: none, or a half turn about x
        rotvec = np.zeros(3) if cos > 0 else np.array([np.pi, 0.0, 0.0])
    else:
        rotvec = axis / sin * np.arctan2(sin, cos)
    return np.roll(quaternion_xyzw_from_R(R_from_rotvec(rotvec)), 1)


def sample_cable(rng: np.random.Generator, keypoint_links: tuple[str, ...], radius_m: tuple,
                 slack: tuple, clip_offset_m: tuple, start_distance_m: tuple) -> CableDraw:
    """A cable from the floor `start_distance_m` from the base (any direction) to a clip on
    each keypoint link from the second to a random one of the last half (the first, the base,
    never moves), each clip `clip_offset_m` from its link's origin in a random direction."""
    if len(keypoint_links) < 2:
        raise InputError(f"a cable needs at least two keypoint links, got {keypoint_links}")
    last = int(rng.integers(max(1, len(keypoint_links) // 2), len(keypoint_links)))
    links = tuple(keypoint_links[1:last + 1])
    directions = rng.normal(size=(len(links), 3))
    clips = directions / np.linalg.norm(directions, axis=1, keepdims=True) * \
        rng.uniform(*clip_offset_m, (len(links), 1))
    angle = rng.uniform(0.0, 2 * np.pi)
    radius = rng.uniform(*radius_m)
    start = np.array([np.cos(angle), np.sin(angle), 0.0]) * rng.uniform(*start_distance_m)
    start[2] = radius
    return CableDraw(start, links, clips, radius, float(rng.uniform(*slack)),
                     np.array([*rng.random(3) * rng.uniform(*VALUE_RANGE), 1.0]))


def cable_in_base(cable: CableDraw, T_base_links: np.ndarray, count: int
                  ) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The cable's `count` capsules (centre, quaternion_wxyz, half-length) in the base frame,
    its clips carried by `T_base_links` (len(links), 4, 4), the links' poses in this frame."""
    clips = np.einsum("nij,nj->ni", T_base_links[:, :3, :3], cable.clips_m) + \
        T_base_links[:, :3, 3]
    points = cable_points(np.vstack([cable.start_m, clips]), cable.slack)
    return cable_segments(points, count, floor_z=cable.radius_m)
