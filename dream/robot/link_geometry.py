"""A link whose visible geometry differs from the URDF's: a tool, a gripper or a held board.

The `link_geometry` effect of a model extension (`dream.extension`), one `LinkGeometry` per
link, of one of three kinds:

- `box`: a box attached to the link: full extents `size_m`, centre `position_m` and rotation
  vector `rotation_rad` in the link frame (a plate at the flange, a held checkerboard);
- `scale`: the link's visual geometry scaled by `scale` about the link frame's origin;
- `exclude`: the link's true outline is unknown: image comparisons leave it out.

Applied (pure) to the two geometries the project draws: the URDF visuals a MuJoCo scene is built
from (`extended_visuals`, for `dream synth`) and the triangle meshes of the image refinement
(`with_link_geometry`, for `dream calibrate --refine edges`). Keypoints stay link origins.
Metres and radians.

    >>> plate = LinkGeometry("panda_hand", BOX_KIND, size_m=(0.2, 0.15, 0.004),
    ...                      position_m=(0.0, 0.0, 0.12))
    >>> plate.to_params()["size_m"]
    [0.2, 0.15, 0.004]
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from dream.errors import InputError
from dream.transforms import T_from_rotvec_t

BOX_KIND = "box"
SCALE_KIND = "scale"
EXCLUDE_KIND = "exclude"
KINDS = (BOX_KIND, SCALE_KIND, EXCLUDE_KIND)
PARAM_KEYS = {BOX_KIND: ("kind", "size_m", "position_m", "rotation_rad"),
              SCALE_KIND: ("kind", "scale"), EXCLUDE_KIND: ("kind",)}
# Plausibility: a tool or board at a link is at most this large, and a scale this far from 1.
MAX_BOX_SIZE_M = 1.5
MAX_OFFSET_M = 1.5
SCALE_RANGE = (0.5, 2.0)
BOX_RGBA = (0.55, 0.55, 0.55, 1.0)    # the colour synth renders an added box with
_BOX_CORNERS = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5)
                         for z in (-0.5, 0.5)])
# the 12 triangles of a box over `_BOX_CORNERS` (index = 4x + 2y + z), outward normals
_BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                       [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def _vector3(value: Any, what: str) -> np.ndarray:
    a = np.asarray(value, dtype=float).reshape(-1) if not isinstance(value, str) else None
    if a is None or a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"link_geometry {what} must be 3 finite numbers, got {value!r}")
    return a


@dataclass(frozen=True)
class LinkGeometry:
    """The visible geometry of one link, where it differs from the URDF (module doc)."""

    link: str
    kind: str
    size_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: float = 1.0

    def __post_init__(self) -> None:
        if not isinstance(self.link, str) or not self.link:
            raise InputError(f"link_geometry needs a link name, got {self.link!r}")
        if self.kind not in KINDS:
            raise InputError(f"link_geometry of '{self.link}' has kind {self.kind!r}",
                             fix=f"use one of {', '.join(KINDS)}")
        size = _vector3(self.size_m, f"size_m of '{self.link}'")
        position = _vector3(self.position_m, f"position_m of '{self.link}'")
        rotation = _vector3(self.rotation_rad, f"rotation_rad of '{self.link}'")
        if self.kind == BOX_KIND:
            if np.any(size <= 0) or np.any(size > MAX_BOX_SIZE_M):
                raise InputError(f"link_geometry box of '{self.link}' has size_m "
                                 f"{size.tolist()}", fix=f"give 3 extents in metres, each "
                                 f"in (0, {MAX_BOX_SIZE_M}] (are these millimetres?)")
            if np.linalg.norm(position) > MAX_OFFSET_M:
                raise InputError(f"link_geometry box of '{self.link}' lies "
                                 f"{np.linalg.norm(position):.3g} m from its link",
                                 fix=f"give position_m in metres, within {MAX_OFFSET_M} m "
                                 "(are these millimetres?)")
        scale = float(self.scale)
        if self.kind == SCALE_KIND and not (np.isfinite(scale)
                                            and SCALE_RANGE[0] <= scale <= SCALE_RANGE[1]):
            raise InputError(f"link_geometry scale of '{self.link}' is {self.scale!r}",
                             fix=f"give a factor in [{SCALE_RANGE[0]}, {SCALE_RANGE[1]}]")
        for name, value in (("size_m", size), ("position_m", position),
                            ("rotation_rad", rotation)):
            object.__setattr__(self, name, tuple(float(v) for v in value))
        object.__setattr__(self, "scale", scale)

    @property
    def T_link_box(self) -> np.ndarray:
        """(4, 4) the box frame (its centre) in the link frame."""
        return T_from_rotvec_t(np.array(self.rotation_rad), np.array(self.position_m))

    def box_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """The box's (8, 3) corners in the link frame and (12, 3) outward triangles."""
        T = self.T_link_box
        corners = (_BOX_CORNERS * np.array(self.size_m)) @ T[:3, :3].T + T[:3, 3]
        return corners, _BOX_FACES.copy()

    def to_params(self) -> dict[str, Any]:
        """The extended_model.yaml parameters (without the link name, its key)."""
        if self.kind == BOX_KIND:
            return {"kind": BOX_KIND, "size_m": list(self.size_m),
                    "position_m": list(self.position_m),
                    "rotation_rad": list(self.rotation_rad)}
        if self.kind == SCALE_KIND:
            return {"kind": SCALE_KIND, "scale": self.scale}
        return {"kind": EXCLUDE_KIND}


