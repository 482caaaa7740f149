"""Which robot poses may be planned: collisions, keypoints in view and unoccluded, the robot
not cut by the image border.

Geometry is the URDF's visual meshes in the MuJoCo scene of `synth.scene` (MuJoCo measures
meshes by their convex hulls, so the checks err on the safe side). A pose is valid when

- no two links that are not neighbours (`synth.labels.adjacent_links`) come closer than the
  clearance; pairs that are that close in nearly every random pose (a gripper's closed
  fingers) are always in contact and not checked, as MoveIt's setup assistant leaves out its
  "always" pairs;
- every link except the base and its neighbours stays the clearance above the table plane and
  away from every keep-out box (so a box may hold the robot's base, like a table);
- every keypoint lies in the image, at least the margin inside its border, in front of the
  camera, and is not hidden behind another link or a keep-out box
  (`synth.labels.keypoint_labels`);
- at most `max_cut` of the robot's mesh points project outside the image.

Frames: the base frame is MuJoCo's world frame; boxes and the table are given in it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from dream.camera import CameraIntrinsics, project
from dream.errors import InputError
from dream.robot import Robot
from dream.settings_checks import check_fields
from dream.transforms import check_pose, transform_points
from synth.gl import mujoco
from synth.labels import VISIBLE, adjacent_links, keypoint_labels, rigid_group
from synth.rays import keypoint_ray_hits
from synth.render import NUM_GEOM_GROUPS
from synth.scene import RobotScene, build_scene
from synth.scene_settings import SceneSettings
from synth.scene_spec import DISTRACTOR_GROUP, ROBOT_GROUP

logger = logging.getLogger(__name__)

SURFACE_POINTS_PER_GEOM = 200   # mesh points per geom for the share cut by the image border
DISTANCE_HORIZON_M = 0.2        # clearances are measured up to this distance (larger: capped)
CONTACT_SAMPLES = 200           # random poses that decide which link pairs always touch
ALWAYS_IN_CONTACT_SHARE = 0.95  # pairs touching in this share of them are not checked
CONTACT_SEED = 0
MOTION_STEP_RAD = 0.05          # a move between poses is checked at least this finely


@dataclass(frozen=True)
class Box:
    """An axis-aligned keep-out box in the base frame, m."""

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]

    def __post_init__(self) -> None:
        lower, upper = np.asarray(self.lower, float), np.asarray(self.upper, float)
        if lower.shape != (3,) or upper.shape != (3,) or not np.all(np.isfinite(lower)) \
                or not np.all(np.isfinite(upper)) or np.any(upper <= lower):
            raise InputError(f"a keep-out box needs finite corners with lower < upper on each "
                             f"axis, got {self.lower} and {self.upper}",
                             fix="give --keep-out xmin,ymin,zmin,xmax,ymax,zmax in metres")
        object.__setattr__(self, "lower", tuple(lower.tolist()))
        object.__setattr__(self, "upper", tuple(upper.tolist()))


@dataclass(frozen=True)
class Feasibility:
    """What a planned pose must satisfy. Metres, pixels.

    Attributes:
        table_z_m: height of the table plane in the base frame; None: no table.
        keep_out: boxes no link may enter.
        clearance_m: the least distance between non-neighbouring links, to a box, to the table.
        margin_px: keypoints at least this far inside the image border.
        max_cut: the largest share of the robot's mesh points outside the image.
        occlusion_margin_m: a link hides a keypoint when it lies this much nearer the camera.
    """

    table_z_m: float | None = 0.0
    keep_out: tuple[Box, ...] = ()
    clearance_m: float = 0.01
    margin_px: float = 20.0
    max_cut: float = 0.2
    occlusion_margin_m: float = 0.05

    def __post_init__(self) -> None:
        if self.table_z_m is not None and not np.isfinite(self.table_z_m):
            raise InputError(f"the table height must be finite, got {self.table_z_m}")
        check_fields(self, "feasibility", non_negative=("clearance_m", "margin_px",
                                                        "occlusion_margin_m"))
        if not 0 <= self.max_cut <= 1:
            raise InputError(f"max_cut must be a share between 0 and 1, got {self.max_cut}",
                             fix="give e.g. --max-cut 0.2")
        object.__setattr__(self, "keep_out", tuple(self.keep_out))


@dataclass(frozen=True)
class PoseCheck:
    """One pose's checks: `valid`, the first failed check's name in `failed` (or None), the
    least clearance to another link, a box and the table (m, capped at the horizon), the
    share of mesh points outside the image, and how far the keypoint nearest the image border
    lies inside it (px)."""

    valid: bool
    failed: str | None
    self_clearance_m: float = float("inf")
    box_clearance_m: float = float("inf")
    table_clearance_m: float = float("inf")
    cut: float = 0.0
    border_px: float = float("nan")


def border_distance_px(uv: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
    """(...) how far each pixel `uv` (..., 2) lies inside the image border (negative:
    outside; NaN where `uv` is)."""
    return np.minimum.reduce([uv[..., 0], uv[..., 1], camera.width - 1 - uv[..., 0],
                              camera.height - 1 - uv[..., 1]])


def keypoints_in_view(P_base: np.ndarray, camera: CameraIntrinsics, T_cam_base: np.ndarray,
                      margin_px: float) -> np.ndarray:
    """(N, K) True where keypoint k of pose n (`P_base` (N, K, 3)) lies in front of the camera
    and at least `margin_px` inside the image border."""
    P_cam = transform_points(T_cam_base, P_base)
    uv = project(camera, P_cam)
    return (border_distance_px(uv, camera) >= margin_px) & (P_cam[..., 2] > 0) & \
        np.all(np.isfinite(uv), -1)


def in_view(P_base: np.ndarray, camera: CameraIntrinsics, T_cam_base: np.ndarray,
            margin_px: float) -> np.ndarray:
    """(N,) True where every keypoint of a pose (`P_base` (N, K, 3)) is in view
    (`keypoints_in_view`). Cheap: filters draws before the MuJoCo checks."""
    return np.all(keypoints_in_view(P_base, camera, T_cam_base, margin_px), axis=-1)


def place_boxes(scene: RobotScene, boxes: tuple[Box, ...]) -> None:
    """Put `boxes` into the scene's distractor slots (one slot per box, made by
    `SceneSettings(num_distractors=len(boxes))`)."""
    model = scene.model
    for body, geom, box in zip(scene.distractor_body_ids, scene.distractor_geom_ids, boxes,
                               strict=True):
        lower, upper = np.array(box.lower), np.array(box.upper)
        half = (upper - lower) / 2
        model.body_pos[body] = (upper + lower) / 2
        model.body_quat[body] = [1.0, 0.0, 0.0, 0.0]
        model.geom_type[geom] = mujoco.mjtGeom.mjGEOM_BOX
        model.geom_size[geom] = half
        model.geom_rbound[geom] = float(np.linalg.norm(half))
        model.geom_aabb[geom] = np.concatenate([np.zeros(3), half])


def _mesh_points(model: mujoco.MjModel, geom: int) -> np.ndarray:
    """(P, 3) points of a geom in its own frame: a mesh's vertices, else its box corners."""
    mesh = int(model.geom_dataid[geom])
    if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_MESH and mesh >= 0:
        start, count = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
        return np.array(model.mesh_vert[start:start + count], dtype=float)
    centre, half = model.geom_aabb[geom][:3], model.geom_aabb[geom][3:]
    corners = np.array(np.meshgrid(*[[-1.0, 1.0]] * 3, indexing="ij")).reshape(3, -1).T
    return centre + corners * half


