"""A person guiding the arm by hand (kinesthetic teaching, as a Franka or a UR is often moved
for a calibration recording): a hand gripping the last keypoint link, a forearm and an upper
arm up to a shoulder, a torso and a head beside the robot.

The person stands on the floor (z = 0) at an anchor drawn once per sequence, beside or behind
the arm as the camera sees it. Wherever the hand is within reach of the anchor the shoulder
rests there; where it is not, the shoulder leans towards the hand until it is (bending no
lower than `MIN_SHOULDER_HEIGHT_M`), the torso from the hips to it. The elbow hangs below the
line from the shoulder to the hand, turned about it by a drawn swivel. Everything is drawn as
capsules and a sphere in distractor slots, so it is in no robot mask and in no label:
something large that moves with the hand in every frame and touches it, which a motion mask
holds and a silhouette of the URDF does not.

    >>> import numpy as np
    >>> shoulder, hand = np.array([0.0, 0.0, 0.6]), np.array([0.4, 0.0, 0.3])
    >>> elbow = elbow_position(shoulder, hand, 0.3, 0.28, 0.0)
    >>> [round(float(np.linalg.norm(b - a)), 3) for a, b in ((shoulder, elbow), (elbow, hand))]
    [0.3, 0.28]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.errors import InputError
from dream.transforms import transform_points
from synth.cable import Z_AXIS, z_onto

UPPER_ARM_M = 0.30            # shoulder to elbow of an adult, before the drawn scale
FOREARM_M = 0.27              # elbow to the middle of the hand
UPPER_ARM_RADIUS_M = 0.045
FOREARM_RADIUS_M = 0.035
HAND_RADIUS_M = 0.04          # a gripping hand, as a capsule along the forearm
HAND_HALF_LENGTH_M = 0.03
TORSO_RADIUS_M = 0.15
HIP_HEIGHT_M = 0.9            # the hips above the floor (z = 0); the legs below them
LEG_RADIUS_M = 0.12           # both legs as one capsule
MIN_SHOULDER_HEIGHT_M = 0.7   # a person bends no lower to reach the hand
HEAD_RADIUS_M = 0.1
HEAD_ABOVE_SHOULDER_M = 0.25  # along the torso
SCALE_RANGE = (0.9, 1.1)      # a person's size over the numbers above
GRIP_OFFSET_M = (0.02, 0.06)  # the grip from the link's origin, any direction
REACH_FRACTION = 0.95         # the shoulder leans until the hand is this share of the reach
CAMERA_CLEAR_RAD = np.pi / 3  # the anchor's bearing stays this far from the camera's
SWIVEL_RAD = np.pi / 4        # the elbow's turn about the shoulder-hand line, at most
SKIN_VALUE = (0.35, 0.95)     # skin tones: red 1, green and blue these shares of it, all
SKIN_GREEN = (0.6, 0.8)       # scaled by a value from SKIN_VALUE
SKIN_BLUE = (0.45, 0.65)
TINY_M = 1e-9                 # below this length a direction is taken as undefined
SLOTS = 6                     # upper arm, forearm, hand, torso, legs, head


@dataclass(frozen=True)
class PersonDraw:
    """A person's draw along a sequence (module doc).

    Attributes:
        link: the link the hand grips.
        grip_m: (3,) the grip in that link's frame.
        anchor_m: (3,) the shoulder where the hand is within reach, base frame.
        scale: the person's size over the module's numbers.
        swivel_rad: the elbow's turn about the line from the shoulder to the hand.
        sleeve_rgba, skin_rgba: (4,) colours of the clothes and of the hand and head.
    """

    link: str
    grip_m: np.ndarray
    anchor_m: np.ndarray
    scale: float
    swivel_rad: float
    sleeve_rgba: np.ndarray
    skin_rgba: np.ndarray

    def __post_init__(self) -> None:
        if np.shape(self.grip_m) != (3,) or np.shape(self.anchor_m) != (3,):
            raise InputError(f"a person needs a (3,) grip and a (3,) anchor, got shapes "
                             f"{np.shape(self.grip_m)} and {np.shape(self.anchor_m)}")
        if not self.scale > 0:
            raise InputError(f"a person's scale must be positive, got {self.scale}")


def elbow_position(shoulder: np.ndarray, hand: np.ndarray, upper_m: float, fore_m: float,
                   swivel_rad: float) -> np.ndarray:
    """The elbow (3,) of an arm of segments `upper_m` and `fore_m` from `shoulder` to `hand`,
    below the line between them and turned about it by `swivel_rad` (pure). A hand out of
    reach straightens the arm towards it; one too near folds it."""
    shoulder, hand = np.asarray(shoulder, float), np.asarray(hand, float)
    line = hand - shoulder
    d = float(np.linalg.norm(line))
    u = line / d if d > 0 else -Z_AXIS
    d = float(np.clip(d, abs(upper_m - fore_m), upper_m + fore_m))
    along = (upper_m ** 2 - fore_m ** 2 + d ** 2) / (2 * d) if d > 0 else 0.0
    off = np.sqrt(max(upper_m ** 2 - along ** 2, 0.0))
    down = -Z_AXIS - (-Z_AXIS @ u) * u
    if np.linalg.norm(down) < TINY_M:       # a vertical line: any horizontal side
        down = np.cross(u, [1.0, 0.0, 0.0])
    down /= np.linalg.norm(down)
    side = np.cross(u, down)
    v = np.cos(swivel_rad) * down + np.sin(swivel_rad) * side
    return shoulder + along * u + off * v


def shoulder_position(anchor: np.ndarray, hand: np.ndarray, reach_m: float) -> np.ndarray:
    """The anchor where `hand` lies within `REACH_FRACTION` of `reach_m` of it, else the point
    on the line from the hand towards the anchor at that distance (pure)."""
    anchor, hand = np.asarray(anchor, float), np.asarray(hand, float)
    away = anchor - hand
    d = float(np.linalg.norm(away))
    limit = REACH_FRACTION * reach_m
    return anchor.copy() if d <= limit else hand + away / d * limit


def capsule(a: np.ndarray, b: np.ndarray, radius: float
            ) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """A capsule of `radius` from `a` to `b` (3,): (kind, MuJoCo size (3,), centre (3,),
    quaternion_wxyz (4,))."""
    length = float(np.linalg.norm(b - a))
    axis = (b - a) / length if length > 0 else Z_AXIS
    return "capsule", np.array([radius, length / 2, 0.0]), (a + b) / 2, z_onto(axis)


def person_shapes(person: PersonDraw, T_base_link: np.ndarray
                  ) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The person's `SLOTS` shapes at the gripped link's pose `T_base_link` (4, 4): each
    (kind, MuJoCo size (3,), centre (3,), quaternion_wxyz (4,), rgba (4,)), base frame, the
    floor at z = 0. The hips stay below the anchor; the torso leans from them to the
    shoulder."""
    s = person.scale
    upper, fore = UPPER_ARM_M * s, FOREARM_M * s
    hand = transform_points(T_base_link, person.grip_m)
    shoulder = shoulder_position(person.anchor_m, hand, upper + fore)
    shoulder[2] = max(shoulder[2], MIN_SHOULDER_HEIGHT_M * s)
    elbow = elbow_position(shoulder, hand, upper, fore, person.swivel_rad)
    along = (hand - elbow) / max(float(np.linalg.norm(hand - elbow)), TINY_M)
    hips = np.array([*person.anchor_m[:2], HIP_HEIGHT_M * s])
    up = (shoulder - hips) / max(float(np.linalg.norm(shoulder - hips)), TINY_M)
    sleeve, skin = person.sleeve_rgba, person.skin_rgba
    return [(*capsule(shoulder, elbow, UPPER_ARM_RADIUS_M * s), sleeve),
            (*capsule(elbow, hand - HAND_HALF_LENGTH_M * s * along, FOREARM_RADIUS_M * s),
             sleeve),
            ("capsule", np.array([HAND_RADIUS_M * s, HAND_HALF_LENGTH_M * s, 0.0]), hand,
             z_onto(along), skin),
            (*capsule(hips, shoulder, TORSO_RADIUS_M * s), sleeve),
            (*capsule(hips * [1, 1, 0] + LEG_RADIUS_M * s * Z_AXIS, hips, LEG_RADIUS_M * s),
             sleeve),
            ("sphere", np.array([HEAD_RADIUS_M * s, 0.0, 0.0]),
             shoulder + HEAD_ABOVE_SHOULDER_M * s * up, z_onto(Z_AXIS), skin)]


