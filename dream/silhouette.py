"""Robot silhouettes rendered on the CPU from the URDF's visual meshes (numpy + OpenCV only).

Geometry: every `<visual>` of every link (mesh files read with trimesh, with their scene-graph
transforms, COLLADA unit and URDF `scale`; boxes, cylinders and spheres tessellated) is placed
in its link frame by the visual `<origin>`, once per robot, and decimated by vertex clustering
on one grid for the whole robot so that the total number of triangles fits a budget (the
silhouette is what matters: clustering on a grid of cell c moves the outline by less than c).

Rendering: the vertices are posed by `Robot.link_poses`, mapped into the camera by
`T_cam_base`, projected with `dream.camera.project` (distortion included) and every triangle is
filled by an exact pixel-centre rule: a pixel is robot when its centre (u, v integer,
docs/data_format.md) lies inside or on the edge of a projected triangle, as a GPU rasteriser
samples it. (OpenCV's
`fillPoly` rounds the vertices and draws the edges, which grows every outline by about half a
pixel; a silhouette fit would turn that into a depth bias, so the fill is done in numpy by
`dream.rasterize`.) Triangles with a vertex closer than `MIN_DEPTH_M` to the camera plane, or
behind it, are skipped. `render_frames` renders the frames in parallel (`dream.threads`).

Public API:
    load_robot_meshes(robot, max_triangles) -> RobotMeshes
    vertices_in_base(meshes, joints) -> (..., V, 3)
    rasterize_triangles(uv_triangles, height, width) -> bool (H, W)   (from dream.rasterize)
    render_points(P_base, faces, T_cam_base, camera) -> bool (H, W)
    render_frames(P_frames, faces, T_cam_base, camera) -> bool (F, H, W)
    render_silhouette(meshes, joints, T_cam_base, camera) -> bool (H, W)
    silhouette_iou(a, b) -> float
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dream.arrays import read_only
from dream.camera import CameraIntrinsics, project
from dream.errors import InputError, RobotError
from dream.rasterize import rasterize_faces, rasterize_triangles  # noqa: F401 (public API)
from dream.robot import Robot
from dream.robot.visuals import BOX, CYLINDER, MESH, LinkVisual, load_mesh_parts, read_link_visuals
from dream.threads import map_frames

log = logging.getLogger(__name__)

DEFAULT_MAX_TRIANGLES = 50000   # triangle budget of a whole robot after decimation
MIN_DEPTH_M = 1e-3              # vertices nearer the camera plane than this count as behind it
CLUSTER_ROUNDS = 12             # grid-size adjustments when decimating to the budget
CLUSTER_MARGIN = 1.05           # grow the grid this much more than the estimate asks
CYLINDER_SECTIONS = 32          # tessellation of URDF cylinders
SPHERE_SUBDIVISIONS = 2         # icosphere subdivisions of URDF spheres



@dataclass(frozen=True, eq=False)
class RobotMeshes:
    """A robot's visual triangles, each vertex attached to one link frame.

    Attributes:
        robot: the kinematics that poses the links.
        links: L link names that carry geometry.
        vertices: (V, 3) vertex positions in their link frame, m.
        vertex_link: (V,) index into `links` of each vertex's link.
        faces: (T, 3) vertex indices of the triangles.
        cell_m: the decimation grid (0 when the meshes were not decimated).
    """

    robot: Robot
    links: tuple[str, ...]
    vertices: np.ndarray
    vertex_link: np.ndarray
    faces: np.ndarray
    cell_m: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.robot, Robot):
            raise InputError("RobotMeshes.robot must be a dream.robot.Robot")
        object.__setattr__(self, "links", tuple(self.links))
        vertices = read_only(self.vertices, float)
        vertex_link = read_only(self.vertex_link, np.int64)
        faces = read_only(self.faces, np.int64)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or not np.all(np.isfinite(vertices)):
            raise InputError(f"mesh vertices have shape {vertices.shape} or are not finite",
                             fix="give (V, 3) finite vertices in metres")
        if vertex_link.shape != (len(vertices),) or (vertex_link.size and (
                vertex_link.min() < 0 or vertex_link.max() >= len(self.links))):
            raise InputError("vertex_link must give one link index per vertex")
        if faces.ndim != 2 or faces.shape[1] != 3 or (faces.size and (
                faces.min() < 0 or faces.max() >= len(vertices))):
            raise InputError(f"faces have shape {faces.shape} or index missing vertices",
                             fix="give (T, 3) indices into the vertices")
        if not (np.isfinite(self.cell_m) and self.cell_m >= 0):
            raise InputError(f"cell_m must be >= 0 metres, got {self.cell_m}")
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "vertex_link", vertex_link)
        object.__setattr__(self, "faces", faces)

    @property
    def num_triangles(self) -> int:
        return len(self.faces)


# ----- loading -------------------------------------------------------------------------------

def _primitive(visual: LinkVisual) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of a URDF box, cylinder or sphere (`LinkVisual.size` holds half-sizes)."""
    import trimesh

    if visual.kind == BOX:
        mesh = trimesh.creation.box(extents=2.0 * visual.size)
    elif visual.kind == CYLINDER:
        mesh = trimesh.creation.cylinder(radius=float(visual.size[0]),
                                         height=2.0 * float(visual.size[1]),
                                         sections=CYLINDER_SECTIONS)
    else:
        mesh = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS,
                                          radius=float(visual.size[0]))
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)