def _hull(points: np.ndarray) -> np.ndarray:
    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):   # flat or tiny geometry: keep every point
        return points


@dataclass(eq=False)
class PoseChecker:
    """Checks poses of `robot` against `feasibility` for a camera at `T_cam_base`.

    Owns a MuJoCo scene of the robot (boxes as its distractor slots) and its data; not for use
    from several threads at once.
    """

    robot: Robot
    feasibility: Feasibility
    camera: CameraIntrinsics
    T_cam_base: np.ndarray
    scene: RobotScene = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.T_cam_base = check_pose(self.T_cam_base, "T_cam_base")
        options = SceneSettings(num_lights=1, num_distractors=len(self.feasibility.keep_out),
                                floor=False)
        self.scene = build_scene(self.robot, options)
        self.data = mujoco.MjData(self.scene.model)
        place_boxes(self.scene, self.feasibility.keep_out)
        self._index_pairs()
        model = self.scene.model
        self._hulls = {int(g): _hull(_mesh_points(model, int(g)))
                       for g in self.scene.robot_geom_ids}
        self._surface = {}
        for g in self.scene.robot_geom_ids:
            points = _mesh_points(model, int(g))
            stride = max(1, len(points) // SURFACE_POINTS_PER_GEOM)
            self._surface[int(g)] = points[::stride]
        self._groups = np.zeros(NUM_GEOM_GROUPS, np.uint8)   # rays meet links and boxes
        self._groups[[ROBOT_GROUP, DISTRACTOR_GROUP]] = 1
        self._box_geoms = frozenset(self.scene.distractor_geom_ids.tolist())

    def _index_pairs(self) -> None:
        """Geom pairs of non-neighbouring links, less those in contact in nearly every pose;
        robot geoms that the table and boxes are tested against."""
        scene, robot = self.scene, self.robot
        link_of = {int(g): scene.link_names[scene.geom_link_index[g] - 1]
                   for g in scene.robot_geom_ids}
        geoms = sorted(link_of)
        pairs = np.array([(a, b) for i, a in enumerate(geoms) for b in geoms[i + 1:]
                          if link_of[b] not in adjacent_links(robot, link_of[a])],
                         dtype=int).reshape(-1, 2)
        rng = np.random.default_rng(CONTACT_SEED)
        touching = np.zeros(len(pairs))
        for q in rng.uniform(robot.joint_lower, robot.joint_upper,
                             (CONTACT_SAMPLES, robot.num_joints)):
            scene.set_joints(self.data, q)
            touching += self._distances(pairs) < self.feasibility.clearance_m
        always = touching >= ALWAYS_IN_CONTACT_SHARE * CONTACT_SAMPLES
        self.always_in_contact = tuple(sorted({(link_of[a], link_of[b])
                                               for a, b in pairs[always]}))
        for a, b in self.always_in_contact:
            logger.info("%s and %s touch in nearly every pose: not checked", a, b)
        self._pairs = pairs[~always]
        grounded = adjacent_links(robot, robot.base_link) | rigid_group(robot, robot.base_link)
        self._free_geoms = [g for g in geoms if link_of[g] not in grounded]
        self._box_pairs = np.array([(b, g) for b in scene.distractor_geom_ids
                                    for g in self._free_geoms], dtype=int).reshape(-1, 2)

    def _distances(self, pairs: np.ndarray) -> np.ndarray:
        """(K,) distance of each geom pair (K, 2) in the current state, m (negative: they
        overlap), capped at the horizon; bounding spheres skip the pairs far apart."""
        model, data = self.scene.model, self.data
        out = np.full(len(pairs), DISTANCE_HORIZON_M)
        if len(pairs) == 0:
            return out
        centre = data.geom_xpos
        gap = np.linalg.norm(centre[pairs[:, 0]] - centre[pairs[:, 1]], axis=1) - \
            model.geom_rbound[pairs[:, 0]] - model.geom_rbound[pairs[:, 1]]
        fromto = np.zeros(6)
        for k in np.flatnonzero(gap < DISTANCE_HORIZON_M):
            out[k] = mujoco.mj_geomDistance(model, data, int(pairs[k, 0]), int(pairs[k, 1]),
                                            DISTANCE_HORIZON_M, fromto)
        return out

    def _clearance(self, pairs: np.ndarray) -> float:
        """The least distance over geom `pairs` (K, 2), capped at the horizon."""
        return float(self._distances(pairs).min()) if len(pairs) else float("inf")

    def _table_clearance(self) -> float:
        z0 = self.feasibility.table_z_m
        if z0 is None or not self._free_geoms:
            return float("inf")
        data = self.data
        lowest = min(float(np.min(self._hulls[g] @ data.geom_xmat[g].reshape(3, 3)[2]))
                     + float(data.geom_xpos[g][2]) for g in self._free_geoms)
        return lowest - z0

    def _world_points(self, points: dict[int, np.ndarray]) -> np.ndarray:
        data = self.data
        return np.concatenate([p @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
                               for g, p in points.items()])

    def cut_share(self) -> float:
        """Share of the robot's mesh points (current state) outside the image or behind."""
        P_cam = transform_points(self.T_cam_base, self._world_points(self._surface))
        uv = project(self.camera, P_cam)
        inside = self.camera.in_image(uv) & (P_cam[:, 2] > 0) & np.all(np.isfinite(uv), -1)
        return float(1.0 - inside.mean())

    def motion_clearance(self, q_from: np.ndarray, q_to: np.ndarray) -> float:
        """The least clearance (links, boxes, table; m, capped at the horizon) along the
        straight joint-space move from `q_from` to `q_to`, sampled every `MOTION_STEP_RAD` of
        the joint that moves most."""
        q_from, q_to = np.asarray(q_from, float), np.asarray(q_to, float)
        steps = max(1, int(np.ceil(np.max(np.abs(q_to - q_from)) / MOTION_STEP_RAD)))
        least = float("inf")
        for t in np.linspace(0.0, 1.0, steps + 1):
            self.scene.set_joints(self.data, q_from + t * (q_to - q_from))
            least = min(least, self._table_clearance(), self._clearance(self._pairs),
                        self._clearance(self._box_pairs))
        return least

    def check(self, q: np.ndarray) -> PoseCheck:
        """All checks of joint vector `q` (J,), in order of cost; stops at the first failure."""
        f = self.feasibility
        P_base = self.robot.forward_kinematics(q)
        if not in_view(P_base[None], self.camera, self.T_cam_base, f.margin_px)[0]:
            return PoseCheck(False, "keypoint out of view")
        self.scene.set_joints(self.data, q)
        table = self._table_clearance()
        if table < f.clearance_m:
            return PoseCheck(False, "table", table_clearance_m=table)
        own = self._clearance(self._pairs)
        if own < f.clearance_m:
            return PoseCheck(False, "self-collision", own, table_clearance_m=table)
        boxes = self._clearance(self._box_pairs)
        if boxes < f.clearance_m:
            return PoseCheck(False, "keep-out box", own, boxes, table)
        P_cam = transform_points(self.T_cam_base, P_base)
        hits = keypoint_ray_hits(self.scene, self.data, P_cam, self.T_cam_base, self._groups,
                                 self._box_geoms)
        labels = keypoint_labels(self.robot, P_cam, self.camera, *hits,
                                 margin_m=f.occlusion_margin_m)
        if any(o != VISIBLE for o in labels.occlusion):
            return PoseCheck(False, "keypoint hidden", own, boxes, table)
        cut = self.cut_share()
        if cut > f.max_cut:
            return PoseCheck(False, "cut by the image border", own, boxes, table, cut)
        border = float(np.min(border_distance_px(labels.uv, self.camera)))
        return PoseCheck(True, None, own, boxes, table, cut, border)
