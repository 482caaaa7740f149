"""`benchmarks/coarse_start.py`'s scenes of arms that are not built in: a URDF from
example-robot-data rendered with its suggested keypoints, and the randomisation scaled to the
robot's size."""

from __future__ import annotations

import numpy as np
import pytest

from dream.io import read_sequence
from dream.robot import robot_data_dir
from tests.benchmark_scripts import load_benchmark

SO101 = "robots/so_arm_description/urdf/so101.urdf"     # a small arm (about 0.4 of a Panda)
TIAGO_DUAL = "robots/tiago_description/robots/tiago_dual.urdf"      # two arms on a torso
TIAGO = "robots/tiago_description/robots/tiago.urdf"     # an arm above a prismatic torso lift


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("coarse_start")


def test_the_reference_robot_keeps_the_randomisation_and_others_scale(bench):
    assert bench.robot_keypoints("panda") is None and bench.robot_keypoints("ur5") is None
    assert bench.randomisation("panda", True) == bench.randomisation("panda", False)
    assert bench.randomisation("ur5", True) != bench.randomisation("ur5", False)


def test_a_small_arms_scenes_are_seen_from_nearer(bench):
    so101 = str(robot_data_dir() / SO101)
    assert bench.robot_keypoints(so101)
    factor = bench.robot_size(so101) / bench.robot_size("panda")
    assert 0.3 < factor < 0.5
    as_written = bench.randomisation(so101, False).to_dict()
    scaled = bench.randomisation(so101, True).to_dict()
    for section, key in bench.SCALED_KEYS:
        np.testing.assert_allclose(scaled[section][key],
                                   np.asarray(as_written[section][key]) * factor)
    assert scaled["intrinsics"] == as_written["intrinsics"]


def test_a_two_armed_robots_scenes_move_both_arms(bench):
    from dream.robot import load_robot

    tiago_dual = str(robot_data_dir() / TIAGO_DUAL)
    keypoints = bench.robot_keypoints(tiago_dual)
    assert keypoints[0] == "base_footprint" and len(set(keypoints)) == len(keypoints)
    moved = load_robot(tiago_dual, keypoints).joint_names
    for side in ("left", "right"):
        assert {f"arm_{side}_{k}_joint" for k in range(1, 8)} <= set(moved)


def test_a_urdf_scene_renders_without_masks_and_takes_marks(bench, tmp_path):
    keypoints = bench.robot_keypoints(str(robot_data_dir() / SO101))
    data = bench.render_scene(str(robot_data_dir() / SO101), tmp_path / "so101", 7, 2, True)
    sequence = read_sequence(data)
    assert len(sequence) == 2 and not list(data.glob("*.seg.png"))
    assert sequence.frames[0].uv_labels.shape[0] == len(keypoints)
    T_true = sequence.frames[0].T_cam_base_true
    marks, link = bench.mark_file(data, T_true, 5, 0.0, np.random.default_rng(0), tmp_path)
    assert link == keypoints[-1] and marks.read_text().startswith("frame,u,v\n")


def test_randomisation_overrides_apply_before_the_scaling(bench):
    so101 = str(robot_data_dir() / SO101)
    config = bench.randomisation(so101, True, ("intrinsics.width=960", "camera.radius_m=[1, 2]"))
    assert config.intrinsics.width == 960
    factor = bench.robot_size(so101) / bench.robot_size("panda")
    np.testing.assert_allclose(config.camera.radius_m, np.array([1.0, 2.0]) * factor)


def test_a_scene_given_the_wrong_focal_length_and_a_rendered_scene_reused(bench, tmp_path):
    """`--given-focal`: a copy whose fx, fy are scaled, the truth and images as rendered;
    `--reuse-scenes`: a scene already rendered with the same settings is taken as it is, not
    rendered again; one whose rendering stopped part way, or rendered with another seed,
    length, override or lag, is rendered again."""
    from dream.extension import ModelExtension

    data = bench.render_scene(str(robot_data_dir() / SO101), tmp_path / "so101", 7, 2, True)
    stamp = (data / "_synth.json").stat().st_mtime_ns
    again = bench.render_scene(str(robot_data_dir() / SO101), tmp_path / "so101", 7, 2, True,
                               reuse=True)
    assert again == data and (data / "_synth.json").stat().st_mtime_ns == stamp
    so101 = str(robot_data_dir() / SO101)
    assert bench.rendered_for(bench.scene_job(so101, data, 7, 2, True))
    for other in (bench.scene_job(so101, data, 7, 3, True),         # another length
                  bench.scene_job(so101, data, 8, 2, True),         # another seed
                  bench.scene_job(so101, data, 7, 2, True, ("sequence.mode=trajectory",)),
                  bench.scene_job(so101, data, 7, 2, True,
                                  extension=ModelExtension(time_offset_s=0.05))):
        assert not bench.rendered_for(other)                       # rendered anew
    (data / "000001.json").unlink()                       # a rendering stopped part way
    assert not bench.rendered_for(bench.scene_job(so101, data, 7, 2, True))
    bench.render_scene(so101, tmp_path / "so101", 7, 2, True, reuse=True)
    assert (data / "000001.json").is_file()
    given = read_sequence(bench.given_focal(data, 0.96, tmp_path / "short"))
    rendered = read_sequence(data)
    assert given.camera.fx == pytest.approx(0.96 * rendered.camera.fx)
    assert given.camera.fy == pytest.approx(0.96 * rendered.camera.fy)
    assert (given.camera.cx, given.camera.cy) == (rendered.camera.cx, rendered.camera.cy)
    np.testing.assert_allclose(given.frames[0].T_cam_base_true,
                               rendered.frames[0].T_cam_base_true, atol=1e-12)


