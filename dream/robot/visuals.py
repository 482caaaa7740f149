"""Visual geometry of URDF links: mesh files (DAE, STL, OBJ, ...) and primitives, with colours.

Frames: a `LinkVisual` is placed in its link frame by `T_link_visual` (the URDF `<visual>`
`<origin>`); a `MeshPart`'s vertices are in that visual frame, i.e. mesh-file coordinates with
the file's scene-graph transforms, its COLLADA unit and the URDF `scale` already applied. Metres.

Colours: a mesh file's parts keep their own material colours (one `MeshPart` per distinct
colour; a textured or per-vertex-coloured part gets its average colour); a file without colours
(STL) takes the URDF `<material>` colour, else `DEFAULT_RGBA`.
"""

from __future__ import annotations

import functools
import io
import logging
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dream.arrays import read_only
from dream.errors import InputError
from dream.robot.resources import filename_handler, resolve_resource

logger = logging.getLogger(__name__)

DEFAULT_RGBA = (0.7, 0.7, 0.7, 1.0)  # parts whose file and URDF give no colour
COLOUR_DECIMALS = 3  # parts whose rgba agree to this many decimals share one MeshPart
MIN_PART_FACES = 1  # parts with fewer triangles are dropped
UINT8_MAX = 255.0
MESH = "mesh"
BOX = "box"
CYLINDER = "cylinder"
SPHERE = "sphere"
VISUAL_KINDS = (MESH, BOX, CYLINDER, SPHERE)
METRE_UNITS = ("meters", "meter", "metres", "metre", "m")
_BIND_MATERIAL = re.compile(r"<bind_material\b.*?</bind_material>", re.DOTALL)



@dataclass(frozen=True, eq=False)
class MeshPart:
    """Triangles of one colour.

    Attributes:
        vertices: (N, 3) float32, in the visual frame, m.
        faces: (F, 3) int32 vertex indices.
        rgba: (4,) float in [0, 1], or None when the file gives no colour.
    """

    vertices: np.ndarray
    faces: np.ndarray
    rgba: np.ndarray | None

    def __post_init__(self) -> None:
        vertices = read_only(self.vertices, np.float32)
        faces = read_only(self.faces, np.int32)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.all(np.isfinite(vertices)):
            raise InputError(f"mesh vertices have shape {vertices.shape} or are not finite",
                             fix="give (N, 3) finite vertices")
        if faces.ndim != 2 or faces.shape[1] != 3 or (faces.size and (
                faces.min() < 0 or faces.max() >= len(vertices))):
            raise InputError("mesh faces must be (F, 3) indices into the vertices")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)
        if self.rgba is not None:
            object.__setattr__(self, "rgba", _check_rgba(self.rgba, "mesh part colour"))


@dataclass(frozen=True, eq=False)
class LinkVisual:
    """One `<visual>` element of a link.

    Attributes:
        link: the link's name.
        kind: one of `VISUAL_KINDS`.
        T_link_visual: (4, 4) the visual frame in the link frame.
        size: (3,) MuJoCo primitive size: box half-extents; cylinder (radius, half length, 0);
            sphere (radius, 0, 0); zeros for meshes. Metres.
        mesh_path: the mesh file (meshes only).
        mesh_scale: (3,) the URDF `scale` of a mesh.
        rgba: (4,) the URDF material colour, or None.
    """

    link: str
    kind: str
    T_link_visual: np.ndarray
    size: np.ndarray = field(default_factory=lambda: np.zeros(3))
    mesh_path: Path | None = None
    mesh_scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    rgba: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.kind not in VISUAL_KINDS:
            raise InputError(f"visual of link '{self.link}' has kind '{self.kind}'",
                             fix=f"use one of {', '.join(VISUAL_KINDS)}")
        T = read_only(self.T_link_visual, float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"visual origin of link '{self.link}' is not a finite 4x4 matrix")
        object.__setattr__(self, "T_link_visual", T)
        size = read_only(self.size, float)
        scale = read_only(self.mesh_scale, float)
        if size.shape != (3,) or np.any(size < 0) or not np.all(np.isfinite(size)):
            raise InputError(f"visual of link '{self.link}' has an invalid size {self.size}",
                             fix="give non-negative sizes in metres")
        if scale.shape != (3,) or not np.all(np.isfinite(scale)) or np.any(scale == 0):
            raise InputError(f"mesh scale of link '{self.link}' is {self.mesh_scale}",
                             fix="give three finite non-zero scale factors")
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "mesh_scale", scale)
        if self.kind == MESH and self.mesh_path is None:
            raise InputError(f"mesh visual of link '{self.link}' has no file")
        if self.rgba is not None:
            object.__setattr__(self, "rgba", _check_rgba(self.rgba, f"colour of '{self.link}'"))