def sample_person(rng: np.random.Generator, link: str, camera_position_m: np.ndarray,
                  distance_m: tuple[float, float], shoulder_height_m: tuple[float, float]
                  ) -> PersonDraw:
    """A person gripping `link`, the anchor `distance_m` from the base horizontally at a bearing
    at least `CAMERA_CLEAR_RAD` from the camera's (`camera_position_m`, base frame) and
    `shoulder_height_m` above the base."""
    camera_bearing = float(np.arctan2(camera_position_m[1], camera_position_m[0]))
    bearing = camera_bearing + rng.uniform(CAMERA_CLEAR_RAD, 2 * np.pi - CAMERA_CLEAR_RAD)
    r = rng.uniform(*distance_m)
    anchor = np.array([r * np.cos(bearing), r * np.sin(bearing), rng.uniform(*shoulder_height_m)])
    direction = rng.normal(size=3)
    grip = direction / np.linalg.norm(direction) * rng.uniform(*GRIP_OFFSET_M)
    skin_hue = np.array([1.0, rng.uniform(*SKIN_GREEN), rng.uniform(*SKIN_BLUE)])
    return PersonDraw(link=link, grip_m=grip, anchor_m=anchor,
                      scale=float(rng.uniform(*SCALE_RANGE)),
                      swivel_rad=float(rng.uniform(-SWIVEL_RAD, SWIVEL_RAD)),
                      sleeve_rgba=np.array([*rng.random(3), 1.0]),
                      skin_rgba=np.array([*(skin_hue * rng.uniform(*SKIN_VALUE)), 1.0]))