def test_a_scene_through_a_video_codec_keeps_its_frames_and_truth(bench, tmp_path):
    """`--video-codec`: a copy whose images went through the codec and back: as many frames,
    the same size, a few levels off the rendered pixels, the truth as rendered."""
    import cv2

    data = bench.render_scene("panda", tmp_path / "panda", 7, 3)
    rendered = read_sequence(data)
    for codec in sorted(bench.VIDEO_CODECS):
        coded = read_sequence(bench.video_coded(data, codec, tmp_path / codec))
        assert len(coded) == len(rendered)
        for before, after in zip(rendered.frames, coded.frames, strict=True):
            a = cv2.imread(str(before.image_path)).astype(int)
            b = cv2.imread(str(after.image_path)).astype(int)
            assert a.shape == b.shape and 0 < np.abs(a - b).mean() < 10
            np.testing.assert_allclose(after.T_cam_base_true, before.T_cam_base_true)


def test_a_scene_given_joint_offsets_reads_every_joint_but_the_first_off(bench, tmp_path):
    """`--joint-offsets-deg`: a copy whose readings of each revolute joint beyond the first
    lie a constant off the rendered ones, the same for a scene's seed; the first revolute one
    and the prismatic ones (TIAGo's torso lift) as rendered, the truth as rendered."""
    from dream.robot import load_robot
    from dream.robot.tree import PRISMATIC

    data = bench.render_scene(str(robot_data_dir() / TIAGO), tmp_path / "tiago", 7, 2, True)
    rendered = read_sequence(data)
    given, offsets = bench.given_joint_offsets(data, np.deg2rad(0.3), 7, tmp_path / "off")
    same = bench.given_joint_offsets(data, np.deg2rad(0.3), 7, tmp_path / "again")[1]
    other = bench.given_joint_offsets(data, np.deg2rad(0.3), 8, tmp_path / "other")[1]
    moved = read_sequence(given)
    np.testing.assert_allclose(moved.joints - rendered.joints,
                               np.broadcast_to(offsets, rendered.joints.shape), atol=1e-9)
    np.testing.assert_array_equal(offsets, same)
    assert not np.allclose(offsets, other)
    tree = load_robot(rendered.robot, rendered.keypoint_names).tree
    kinds = [tree.joints[tree.joint_index[n]].type for n in rendered.joint_names]
    assert kinds[:2] == [PRISMATIC, "revolute"] and offsets[0] == offsets[1] == 0.0
    assert np.all(offsets[2:] != 0.0) and np.all(np.abs(offsets) < np.deg2rad(2.0))
    np.testing.assert_allclose(moved.frames[1].T_cam_base_true,
                               rendered.frames[1].T_cam_base_true, atol=1e-12)


def test_marks_are_where_the_images_show_the_end_effector_also_with_a_late_log(bench,
                                                                                tmp_path):
    """`--mark-frames` with `--time-offset`: the marks are the end effector's labels (where the
    images show it), not its projection from the late readings."""
    from dream.camera import project
    from dream.pipeline import joints_in_robot_order, robot_for
    from dream.transforms import transform_points

    so101 = str(robot_data_dir() / SO101)
    data = bench.render_scene(so101, tmp_path / "late", 7, 4, True, ("sequence.mode=trajectory",),
                              time_offset_s=0.05)
    seq = read_sequence(data)
    T_true = seq.frames[0].T_cam_base_true
    marks, link = bench.mark_file(data, T_true, 4, 0.0, np.random.default_rng(0), tmp_path)
    rows = [line.split(",") for line in marks.read_text().splitlines()[1:]]
    index = [[f.name for f in seq.frames].index(name) for name, _, _ in rows]
    clicked = np.array([[float(u), float(v)] for _, u, v in rows])
    labels = seq.uv_labels()[index, seq.keypoint_names.index(link)]
    np.testing.assert_allclose(clicked, labels, atol=0.01)
    robot = robot_for(seq, None, tuple(seq.keypoint_names))
    P = robot.link_poses(joints_in_robot_order(seq, robot), (link,))[index, 0, :3, 3]
    late = project(seq.camera, transform_points(T_true, P))
    assert np.abs(late - labels).max() > 0.05       # the readings do lag the images
