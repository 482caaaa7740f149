"""MuJoCo scenes of URDF robots and their renders: frames, labels vs pixels, depth, cache."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from dream.camera import CameraIntrinsics, project
from dream.errors import InputError, RobotError
from dream.robot import load_robot
from dream.transforms import look_at, transform_points
from synth import scene as scene_module
from synth.gl import mujoco
from synth.render import RenderSettings, SceneRenderer
from synth.scene import SceneSettings, build_scene
from synth.scene_cache import MODEL_FILE
from synth.scene_settings import GL_MIN_RENDERBUFFER_PX, MAX_IMAGE_SIZE_PX

FRAME_TOLERANCE = 1e-9  # m and rotation-matrix entries
CENTROID_TOLERANCE_PX = 0.5
DEPTH_TOLERANCE_M = 1e-4  # seen: 3e-6 m at 1.6 m
MIN_MARKER_PIXELS = 12
MARKER_RADIUS_M = 0.012  # about 2.5 px radius at 1.5 m with f = 320 px
MARKER_SEPARATION_PX = 3.0  # markers closer than their radii plus this may occlude each other
IMAGE_MARGIN_PX = 2.0
CAMERA_DISTANCE_M = 1.5
ROBOT_CENTRE = np.array([0.0, 0.0, 0.4])
DISTORTION = (0.1, -0.05, 0.001, -0.001, 0.0)
CAMERAS = {
    "square": CameraIntrinsics(320.0, 320.0, 160.0, 120.0, 320, 240),
    "fx_ne_fy_off_centre": CameraIntrinsics(335.0, 310.0, 171.3, 112.6, 320, 240),
    "distorted": CameraIntrinsics(335.0, 310.0, 171.3, 112.6, 320, 240, DISTORTION),
}


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("scene_cache")


@pytest.fixture(scope="module")
def panda_markers(cache_dir):
    robot = load_robot("panda")
    return build_scene(robot, SceneSettings(keypoint_markers=True, marker_radius_m=MARKER_RADIUS_M,
                                            floor=True, num_distractors=1, num_textures=1),
                       cache_dir=cache_dir)


def _camera_pose(rng: np.random.Generator) -> np.ndarray:
    azimuth = rng.uniform(0, 2 * np.pi)
    elevation = rng.uniform(0.1, 0.6)
    position = ROBOT_CENTRE + CAMERA_DISTANCE_M * np.array([
        np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation),
        np.sin(elevation)])
    return look_at(position, ROBOT_CENTRE, rng.uniform(-0.3, 0.3))


@pytest.mark.parametrize("name", ["panda", "ur5", "xarm7"])
def test_link_frames_match_robot_kinematics(name, cache_dir, rng):
    robot = load_robot(name)
    scene = build_scene(robot, cache_dir=cache_dir)
    data = mujoco.MjData(scene.model)
    links = [k for k, b in zip(scene.link_names, scene.link_body_ids, strict=True) if b >= 0]
    assert robot.base_link in links and set(robot.keypoint_names) <= set(links)
    for _ in range(5):
        q = robot.sample_joints(rng)
        scene.set_joints(data, q)
        expected = robot.link_poses(q, links)
        for i, link in enumerate(links):
            np.testing.assert_allclose(scene.body_pose(data, link), expected[i],
                                       atol=FRAME_TOLERANCE, rtol=0)


def test_mimic_and_extra_joints(cache_dir):
    robot = load_robot("panda")
    scene = build_scene(robot, cache_dir=cache_dir)
    assert scene.extra_joint_names == ("panda_finger_joint1",)
    qpos = scene.joint_values(robot.rest_joints, {"panda_finger_joint1": 0.03})
    adr = {mujoco.mj_id2name(scene.model, mujoco.mjtObj.mjOBJ_JOINT, j): scene.model.jnt_qposadr[j]
           for j in range(scene.model.njnt)}
    assert qpos[adr["joint:panda_finger_joint1"]] == pytest.approx(0.03)
    assert qpos[adr["joint:panda_finger_joint2"]] == pytest.approx(0.03)  # mimic
    with pytest.raises(RobotError, match="extra joint"):
        scene.joint_values(robot.rest_joints, {"panda_joint1": 0.1})
    with pytest.raises(RobotError):
        scene.joint_values(np.zeros(3))


def _marker_errors(scene, camera: CameraIntrinsics, rng: np.random.Generator,
                   poses: int) -> list[float]:
    robot = scene.robot
    errors: list[float] = []
    options = RenderSettings(show_robot=False, show_floor=False, show_markers=True)
    with SceneRenderer(scene, camera, options) as renderer:
        for _ in range(poses):
            q = robot.sample_joints(rng)
            T_cam_base = _camera_pose(rng)
            renderer.set_state(q, T_cam_base)
            out = renderer.render(rgb=False, segmentation=True)
            P_cam = transform_points(T_cam_base, robot.forward_kinematics(q))
            uv = project(camera, P_cam)
            radius_px = camera.fx * MARKER_RADIUS_M / P_cam[:, 2]
            for k, geom in enumerate(scene.marker_geom_ids):
                others = np.delete(np.arange(len(uv)), k)
                gap = np.linalg.norm(uv[others] - uv[k], axis=1) - radius_px[others]
                if np.any(gap < radius_px[k] + MARKER_SEPARATION_PX):
                    continue  # may be occluded by another marker
                if not camera.in_image(uv[k], -radius_px[k] - IMAGE_MARGIN_PX):
                    continue
                v, u = np.nonzero(out.geom_ids == geom)
                if len(u) < MIN_MARKER_PIXELS:
                    continue
                errors.append(float(np.hypot(u.mean() - uv[k, 0], v.mean() - uv[k, 1])))
    return errors


@pytest.mark.parametrize("camera_name", list(CAMERAS))
def test_marker_pixels_centre_on_projected_keypoints(panda_markers, camera_name):
    camera = CAMERAS[camera_name]
    rng = np.random.default_rng(7)
    errors = _marker_errors(panda_markers, camera, rng, poses=6)
    assert len(errors) >= 15, f"only {len(errors)} markers checked"
    assert max(errors) < CENTROID_TOLERANCE_PX, (camera_name, max(errors))


def test_render_is_deterministic_and_shows_the_robot(panda_markers, rng):
    scene = panda_markers
    robot = scene.robot
    camera = CAMERAS["fx_ne_fy_off_centre"]
    q = robot.sample_joints(rng) * 0.5
    T_cam_base = look_at(np.array([1.2, 0.6, 0.8]), ROBOT_CENTRE)
    with SceneRenderer(scene, camera, RenderSettings(show_floor=False)) as renderer:
        renderer.set_state(q, T_cam_base)
        first = renderer.render(rgb=True, segmentation=True, depth=True)
        second = renderer.render(rgb=True, segmentation=True, depth=True)
    for a, b in ((first.rgb, second.rgb), (first.geom_ids, second.geom_ids),
                 (first.link_ids, second.link_ids), (first.depth, second.depth)):
        np.testing.assert_array_equal(a, b)
    assert first.rgb.shape == (240, 320, 3) and first.rgb.dtype == np.uint8
    assert first.geom_ids.dtype == np.int32 and first.link_ids.dtype == np.uint16
    assert first.depth.dtype == np.float32
    robot_pixels = first.link_ids > 0
    assert robot_pixels.sum() > 1000
    grey = first.rgb[robot_pixels].astype(float).mean(axis=1)
    assert np.percentile(grey, 95) > 150 and np.percentile(grey, 5) < 60  # white and black parts
    labels = set(np.unique(first.link_ids[robot_pixels]))
    assert labels <= {scene.link_names.index(k) + 1 for k in robot.link_names}
    assert len(labels) >= 5
    background = first.geom_ids == -1
    assert np.all(first.link_ids[background] == 0) and np.all(np.isinf(first.depth[background]))
    assert np.all(np.isfinite(first.depth[~background]))


@pytest.mark.parametrize("camera_name", ["square", "distorted"])
def test_depth_at_base_origin_on_the_floor(panda_markers, camera_name):
    scene = panda_markers
    camera = CAMERAS[camera_name]
    T_cam_base = look_at(np.array([1.3, -0.4, 0.9]), np.array([0.0, 0.0, 0.0]), 0.2)
    options = RenderSettings(show_robot=False, show_distractors=False)
    with SceneRenderer(scene, camera, options) as renderer:
        renderer.set_state(scene.robot.rest_joints, T_cam_base)
        out = renderer.render(rgb=False, segmentation=True, depth=True)
    assert np.all(out.geom_ids[np.isfinite(out.depth)] == scene.floor_geom_id)
    u, v = project(camera, T_cam_base[:3, 3])
    u0, v0 = int(np.floor(u)), int(np.floor(v))
    a, b = u - u0, v - v0
    inverse = 1.0 / out.depth[v0:v0 + 2, u0:u0 + 2].astype(float)  # 1/z is affine on a plane
    interpolated = ((1 - b) * ((1 - a) * inverse[0, 0] + a * inverse[0, 1])
                    + b * ((1 - a) * inverse[1, 0] + a * inverse[1, 1]))
    assert 1.0 / interpolated == pytest.approx(T_cam_base[2, 3], abs=DEPTH_TOLERANCE_M)


def test_randomisation_handles(panda_markers, rng):
    scene = panda_markers
    model = scene.model
    assert len(scene.light_ids) == 4 and np.all(model.light_castshadow[scene.light_ids] == 0)
    assert len(scene.default_geom_rgba) == model.ngeom
    assert np.all(scene.geom_link_index[scene.robot_geom_ids] > 0)
    assert np.all(scene.geom_link_index[scene.marker_geom_ids] == 0)
    body, geom = scene.distractor_body_ids[0], scene.distractor_geom_ids[0]
    texture, material = scene.texture_ids[0], scene.material_ids[0]
    camera = CAMERAS["square"]
    T_cam_base = look_at(np.array([1.2, 0.0, 0.6]), ROBOT_CENTRE)
    with SceneRenderer(scene, camera, RenderSettings(show_robot=False)) as renderer:
        renderer.set_state(scene.robot.rest_joints, T_cam_base)
        model.body_pos[body] = [0.6, 0.0, 0.5]
        model.geom_matid[geom] = material
        model.geom_rgba[geom] = [1.0, 1.0, 1.0, 1.0]
        start = model.tex_adr[texture]
        size = model.tex_width[texture] * model.tex_height[texture] * model.tex_nchannel[texture]
        saved = model.tex_data[start:start + size].copy()
        try:
            model.tex_data[start:start + size] = np.tile([255, 0, 0], size // 3)
            renderer.upload_texture(int(texture))
            out = renderer.render(rgb=True, segmentation=True)
        finally:
            model.tex_data[start:start + size] = saved
            model.body_pos[body] = [0.0, 0.0, scene.options.distractor_parking_z_m]
            model.geom_matid[geom] = -1
            model.geom_rgba[geom] = scene.default_geom_rgba[geom]
            renderer.upload_texture(int(texture))
        with pytest.raises(InputError):
            renderer.upload_texture(model.ntex)
    box = out.geom_ids == geom
    assert box.sum() > 100
    colour = out.rgb[box].astype(float).mean(axis=0)
    assert colour[0] > 50 and colour[1] < 5 and colour[2] < 5


def test_invalid_inputs(panda_markers):
    with pytest.raises(InputError):
        SceneSettings(num_lights=-1)
    with pytest.raises(InputError):
        RenderSettings(near_m=1.0, far_m=0.5)
    with SceneRenderer(panda_markers, CAMERAS["square"]) as renderer:
        with pytest.raises(InputError, match="rigid"):
            renderer.set_state(panda_markers.robot.rest_joints, np.eye(4) * 2)
        with pytest.raises(RobotError):
            renderer.set_state(np.zeros(2), np.eye(4))
    with pytest.raises(InputError, match="closed"):
        renderer.render()


def test_largest_recipe_image_renders_even_when_resampled(cache_dir):
    """A recipe's image is at most MAX_IMAGE_SIZE_PX a side: a camera that wide with pixels far
    from square renders its ids into a buffer near 4 times its width, still within OpenGL's
    renderbuffer limit (16384 on Mesa's llvmpipe). A buffer past every OpenGL's limit is an
    InputError that says its size and the fix."""
    options = RenderSettings()
    assert MAX_IMAGE_SIZE_PX * options.max_render_scale * options.id_oversampling <= \
        GL_MIN_RENDERBUFFER_PX
    scene = build_scene(load_robot("panda"), SceneSettings(), cache_dir=cache_dir)
    camera = CameraIntrinsics(1000.0, 1990.0, MAX_IMAGE_SIZE_PX / 2, 16.0, MAX_IMAGE_SIZE_PX, 32)
    with SceneRenderer(scene, camera) as renderer:
        assert renderer.id_lens.width > 0.99 * GL_MIN_RENDERBUFFER_PX
        renderer.set_state(scene.robot.rest_joints, _camera_pose(np.random.default_rng(0)))
        out = renderer.render(rgb=True, segmentation=True)
    assert out.rgb.shape == (32, MAX_IMAGE_SIZE_PX, 3) and out.link_ids.max() > 0
    huge = CameraIntrinsics(300.0, 300.0, 20000.0, 16.0, 40000, 32)
    with pytest.raises(InputError, match=r"40000x\d+ offscreen buffer.*render smaller images"):
        SceneRenderer(scene, huge)


def _write_user_robot(folder: Path) -> Path:
    import trimesh

    trimesh.creation.box(extents=(0.08, 0.08, 0.3)).export(folder / "arm.stl")
    urdf = folder / "tiny.urdf"
    urdf.write_text("""<?xml version="1.0"?>
<robot name="tiny">
  <material name="blue"><color rgba="0.1 0.2 0.9 1"/></material>
  <link name="base">
    <visual><origin xyz="0 0 0.05" rpy="0 0 0"/><geometry><box size="0.2 0.2 0.1"/></geometry>
      <material name="grey"><color rgba="0.5 0.5 0.5 1"/></material></visual>
  </link>
  <link name="arm">
    <visual><origin xyz="0 0 0.15" rpy="0 0 0"/>
      <geometry><mesh filename="arm.stl" scale="1 1 1"/></geometry>
      <material name="blue"/></visual>
  </link>
  <link name="tip"/>
  <joint name="j1" type="revolute">
    <origin xyz="0 0 0.1" rpy="0 0 0.3"/><parent link="base"/><child link="arm"/>
    <axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/>
  </joint>
  <joint name="tip_joint" type="fixed">
    <origin xyz="0 0 0.3" rpy="0 0 0"/><parent link="arm"/><child link="tip"/>
  </joint>
</robot>
""")
    return urdf


def test_user_urdf_with_box_and_stl(tmp_path, cache_dir):
    robot = load_robot(_write_user_robot(tmp_path), keypoints=["base", "tip"])
    scene = build_scene(robot, SceneSettings(keypoint_markers=True), cache_dir=cache_dir)
    q = np.array([0.4])
    data = mujoco.MjData(scene.model)
    scene.set_joints(data, q)
    np.testing.assert_allclose(scene.body_pose(data, "tip"), robot.link_poses(q, "tip")[0],
                               atol=FRAME_TOLERANCE, rtol=0)
    arm_geoms = scene.robot_geom_ids[scene.geom_link_index[scene.robot_geom_ids]
                                     == scene.link_names.index("arm") + 1]
    np.testing.assert_allclose(scene.model.geom_rgba[arm_geoms[0]], [0.1, 0.2, 0.9, 1.0],
                               atol=1e-6)
    camera = CAMERAS["square"]
    with SceneRenderer(scene, camera) as renderer:
        renderer.set_state(q, look_at(np.array([0.8, -0.6, 0.5]), np.array([0, 0, 0.2])))
        out = renderer.render(rgb=True, segmentation=True)
    labels = set(np.unique(out.link_ids)) - {0}
    assert labels == {scene.link_names.index("base") + 1, scene.link_names.index("arm") + 1}


def test_second_build_uses_the_cache(tmp_path, monkeypatch):
    robot = load_robot("panda")
    options = SceneSettings(num_lights=2)
    start = time.perf_counter()
    first = build_scene(robot, options, cache_dir=tmp_path)
    first_s = time.perf_counter() - start

    def no_build(*args, **kwargs):
        raise AssertionError("the scene was built again instead of read from the cache")

    monkeypatch.setattr(scene_module, "build_spec", no_build)
    start = time.perf_counter()
    second = build_scene(robot, options, cache_dir=tmp_path)
    cached_s = time.perf_counter() - start
    assert second.model is not first.model
    np.testing.assert_array_equal(second.geom_link_index, first.geom_link_index)
    assert cached_s < max(0.5, first_s)
    monkeypatch.undo()
    (model_file,) = tmp_path.glob(f"*/{MODEL_FILE}")
    model_file.write_bytes(b"not a model")  # a corrupt entry is rebuilt, not fatal
    third = build_scene(robot, options, cache_dir=tmp_path)
    assert third.model.ngeom == first.model.ngeom
    assert model_file.stat().st_size > 1000