def _check_rgba(rgba: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(rgba, dtype=float).reshape(-1)
    if a.shape != (4,) or not np.all(np.isfinite(a)):
        raise InputError(f"{what} must be 4 finite numbers (r, g, b, a), got {rgba}")
    return read_only(np.clip(a, 0.0, 1.0), float)


# ----- URDF visuals --------------------------------------------------------------------------

def _primitive_size(geometry, link: str) -> tuple[str, np.ndarray]:
    if geometry.box is not None:
        return BOX, np.asarray(geometry.box.size, dtype=float) / 2.0
    if geometry.cylinder is not None:
        c = geometry.cylinder
        return CYLINDER, np.array([c.radius, c.length / 2.0, 0.0])
    if geometry.sphere is not None:
        return SPHERE, np.array([geometry.sphere.radius, 0.0, 0.0])
    raise InputError(f"a visual of link '{link}' has no box, cylinder, sphere or mesh geometry",
                     fix="give each <visual> one <geometry> child")


def read_link_visuals(urdf_path: str | Path) -> Mapping[str, tuple[LinkVisual, ...]]:
    """Every link's visuals, as written in the URDF (link name -> visuals, in file order).

    Mesh files are resolved with `dream.robot.resolve_resource` (`package://`, relative and
    absolute paths) but not loaded.

    Raises:
        InputError: unreadable URDF, missing mesh file or malformed geometry.
    """
    import yourdfpy  # slow import (trimesh)

    urdf_path = Path(urdf_path)
    try:
        urdf = yourdfpy.URDF.load(str(urdf_path), load_meshes=False, build_scene_graph=False,
                                  load_collision_meshes=False,
                                  build_collision_scene_graph=False,
                                  filename_handler=filename_handler(urdf_path))
    except (ValueError, KeyError, AttributeError, TypeError, IndexError, OSError) as e:
        raise InputError(f"cannot read the URDF's visuals ({type(e).__name__}: {e})", urdf_path,
                         fix="give a valid URDF file") from e
    named = {m.name: m for m in urdf.robot.materials if m.name}
    result: dict[str, tuple[LinkVisual, ...]] = {}
    for link in urdf.robot.links:
        visuals = []
        for v in link.visuals:
            T = np.eye(4) if v.origin is None else np.asarray(v.origin, dtype=float)
            rgba = _material_rgba(v.material, named)
            geometry = v.geometry
            if geometry is None:
                raise InputError(f"a visual of link '{link.name}' has no <geometry>", urdf_path)
            if geometry.mesh is not None:
                path = resolve_resource(geometry.mesh.filename, urdf_path)
                scale = geometry.mesh.scale
                scale = np.ones(3) if scale is None else np.broadcast_to(
                    np.asarray(scale, dtype=float), (3,))
                visuals.append(LinkVisual(link.name, MESH, T, mesh_path=path, mesh_scale=scale,
                                          rgba=rgba))
            else:
                kind, size = _primitive_size(geometry, link.name)
                visuals.append(LinkVisual(link.name, kind, T, size=size, rgba=rgba))
        result[link.name] = tuple(visuals)
    return result


def _material_rgba(material, named: Mapping) -> np.ndarray | None:
    if material is None:
        return None
    if material.color is None and material.name in named:
        material = named[material.name]
    if material.color is None or material.color.rgba is None:
        return None
    return np.asarray(material.color.rgba, dtype=float)


# ----- mesh files ----------------------------------------------------------------------------

def _unit_scale(scene, path: Path) -> float:
    """The COLLADA `<unit meter=...>` factor that trimesh records in its metadata but does
    not apply."""
    units = str(scene.metadata.get("units", "meters") or "meters").strip().lower()
    if units in METRE_UNITS:
        return 1.0
    head, _, tail = units.partition("*")
    try:
        factor = float(head)
    except ValueError:
        factor = None
    if factor is None or tail.strip() not in METRE_UNITS or not factor > 0:
        logger.warning("%s: unknown mesh units '%s'; taking metres", path, units)
        return 1.0
    return factor


def _without_material_bindings(path: Path):
    """The COLLADA scene read again without its nodes' `<bind_material>`: a node whose
    material refers to a missing effect or texture (a Blender export whose image was renamed)
    is dropped whole by the reader, so a file of good triangles reads as empty. Its parts then
    take the URDF's colour."""
    import trimesh

    text = path.read_text(encoding="utf-8", errors="replace")
    stripped = _BIND_MATERIAL.sub("", text)
    if stripped == text:
        return trimesh.Scene()
    scene = trimesh.load(io.BytesIO(stripped.encode("utf-8")), file_type="dae", force="scene")
    if scene.graph.nodes_geometry:
        logger.warning("%s: its materials refer to parts the file lacks; its triangles are "
                       "read without them (the URDF's colour)", path)
    return scene


def _image_mean_rgba(image) -> np.ndarray | None:
    if image is None:
        return None
    pixels = np.asarray(image.convert("RGBA"), dtype=float).reshape(-1, 4)
    return pixels.mean(axis=0) / UINT8_MAX if len(pixels) else None


def part_rgba(visual) -> np.ndarray | None:
    """The main colour (4,) in [0, 1] of a trimesh visual, or None when it has none.

    Material colours are taken as they are; a texture image gives its mean colour (times the
    material's factor); per-vertex or per-face colours give their mean.
    """
    kind = getattr(visual, "kind", None)
    if kind == "texture":
        material = getattr(visual, "material", None)
        if material is None:
            return None
        image = getattr(material, "baseColorTexture", None)
        if image is None:
            image = getattr(material, "image", None)
        mean = _image_mean_rgba(image)
        if mean is None:
            return np.asarray(material.main_color, dtype=float) / UINT8_MAX
        factor = getattr(material, "baseColorFactor", None)
        return mean if factor is None else mean * np.asarray(factor, dtype=float) / UINT8_MAX
    if kind == "vertex":
        return np.asarray(visual.vertex_colors, dtype=float).mean(axis=0) / UINT8_MAX
    if kind == "face":
        return np.asarray(visual.face_colors, dtype=float).mean(axis=0) / UINT8_MAX
    return None


def load_mesh_parts(path: str | Path, scale: np.ndarray | tuple = (1.0, 1.0, 1.0)
                    ) -> tuple[MeshPart, ...]:
    """The triangles of a mesh file, one `MeshPart` per distinct colour, in the visual frame.

    Args:
        path: a mesh file trimesh reads (DAE needs pycollada).
        scale: (3,) the URDF scale, applied after the file's own transforms and unit.
    Raises:
        InputError: the file cannot be read or holds no triangles.
    """
    path = Path(path).resolve()
    try:
        stat = path.stat()
    except OSError as e:
        raise InputError(f"cannot read the mesh file ({e.strerror})", path) from e
    key = tuple(float(s) for s in np.broadcast_to(np.asarray(scale, dtype=float), (3,)))
    return _load_cached(path, stat.st_mtime_ns, stat.st_size, key)


@functools.lru_cache(maxsize=256)
def _load_cached(path: Path, mtime_ns: int, size: int,
                 scale: tuple[float, float, float]) -> tuple[MeshPart, ...]:
    import trimesh  # slow import

    try:
        scene = trimesh.load(str(path), force="scene")
        if path.suffix.lower() == ".dae" and not scene.graph.nodes_geometry:
            scene = _without_material_bindings(path)
    except (ValueError, KeyError, IndexError, TypeError, AttributeError, OSError) as e:
        raise InputError(f"cannot read the mesh ({type(e).__name__}: {e})", path,
                         fix="give a mesh file trimesh reads (DAE, STL, OBJ, PLY, GLB)") from e
    factor = _unit_scale(scene, path) * np.asarray(scale)
    groups: dict[tuple | None, list[tuple[np.ndarray, np.ndarray]]] = {}
    for node in scene.graph.nodes_geometry:
        T, name = scene.graph[node]
        mesh = scene.geometry[name]
        faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
        if faces.ndim != 2 or len(faces) < MIN_PART_FACES:
            continue  # point clouds, paths
        vertices = np.asarray(mesh.vertices, dtype=float) @ T[:3, :3].T + T[:3, 3]
        rgba = part_rgba(mesh.visual)
        key = None if rgba is None else tuple(np.round(rgba, COLOUR_DECIMALS))
        groups.setdefault(key, []).append((vertices * factor, faces))
    if not groups:
        raise InputError("the mesh holds no triangles", path, fix="give a triangle mesh")
    parts = []
    for key, items in groups.items():
        offsets = np.cumsum([0] + [len(v) for v, _ in items[:-1]])
        vertices = np.concatenate([v for v, _ in items])
        faces = np.concatenate([f + o for (_, f), o in zip(items, offsets, strict=True)])
        if np.prod(np.sign(factor)) < 0:  # a mirroring scale flips the winding
            faces = faces[:, ::-1]
        # files often repeat a vertex per face (per-face normals or texture coordinates):
        # merging them gives smooth shading and far fewer vertices to render
        merged = trimesh.Trimesh(vertices, faces, process=True, validate=False)
        parts.append(MeshPart(merged.vertices, merged.faces,
                              None if key is None else np.array(key)))
    return tuple(parts)
