"""A dexterous hand the URDF lacks, mounted at the flange: a palm and fingers of three
segments each, the fingers opening and closing on their own over time (the hand's joints are
not in the arm's joint log), as on an arm that carries an Allegro or a Shadow hand.

The palm sits along the last keypoint link's z axis (the tool axis of the flanges this project
ships: `panda_hand`, `tool0`, `link_eef`), turned about it by a drawn roll. Four fingers leave
the palm's far edge and a thumb its side; each finger's three joints bend alike, towards the
palm's face, by `curl(t) = mean + amplitude sin(2 pi t / period + phase)`, with a phase of
its own. Everything is drawn as a box and capsules in distractor slots, so it is in no robot
mask and in no label: something that moves with the flange, larger than the flange, and
changes its shape from frame to frame.

    >>> import numpy as np
    >>> hand = HandDraw(link="tool0", scale=1.0, roll_rad=0.0, mean_curl_rad=0.6,
    ...                 curl_amplitude_rad=0.4, period_s=2.0, phases_rad=np.zeros(FINGERS),
    ...                 rgba=np.array([0.2, 0.2, 0.2, 1.0]))
    >>> shapes = hand_shapes(hand, np.eye(4), 0.0)
    >>> len(shapes) == SLOTS, shapes[0][0]
    (True, 'box')
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.errors import InputError
from dream.transforms import R_from_rotvec, quaternion_xyzw_from_R
from synth.person import capsule

PALM_HALF_M = np.array([0.045, 0.015, 0.05])   # half width (x), thickness (y), length (z)
PALM_GAP_M = 0.01             # between the link's origin and the palm's near edge
SEGMENTS_M = (0.05, 0.04, 0.03)                # a finger's three segments, base to tip
FINGER_RADIUS_M = 0.011
FINGERS = 5                   # four across the far edge, then the thumb
THUMB_AT = 0.3                # the thumb leaves the side this share of the palm's length up
THUMB_SPLAY_RAD = np.pi / 3   # the thumb's first segment from the palm's axis, sideways
SCALE_RANGE = (0.9, 1.2)      # the hand's size over the numbers above (an Allegro is ~1.2)
MEAN_CURL_RAD = (0.2, 0.8)    # each joint's mean bend
CURL_AMPLITUDE_RAD = (0.2, 0.5)
PERIOD_S = (1.0, 4.0)         # one open-close cycle
GREY_VALUE = (0.1, 0.9)       # grey level of the hand's cover
SLOTS = 1 + FINGERS * len(SEGMENTS_M)


@dataclass(frozen=True)
class HandDraw:
    """A hand's draw along a sequence (module doc).

    Attributes:
        link: the link the hand is mounted on.
        scale: its size over the module's numbers.
        roll_rad: the palm's turn about the link's z axis.
        mean_curl_rad, curl_amplitude_rad, period_s: the fingers' bend over time.
        phases_rad: (FINGERS,) each finger's phase.
        rgba: (4,) its colour.
    """

    link: str
    scale: float
    roll_rad: float
    mean_curl_rad: float
    curl_amplitude_rad: float
    period_s: float
    phases_rad: np.ndarray
    rgba: np.ndarray

    def __post_init__(self) -> None:
        if np.shape(self.phases_rad) != (FINGERS,) or np.shape(self.rgba) != (4,):
            raise InputError(f"a hand needs ({FINGERS},) phases and a (4,) colour, got shapes "
                             f"{np.shape(self.phases_rad)} and {np.shape(self.rgba)}")
        if not (self.scale > 0 and self.period_s > 0):
            raise InputError(f"a hand's scale and period must be positive, got {self.scale} "
                             f"and {self.period_s}")


def finger_points(base: np.ndarray, along: np.ndarray, towards: np.ndarray, curl_rad: float,
                  segments: tuple[float, ...]) -> np.ndarray:
    """The joints and the tip (len(segments) + 1, 3) of a finger from `base` along the unit
    vector `along`, each joint bending it by `curl_rad` towards `towards` (a unit vector
    normal to `along`; pure).

    >>> pts = finger_points(np.zeros(3), np.array([0, 0, 1.0]), np.array([0, 1.0, 0]),
    ...                     np.pi / 2, (1.0, 1.0))
    >>> np.round(pts, 6).tolist()
    [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, -1.0]]
    """
    axis = np.cross(along, towards)
    R_step = R_from_rotvec(axis * curl_rad)
    points, direction = [np.asarray(base, float)], np.asarray(along, float)
    for length in segments:
        direction = R_step @ direction
        points.append(points[-1] + length * direction)
    return np.array(points)


def hand_shapes(hand: HandDraw, T_base_link: np.ndarray, time_s: float
                ) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The hand's `SLOTS` shapes at the link's pose `T_base_link` (4, 4) and time `time_s`:
    each (kind, MuJoCo size (3,), centre (3,), quaternion_wxyz (4,), rgba (4,)), base frame."""
    s = hand.scale
    R = T_base_link[:3, :3] @ R_from_rotvec(np.array([0.0, 0.0, hand.roll_rad]))
    x, y, z = R.T
    half = PALM_HALF_M * s
    centre = T_base_link[:3, 3] + (PALM_GAP_M * s + half[2]) * z
    palm = ("box", half, centre, np.roll(quaternion_xyzw_from_R(R), 1), hand.rgba)
    segments = tuple(length * s for length in SEGMENTS_M)
    shapes = [palm]
    for k in range(FINGERS):
        curl = hand.mean_curl_rad + hand.curl_amplitude_rad * np.sin(
            2 * np.pi * time_s / hand.period_s + hand.phases_rad[k])
        if k < FINGERS - 1:
            across = (2 * k / (FINGERS - 2) - 1) * (half[0] - FINGER_RADIUS_M * s)
            base, along = centre + half[2] * z + across * x, z
        else:
            base = centre + (THUMB_AT * 2 - 1) * half[2] * z + half[0] * x
            along = np.cos(THUMB_SPLAY_RAD) * z + np.sin(THUMB_SPLAY_RAD) * x
        pts = finger_points(base, along, -y, curl, segments)
        shapes += [(*capsule(a, b, FINGER_RADIUS_M * s), hand.rgba)
                   for a, b in zip(pts[:-1], pts[1:], strict=True)]
    return shapes


def sample_hand(rng: np.random.Generator, link: str) -> HandDraw:
    """A hand mounted on `link`, its size, roll, motion and colour drawn."""
    grey = rng.uniform(*GREY_VALUE)
    return HandDraw(link=link, scale=float(rng.uniform(*SCALE_RANGE)),
                    roll_rad=float(rng.uniform(-np.pi, np.pi)),
                    mean_curl_rad=float(rng.uniform(*MEAN_CURL_RAD)),
                    curl_amplitude_rad=float(rng.uniform(*CURL_AMPLITUDE_RAD)),
                    period_s=float(rng.uniform(*PERIOD_S)),
                    phases_rad=rng.uniform(0.0, 2 * np.pi, FINGERS),
                    rgba=np.array([grey, grey, grey, 1.0]))
