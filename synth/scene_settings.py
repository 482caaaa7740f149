"""`SceneSettings`: what a robot scene holds besides the robot (lights, distractors, ...)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from dream.errors import InputError

MAX_LIGHTS = 7  # OpenGL's fixed pipeline has 8 lights; MuJoCo's headlight takes one
MAX_TEXTURE_SIZE_PX = 4096
# Largest image side (`intrinsics.width` / `height`) a recipe may ask for. MuJoCo renders into
# an OpenGL framebuffer no larger than GL_MAX_RENDERBUFFER_SIZE per side: 16384 on Mesa's
# llvmpipe (the headless EGL default; NVIDIA's drivers allow 32768), and beyond it the buffer
# "is not complete". A camera that is resampled (fx != fy or distortion) renders its ids into
# a buffer up to 4 times its image per side (`RenderSettings.max_render_scale` 2 x
# `id_oversampling` 2), hence 16384 / 4.
GL_MIN_RENDERBUFFER_PX = 16384
MAX_RENDER_BUFFER_FACTOR = 4
MAX_IMAGE_SIZE_PX = GL_MIN_RENDERBUFFER_PX // MAX_RENDER_BUFFER_FACTOR


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise InputError(f"SceneSettings.{name} = {value} must be a positive number")
    return value


def _count(name: str, value: int, upper: int | None = None) -> int:
    if isinstance(value, bool) or int(value) != value or value < 0 or (
            upper is not None and value > upper):
        limit = "" if upper is None else f" up to {upper}"
        raise InputError(f"SceneSettings.{name} = {value} must be a whole number >= 0{limit}")
    return int(value)


def _rgba(name: str, value: tuple[float, ...]) -> tuple[float, float, float, float]:
    a = np.asarray(value, dtype=float).reshape(-1)
    if a.shape != (4,) or not np.all(np.isfinite(a)) or np.any(a < 0) or np.any(a > 1):
        raise InputError(f"SceneSettings.{name} = {value} must be 4 numbers in [0, 1]")
    return tuple(float(x) for x in a)


@dataclass(frozen=True)
class SceneSettings:
    """What `build_scene` puts in the MuJoCo model. Metres, radians, pixels.

    Attributes:
        num_lights: spot lights (not directional; shadows only where `Lights.shadow_prob` asks)
            for domain randomisation.
        light_height_m: initial height of the lights above the base, on a circle of
            `light_radius_m`, all aimed at the base origin.
        light_radius_m: radius of that circle.
        light_diffuse: initial diffuse intensity of each light (grey level in [0, 1]).
        num_distractors: static world bodies with one box geom each, parked below the floor
            at `distractor_parking_z_m` until the caller moves them.
        distractor_half_size_m: initial box half-extent of the distractor geoms.
        distractor_parking_z_m: initial height of the distractors (out of sight).
        num_textures: 2D textures (each with its own material) the caller may rewrite.
        texture_size: their width and height, px.
        floor: add a plane at z = 0 (base frame) with its own material and texture.
        floor_half_size_m: half-extent of the floor plane.
        floor_texture_size: floor texture width and height, px.
        floor_texture_repeat: how many times the floor texture repeats across the plane.
        keypoint_markers: add a small sphere at each keypoint's link origin.
        marker_radius_m: radius of those spheres.
        default_rgba: colour of robot parts whose file and URDF give none.
        link_mass_kg: mass given to every link body (MuJoCo needs one; no dynamics is run).
        link_inertia_kg_m2: diagonal inertia given to every link body.
    """

    num_lights: int = 4
    light_height_m: float = 2.0
    light_radius_m: float = 1.5
    light_diffuse: float = 0.4
    num_distractors: int = 0
    distractor_half_size_m: float = 0.05
    distractor_parking_z_m: float = -100.0
    num_textures: int = 0
    texture_size: int = 64
    floor: bool = False
    floor_half_size_m: float = 5.0
    floor_texture_size: int = 256
    floor_texture_repeat: float = 10.0
    keypoint_markers: bool = False
    marker_radius_m: float = 0.004
    default_rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    link_mass_kg: float = 1.0
    link_inertia_kg_m2: float = 1e-3

    def __post_init__(self) -> None:
        object.__setattr__(self, "num_lights", _count("num_lights", self.num_lights, MAX_LIGHTS))
        object.__setattr__(self, "num_distractors", _count("num_distractors",
                                                           self.num_distractors))
        object.__setattr__(self, "num_textures", _count("num_textures", self.num_textures))
        for name in ("texture_size", "floor_texture_size"):
            size = _count(name, getattr(self, name), MAX_TEXTURE_SIZE_PX)
            if size == 0:
                raise InputError(f"SceneSettings.{name} must be at least 1 px")
            object.__setattr__(self, name, size)
        for name in ("light_height_m", "light_radius_m", "light_diffuse",
                     "distractor_half_size_m", "floor_half_size_m", "floor_texture_repeat",
                     "marker_radius_m", "link_mass_kg", "link_inertia_kg_m2"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        if not np.isfinite(self.distractor_parking_z_m):
            raise InputError("SceneSettings.distractor_parking_z_m must be finite")
        object.__setattr__(self, "distractor_parking_z_m", float(self.distractor_parking_z_m))
        object.__setattr__(self, "floor", bool(self.floor))
        object.__setattr__(self, "keypoint_markers", bool(self.keypoint_markers))
        object.__setattr__(self, "default_rgba", _rgba("default_rgba", self.default_rgba))

    def as_dict(self) -> dict:
        """Plain values (for cache keys and logs)."""
        return dataclasses.asdict(self)
