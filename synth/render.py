"""Rendering a `RobotScene` through a calibrated camera: RGB, geom/link ids and depth.

`SceneRenderer` owns one `mujoco.Renderer` (an OpenGL context: use it from the thread that
created it, and close it). Images follow the camera model of `dream.camera` exactly: pinhole
intrinsics with any fx, fy and principal point, plumb_bob distortion, pixel centres at integer
coordinates with (0, 0) the centre of the top-left pixel (see `synth.lens`). So a point
`P_base` appears at `dream.camera.project(camera, T_cam_base @ P_base)`.

Camera frame (OpenCV): x right, y down, z forward; MuJoCo's cameras look along -z with y up,
so the MuJoCo camera orientation is R_base_cam @ diag(1, -1, -1).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.transforms import invert_T, is_rigid
from synth.gl import mujoco
from synth.lens import RenderLens, plan_lens
from synth.scene import RobotScene
from synth.scene_settings import MAX_IMAGE_SIZE_PX
from synth.scene_spec import DISTRACTOR_GROUP, FLOOR_GROUP, MARKER_GROUP, ROBOT_GROUP

logger = logging.getLogger(__name__)

MUJOCO_TO_OPENCV = np.diag([1.0, -1.0, -1.0])  # camera axes: MuJoCo (y up, -z fwd) <-> OpenCV
NUM_GEOM_GROUPS = 6  # mjNGROUP
BACKGROUND_GEOM = -1
BACKGROUND_LINK = 0
ID_COLOUR_BITS = 8  # MuJoCo encodes segmentation ids as 24-bit RGB
RIGID_TOLERANCE = 1e-6


@dataclass(frozen=True)
class RenderSettings:
    """Renderer settings; the defaults favour speed for synthetic data. Metres, pixels.

    Attributes:
        offsamples: multisampling of the offscreen buffer (0: none; ids and depth need 0, or
            their edges blend).
        shadows, reflections, skybox: MuJoCo render flags.
        show_robot, show_floor, show_distractors, show_markers: which geom groups are drawn.
        near_m, far_m: clipping planes (depth range).
        distortion_margin_px: extra render pixels around a resampled field of view.
        max_render_scale: largest render buffer, in image sizes per axis.
        id_oversampling: when the image is resampled (fx != fy or distortion), ids and depth
            are rendered this many times finer per axis before the nearest-neighbour lookup.
        max_geoms: capacity of MuJoCo's scene.
    """

    offsamples: int = 0
    shadows: bool = False
    reflections: bool = False
    skybox: bool = False
    show_robot: bool = True
    show_floor: bool = True
    show_distractors: bool = True
    show_markers: bool = False
    near_m: float = 0.01
    far_m: float = 20.0
    distortion_margin_px: int = 2
    max_render_scale: float = 2.0
    id_oversampling: int = 2
    max_geoms: int = 10000

    def __post_init__(self) -> None:
        for name in ("offsamples", "distortion_margin_px", "max_geoms", "id_oversampling"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 0:
                raise InputError(f"RenderSettings.{name} = {value} must be a whole number >= 0")
            object.__setattr__(self, name, int(value))
        if not (0 < self.near_m < self.far_m) or not np.isfinite(self.far_m):
            raise InputError(f"clipping planes near_m={self.near_m}, far_m={self.far_m} must "
                             "satisfy 0 < near_m < far_m < inf")
        if not (self.max_render_scale >= 1.0):
            raise InputError(f"RenderSettings.max_render_scale = {self.max_render_scale} must "
                             "be at least 1")
        if self.max_geoms < 1 or self.id_oversampling < 1:
            raise InputError("RenderSettings.max_geoms and id_oversampling must be at least 1")

    def geom_groups(self) -> np.ndarray:
        """(6,) uint8 visibility of MuJoCo's geom groups."""
        groups = np.zeros(NUM_GEOM_GROUPS, dtype=np.uint8)
        for group, shown in ((ROBOT_GROUP, self.show_robot), (FLOOR_GROUP, self.show_floor),
                             (DISTRACTOR_GROUP, self.show_distractors),
                             (MARKER_GROUP, self.show_markers)):
            groups[group] = bool(shown)
        return groups