def _link_geometry(urdf_path: Path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(link, vertices in the link frame, faces) of every link with visuals, URDF order."""
    out = []
    for link, visuals in read_link_visuals(urdf_path).items():
        vertices, faces, count = [], [], 0
        for visual in visuals:
            if visual.kind == MESH:
                pieces = [(p.vertices, p.faces)
                          for p in load_mesh_parts(visual.mesh_path, visual.mesh_scale)]
            else:
                pieces = [_primitive(visual)]
            T = visual.T_link_visual
            for v, f in pieces:
                vertices.append(np.asarray(v, dtype=float) @ T[:3, :3].T + T[:3, 3])
                faces.append(np.asarray(f, dtype=np.int64) + count)
                count += len(v)
        if faces:
            out.append((link, np.concatenate(vertices), np.concatenate(faces)))
    return out


def decimate(vertices: np.ndarray, faces: np.ndarray,
             cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: vertices in one grid cell merge into their mean; collapsed and
    repeated triangles are dropped.

    Args:
        vertices: (N, 3), m. faces: (T, 3) indices. cell_m: grid cell edge, m (> 0).
    Returns:
        (vertices (N', 3), faces (T', 3)).
    """
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(f"vertices have shape {vertices.shape}, expected (N, 3)")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"faces have shape {faces.shape}, expected (T, 3)")
    if not (np.isfinite(cell_m) and cell_m > 0):
        raise InputError(f"decimation cell must be a positive number of metres, got {cell_m}")
    cells = np.floor(vertices / cell_m).astype(np.int64)
    _, cluster = np.unique(cells, axis=0, return_inverse=True)
    cluster = cluster.reshape(-1)
    n = int(cluster.max()) + 1 if len(cluster) else 0
    counts = np.bincount(cluster, minlength=n).astype(float)
    merged = np.stack([np.bincount(cluster, vertices[:, k], minlength=n) for k in range(3)], 1)
    merged /= counts[:, None]
    f = cluster[faces]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[keep]
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    f = f[np.sort(first)]
    used = np.unique(f)
    remap = np.full(n, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return merged[used], remap[f]


def _triangle_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def _decimate_all(parts: list[tuple[str, np.ndarray, np.ndarray]],
                  max_triangles: int) -> tuple[list[tuple[str, np.ndarray, np.ndarray]], float]:
    total = sum(len(f) for _, _, f in parts)
    if total <= max_triangles:
        return parts, 0.0
    area = sum(_triangle_area(v, f) for _, v, f in parts)
    # vertex clustering leaves about 2 triangles per occupied cell, about area / cell^2 cells
    cell = float(np.sqrt(2.0 * area / max_triangles))
    out = parts
    for _ in range(CLUSTER_ROUNDS):
        out = [(name, *decimate(v, f, cell)) for name, v, f in parts]
        count = sum(len(f) for _, _, f in out)
        if count <= max_triangles:
            break
        cell *= float(np.sqrt(count / max_triangles)) * CLUSTER_MARGIN
    else:
        log.warning("decimation stopped at %d triangles (budget %d)", count, max_triangles)
    return out, cell


@functools.lru_cache(maxsize=8)
def _cached_geometry(urdf_path: Path, mtime_ns: int, max_triangles: int
                     ) -> tuple[tuple[tuple[str, np.ndarray, np.ndarray], ...], float]:
    parts = _link_geometry(urdf_path)
    original = sum(len(f) for _, _, f in parts)
    parts, cell = _decimate_all(parts, max_triangles)
    log.info("%s: %d visual triangles, %d after decimation (grid %.4f m)", urdf_path.name,
             original, sum(len(f) for _, _, f in parts), cell)
    return tuple(parts), cell


def load_robot_meshes(robot: Robot, max_triangles: int = DEFAULT_MAX_TRIANGLES) -> RobotMeshes:
    """The robot's visual meshes in their link frames, decimated to `max_triangles`.

    Read once per URDF file and budget (cached). Links whose pose the robot's kinematics cannot
    compute (unsupported joints on their chain) are left out with a warning.

    Raises:
        InputError: unreadable URDF or mesh file, a URDF without any visual geometry, or a
            budget below one triangle.
    """
    if not isinstance(robot, Robot):
        raise InputError("load_robot_meshes needs a dream.robot.Robot (use load_robot)")
    if int(max_triangles) != max_triangles or max_triangles < 1:
        raise InputError(f"max_triangles must be a positive integer, got {max_triangles}")
    path = Path(robot.urdf_path).resolve()
    try:
        mtime = path.stat().st_mtime_ns
    except OSError as e:
        raise InputError(f"cannot read the URDF ({e.strerror})", path) from e
    parts, cell = _cached_geometry(path, mtime, int(max_triangles))
    links, vertices, vertex_link, faces, count = [], [], [], [], 0
    for name, v, f in parts:
        try:
            robot.link_poses(robot.rest_joints, [name])
        except RobotError as e:
            log.warning("link '%s' is not rendered: %s", name, e)
            continue
        vertex_link.append(np.full(len(v), len(links)))
        links.append(name)
        vertices.append(v)
        faces.append(f + count)
        count += len(v)
    if not links:
        raise InputError("the URDF has no visual geometry on links below the robot's base",
                         path, fix="give a URDF with <visual> meshes or primitives")
    return RobotMeshes(robot, tuple(links), np.concatenate(vertices),
                       np.concatenate(vertex_link), np.concatenate(faces), cell)


# ----- rendering -----------------------------------------------------------------------------

def vertices_in_base(meshes: RobotMeshes, joints: np.ndarray) -> np.ndarray:
    """Mesh vertices in the robot base frame for joint vectors (..., J): shape (..., V, 3)."""
    T = meshes.robot.link_poses(joints, meshes.links)            # (..., L, 4, 4)
    P = np.empty(T.shape[:-3] + meshes.vertices.shape)
    for i in range(len(meshes.links)):    # link by link: no (..., V, 4, 4) of every vertex
        at = np.flatnonzero(meshes.vertex_link == i)
        P[..., at, :] = (meshes.vertices[at] @ np.swapaxes(T[..., i, :3, :3], -1, -2)
                         + T[..., i, None, :3, 3])
    return P


def static_links(meshes: RobotMeshes, joints: np.ndarray, min_motion_m: float
                 ) -> tuple[str, ...]:
    """Links whose vertices move less than `min_motion_m` (base frame) over the joint vectors
    (F, J): the links a background model of a fixed camera holds. Measured link by link (no
    (F, V) array of the whole robot)."""
    T = meshes.robot.link_poses(joints, meshes.links)                      # (F, L, 4, 4)
    static = []
    for i, name in enumerate(meshes.links):
        v = meshes.vertices[meshes.vertex_link == i]                       # (V_i, 3)
        P = v @ T[:, i, :3, :3].transpose(0, 2, 1) + T[:, i, None, :3, 3]  # (F, V_i, 3)
        if not len(v) or np.linalg.norm(P - P[:1], axis=2).max() < min_motion_m:
            static.append(name)
    return tuple(static)


def without_links(meshes: RobotMeshes, links: tuple[str, ...]) -> RobotMeshes:
    """The same meshes with the triangles of `links` removed (their vertices stay, unused).

    Raises:
        InputError: an unknown link, or every link with triangles removed.
    """
    unknown = sorted(set(links) - set(meshes.links))
    if unknown:
        raise InputError(f"unknown link(s) {', '.join(unknown)}",
                         fix=f"use links of the robot: {', '.join(meshes.links)}")
    gone = np.isin(meshes.vertex_link, [meshes.links.index(name) for name in links])
    faces = meshes.faces[~gone[meshes.faces].any(axis=1)]
    if not len(faces):
        raise InputError("every link with geometry is left out, so nothing is left to render")
    return dataclasses.replace(meshes, faces=faces)


def render_points(P_base: np.ndarray, faces: np.ndarray, T_cam_base: np.ndarray,
                  camera: CameraIntrinsics) -> np.ndarray:
    """The silhouette (H, W) bool of triangles `faces` (T, 3) over base-frame vertices (V, 3)."""
    P_base = np.asarray(P_base, dtype=float)
    T = np.asarray(T_cam_base, dtype=float)
    if P_base.ndim != 2 or P_base.shape[1] != 3:
        raise InputError(f"P_base has shape {P_base.shape}, expected (V, 3)")
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError("T_cam_base must be a finite 4x4 matrix")
    P_cam = P_base @ T[:3, :3].T + T[:3, 3]
    P_cam[P_cam[:, 2] < MIN_DEPTH_M] = np.nan   # behind: projects to NaN, triangle skipped
    uv = project(camera, P_cam)
    return rasterize_faces(uv[:, 0], uv[:, 1], faces, camera.height, camera.width)


def render_frames(P_frames: np.ndarray, faces: np.ndarray, T_cam_base: np.ndarray,
                  camera: CameraIntrinsics) -> np.ndarray:
    """(F, H, W) bool: `render_points` of each frame's vertices P_frames (F, V, 3), the
    frames rendered in parallel (`dream.threads`)."""
    rendered = map_frames(lambda P: render_points(P, faces, T_cam_base, camera), P_frames)
    if not rendered:
        return np.zeros((0, camera.height, camera.width), dtype=bool)
    return np.stack(rendered)


def render_silhouette(robot_meshes: RobotMeshes, joints: np.ndarray, T_cam_base: np.ndarray,
                      camera: CameraIntrinsics) -> np.ndarray:
    """The robot's silhouette seen by `camera` at `T_cam_base` with joints (J,): (H, W) bool."""
    q = np.asarray(joints, dtype=float)
    if q.shape != (robot_meshes.robot.num_joints,):
        raise InputError(f"joints have shape {q.shape}, expected "
                         f"({robot_meshes.robot.num_joints},) "
                         f"({', '.join(robot_meshes.robot.joint_names)})")
    return render_points(vertices_in_base(robot_meshes, q), robot_meshes.faces, T_cam_base,
                         camera)


def silhouette_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (H, W) masks; 1.0 when both are empty."""
    a = np.asarray(a, dtype=bool)
    b = np.asarray(b, dtype=bool)
    if a.shape != b.shape or a.ndim != 2:
        raise InputError(f"masks have shapes {a.shape} and {b.shape}, expected one (H, W)")
    union = int(np.count_nonzero(a | b))
    return 1.0 if union == 0 else int(np.count_nonzero(a & b)) / union