def parse_link_geometry(params: Mapping[str, Any]) -> tuple[LinkGeometry, ...]:
    """{link: {kind, ...}} (extended_model.yaml) -> LinkGeometry per link; `exclude` alone may
    be written as the plain string."""
    out = []
    for link, spec in params.items():
        if spec == EXCLUDE_KIND:
            spec = {"kind": EXCLUDE_KIND}
        if not isinstance(spec, Mapping) or spec.get("kind") not in KINDS:
            raise InputError(f"link_geometry of '{link}' needs a kind ({', '.join(KINDS)}), "
                             f"got {spec!r}", fix="e.g. panda_hand: {kind: box, size_m: "
                             "[0.2, 0.15, 0.004], position_m: [0, 0, 0.12]}")
        unknown = [str(k) for k in spec if k not in PARAM_KEYS[spec["kind"]]]
        if unknown:
            raise InputError(f"link_geometry {spec['kind']} of '{link}' has unknown parameter "
                             f"'{unknown[0]}'", fix=f"use {', '.join(PARAM_KEYS[spec['kind']])}")
        out.append(LinkGeometry(str(link), **{k: v for k, v in spec.items()}))
    return tuple(out)


def check_links(geometries: tuple[LinkGeometry, ...], links: tuple[str, ...]) -> None:
    """Every geometry must name one of `links`, at most once."""
    names = [g.link for g in geometries]
    unknown = sorted(set(names) - set(links))
    if unknown:
        raise InputError(f"link_geometry names unknown link(s) {', '.join(unknown)}",
                         fix=f"use links of the robot: {', '.join(links)}")
    if len(set(names)) != len(names):
        raise InputError("link_geometry names a link twice", fix="give one entry per link")


def excluded_links(geometries: tuple[LinkGeometry, ...]) -> tuple[str, ...]:
    """The links whose outline image comparisons leave out."""
    return tuple(g.link for g in geometries if g.kind == EXCLUDE_KIND)


def with_link_geometry(meshes, geometries: tuple[LinkGeometry, ...]):
    """`dream.silhouette.RobotMeshes` with the boxes added to their links (a link without
    geometry of its own joins the meshes) and the scaled links' vertices scaled; `exclude`
    is left to the caller (`excluded_links`), which knows what to leave out.

    Raises:
        InputError: a link the robot does not have.
    """
    if not geometries:
        return meshes
    check_links(geometries, tuple(meshes.robot.link_names))
    links = list(meshes.links)
    vertices, vertex_link = meshes.vertices.copy(), meshes.vertex_link.copy()
    faces = [meshes.faces]
    for g in geometries:
        if g.kind == SCALE_KIND and g.link in links:
            vertices[vertex_link == links.index(g.link)] *= g.scale
        elif g.kind == BOX_KIND:
            if g.link not in links:
                links.append(g.link)
            corners, box_faces = g.box_mesh()
            faces.append(box_faces + len(vertices))
            vertices = np.concatenate([vertices, corners])
            vertex_link = np.concatenate([vertex_link, np.full(len(corners),
                                                               links.index(g.link))])
    return dataclasses.replace(meshes, links=tuple(links), vertices=vertices,
                               vertex_link=vertex_link, faces=np.concatenate(faces))


def check_renderable(geometries: tuple[LinkGeometry, ...]) -> None:
    """Refuse `exclude`, which has no geometry to render."""
    for g in geometries:
        if g.kind == EXCLUDE_KIND:
            raise InputError(f"link_geometry exclude of '{g.link}' says its true outline is "
                             "unknown, so it cannot be rendered",
                             fix="give a box or a scale for the link to render it")


def extended_visuals(visuals: Mapping[str, tuple], geometries: tuple[LinkGeometry, ...]
                     ) -> dict[str, tuple]:
    """URDF visuals (`dream.robot.visuals.read_link_visuals`) with each box added to its link as
    a box visual and each scaled link's visuals scaled about the link origin.

    Raises:
        InputError: `exclude`, which has no geometry to render.
    """
    from dream.robot.visuals import BOX, LinkVisual

    check_renderable(geometries)
    out = dict(visuals)
    for g in geometries:
        if g.kind == SCALE_KIND:
            out[g.link] = tuple(_scaled(v, g.scale) for v in out.get(g.link, ()))
        else:
            box = LinkVisual(g.link, BOX, g.T_link_box, size=np.array(g.size_m) / 2.0,
                             rgba=np.array(BOX_RGBA))
            out[g.link] = (*out.get(g.link, ()), box)
    return out


def _scaled(visual, scale: float):
    """One URDF visual scaled by `scale` about its link's origin."""
    T = visual.T_link_visual.copy()
    T[:3, 3] *= scale
    return dataclasses.replace(visual, T_link_visual=T, size=visual.size * scale,
                               mesh_scale=visual.mesh_scale * scale)