@dataclass(frozen=True, eq=False)
class RenderOutput:
    """One rendered view; each image is None when it was not asked for.

    Attributes:
        rgb: (H, W, 3) uint8.
        geom_ids: (H, W) int32 MuJoCo geom id, -1 for background.
        link_ids: (H, W) uint16 URDF link index + 1 (`RobotScene.link_names`), 0 for
            background and non-robot geoms.
        depth: (H, W) float32 distance along the optical axis (camera z), m; inf where no geom.
    """

    rgb: np.ndarray | None = None
    geom_ids: np.ndarray | None = None
    link_ids: np.ndarray | None = None
    depth: np.ndarray | None = None

    def __post_init__(self) -> None:
        shapes = {np.shape(a)[:2] for a in (self.rgb, self.geom_ids, self.link_ids, self.depth)
                  if a is not None}
        if len(shapes) > 1:
            raise InputError(f"render outputs disagree in size: {sorted(shapes)}")


def _check_pose(T_cam_base: np.ndarray) -> np.ndarray:
    T = np.asarray(T_cam_base, dtype=float)
    if T.shape != (4, 4) or not is_rigid(T, atol=RIGID_TOLERANCE):
        raise InputError(f"T_cam_base must be a rigid 4x4 transform, got shape {T.shape}",
                         fix="give a rotation with det +1 and last row [0, 0, 0, 1]")
    return T


class SceneRenderer:
    """Renders a `RobotScene` as seen by one camera.

    Usage:
        with SceneRenderer(scene, camera) as r:
            r.set_state(q, T_cam_base)
            out = r.render(rgb=True, segmentation=True, depth=True)

    The renderer sets a few fields of the shared `scene.model` when it opens (offscreen buffer
    size, multisampling, clipping planes); everything else a caller changes in the model
    (colours, lights, distractor poses, textures after `upload_texture`) shows in the next
    render.
    """

    def __init__(self, scene: RobotScene, camera: CameraIntrinsics,
                 options: RenderSettings | None = None) -> None:
        if not isinstance(scene, RobotScene):
            raise InputError("SceneRenderer needs a RobotScene (from synth.scene.build_scene)")
        if not isinstance(camera, CameraIntrinsics):
            raise InputError("SceneRenderer needs dream.camera.CameraIntrinsics")
        self._renderer: mujoco.Renderer | None = None
        self.scene = scene
        self.camera = camera
        self.options = RenderSettings() if options is None else options
        self._plan(camera)
        model = scene.model
        model.vis.quality.offsamples = self.options.offsamples
        extent = float(model.stat.extent)
        model.vis.map.znear = self.options.near_m / extent
        model.vis.map.zfar = self.options.far_m / extent
        self.data = mujoco.MjData(model)
        self._option = mujoco.MjvOption()
        self._option.geomgroup[:] = self.options.geom_groups()
        self._T_base_cam = np.eye(4)
        self._renderer = self._new_renderer()
        scene.set_joints(self.data, scene.robot.rest_joints)

    def _new_renderer(self) -> mujoco.Renderer:
        """An OpenGL renderer of the lens size, on the model's offscreen buffer."""
        try:
            return mujoco.Renderer(self.scene.model, self.lens.height, self.lens.width,
                                   max_geom=self.options.max_geoms)
        except mujoco.FatalError as e:
            width, height = self.model_buffer()
            raise InputError(f"MuJoCo cannot open an OpenGL context with a {width}x{height} "
                             f"offscreen buffer ({e})",
                             fix="set MUJOCO_GL=egl (or osmesa) before anything imports mujoco "
                                 "(e.g. import synth before mujoco), or render smaller images "
                                 f"(at most {MAX_IMAGE_SIZE_PX} px a side)") from e

    def _plan(self, camera: CameraIntrinsics) -> None:
        """Lenses of `camera`; grows the model's offscreen buffer to fit them."""
        opts = self.options
        self.camera = camera
        self.lens = plan_lens(camera, opts.distortion_margin_px, opts.max_render_scale)
        self.id_lens = plan_lens(camera, opts.distortion_margin_px, opts.max_render_scale,
                                 opts.id_oversampling)
        model = self.scene.model
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), self.lens.width,
                                         self.id_lens.width)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), self.lens.height,
                                          self.id_lens.height)

    def set_camera(self, camera: CameraIntrinsics) -> None:
        """Switch to other intrinsics (e.g. a random field of view per frame). Cheap when the
        render size stays the same (square-pixel pinholes of one resolution); otherwise the
        OpenGL renderer is reopened at the new size."""
        if not isinstance(camera, CameraIntrinsics):
            raise InputError("set_camera needs dream.camera.CameraIntrinsics")
        if camera == self.camera:
            return
        old = (self.lens.width, self.lens.height, self.model_buffer())
        self._plan(camera)
        if (self.lens.width, self.lens.height, self.model_buffer()) != old:
            self.close()
            self._renderer = self._new_renderer()

    def model_buffer(self) -> tuple[int, int]:
        g = self.scene.model.vis.global_
        return int(g.offwidth), int(g.offheight)

    # ----- lifetime ------------------------------------------------------------------------

    def close(self) -> None:
        """Free the OpenGL context (idempotent)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, exc_type, exc_value, traceback) -> None:
        self.close()

    def _open(self) -> mujoco.Renderer:
        if self._renderer is None:
            raise InputError("this SceneRenderer is closed", fix="create a new SceneRenderer")
        return self._renderer

    # ----- state ---------------------------------------------------------------------------

    def set_state(self, q: np.ndarray, T_cam_base: np.ndarray,
                  extra_joints: Mapping[str, float] | None = None) -> None:
        """Set the robot's joints and the camera pose.

        Args:
            q: (J,) values of `scene.robot.joint_names`, rad or m.
            T_cam_base: (4, 4) maps base-frame points into the OpenCV camera frame.
            extra_joints: values of `scene.extra_joint_names` (others at rest).
        """
        T = _check_pose(T_cam_base)
        self.scene.set_joints(self.data, q, extra_joints)
        self._T_base_cam = invert_T(T)

    def _update(self) -> None:
        """Kinematics (the caller may have moved bodies), camera pose, MuJoCo scene, flags."""
        model, data, renderer = self.scene.model, self.data, self._open()
        mujoco.mj_kinematics(model, data)
        mujoco.mj_camlight(model, data)
        cam = self.scene.camera_id
        data.cam_xpos[cam] = self._T_base_cam[:3, 3]
        data.cam_xmat[cam] = (self._T_base_cam[:3, :3] @ MUJOCO_TO_OPENCV).reshape(9)
        renderer.update_scene(data, camera=cam, scene_option=self._option)
        flags = renderer.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self.options.shadows
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = self.options.reflections
        flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = self.options.skybox

    # ----- rendering -----------------------------------------------------------------------

    def render(self, rgb: bool = True, segmentation: bool = True,
               depth: bool = False) -> RenderOutput:
        """Render the current state; only the asked-for images are computed.

        Returns:
            `RenderOutput` with images of the camera's size (H, W).
        """
        self._update()
        out_rgb = ids = links = out_depth = None
        if rgb:
            self._set_frustum(self.lens)
            out_rgb = self._resample_linear(self._open().render())
        if segmentation or depth:
            raw_ids, raw_depth = self._render_ids_depth(depth)
            ids = self._resample_nearest(raw_ids)
            if segmentation:
                lut = np.concatenate([[BACKGROUND_LINK], self.scene.geom_link_index])
                links = lut[ids + 1].astype(np.uint16)
            if depth:
                out_depth = self._resample_nearest(raw_depth)
                out_depth[ids == BACKGROUND_GEOM] = np.inf
            if not segmentation:
                ids = None
        return RenderOutput(rgb=out_rgb, geom_ids=ids, link_ids=links, depth=out_depth)

    def _set_frustum(self, lens: RenderLens) -> None:
        for gl_camera in self._open().scene.camera:
            center, bottom, top = lens.frustum(float(gl_camera.frustum_near))
            gl_camera.frustum_center = center
            gl_camera.frustum_bottom = bottom
            gl_camera.frustum_top = top

    def _render_ids_depth(self, want_depth: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """One segmentation pass through `id_lens`: geom ids (Hr, Wr) int32 and depth
        (Hr, Wr) float32 or None.

        Uses the `mujoco.Renderer`'s context directly so that ids and depth come from one
        pass (its `render()` reads one of them per pass) and at their own resolution.
        """
        renderer = self._open()
        gl_scene = renderer.scene
        self._set_frustum(self.id_lens)
        h, w = self.id_lens.height, self.id_lens.width
        colours = np.empty((h, w, 3), dtype=np.uint8)
        raw = np.empty((h, w), dtype=np.float32) if want_depth else None
        flags = gl_scene.flags
        saved = flags.copy()
        try:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
            gl_context = renderer._gl_context  # no public accessor
            mjr_context = renderer._mjr_context
            if gl_context is not None:
                gl_context.make_current()
            rect = mujoco.MjrRect(0, 0, w, h)
            mujoco.mjr_render(rect, gl_scene, mjr_context)
            mujoco.mjr_readPixels(colours, raw, rect, mjr_context)
        finally:
            np.copyto(flags, saved)
        colours = np.flipud(colours)  # OpenGL's first row is the bottom one
        segid = (colours[..., 0].astype(np.int64) | (colours[..., 1].astype(np.int64)
                 << ID_COLOUR_BITS) | (colours[..., 2].astype(np.int64) << 2 * ID_COLOUR_BITS))
        lut = np.full(gl_scene.ngeom + 2, BACKGROUND_GEOM, dtype=np.int32)
        for g in gl_scene.geoms[:gl_scene.ngeom]:
            if g.segid >= 0 and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lut[g.segid + 1] = g.objid
        ids = lut[np.clip(segid, 0, len(lut) - 1)]
        if raw is None:
            return ids, None
        near = float(gl_scene.camera[0].frustum_near)
        far = float(gl_scene.camera[0].frustum_far)
        # reversed-z depth buffer (MuJoCo's mjDEPTH_ZEROFAR): 1 at near, 0 at far
        metric = (far * near / ((far - near) * np.flipud(raw).astype(np.float64) + near))
        return ids, metric.astype(np.float32)

    def _resample_linear(self, image: np.ndarray) -> np.ndarray:
        if self.lens.direct:
            return image
        return cv2.remap(image, self.lens.map_u, self.lens.map_v, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)

    def _resample_nearest(self, image: np.ndarray) -> np.ndarray:
        if self.id_lens.direct:
            return image
        shape = (self.camera.height, self.camera.width) + image.shape[2:]
        flat = image.reshape((-1,) + image.shape[2:])
        return flat[self.id_lens.nearest_index].reshape(shape)

    # ----- textures ------------------------------------------------------------------------

    def upload_texture(self, texture_id: int) -> None:
        """Send texture `texture_id` to the GPU again after changing `model.tex_data`."""
        renderer = self._open()
        ntex = self.scene.model.ntex
        if isinstance(texture_id, bool) or int(texture_id) != texture_id or \
                not 0 <= texture_id < ntex:
            raise InputError(f"texture id {texture_id} is not in [0, {ntex})",
                             fix="use an id from scene.texture_ids or scene.floor_texture_id")
        gl_context = renderer._gl_context  # no public accessor
        if gl_context is not None:
            gl_context.make_current()
        mujoco.mjr_uploadTexture(self.scene.model, renderer._mjr_context, int(texture_id))
