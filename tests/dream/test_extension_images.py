"""A model extension in the image refinements: the silhouette polish renders the extension's
`link_geometry` (a tool the URDF lacks), and both refinements render the arm at the joints the
images show (timing effects, joint offsets) with the extension's link lengths."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import yaml

from dream.camera import project
from dream.cli import main
from dream.diagnosis.run import apply_extension_to_observations
from dream.errors import InputError
from dream.extension import HeldReadings, ModelExtension
from dream.io import read_sequence, write_dream
from dream.metrics import pose_errors
from dream.pipeline import observations_from_labels, with_robot_joints
from dream.polish import PolishSettings, polish
from dream.polish.calibration import polish_meshes
from dream.robot.link_geometry import BOX_KIND, EXCLUDE_KIND, LinkGeometry, with_link_geometry
from dream.sample import random_joints
from dream.sequence import Frame, Sequence
from dream.silhouette import render_silhouette
from dream.transforms import transform_points
from tests.dream.test_polish import CAMERA, camera_pose, keypoints_at, perturbed

PLATE = LinkGeometry("panda_hand", BOX_KIND, size_m=(0.30, 0.22, 0.01),
                     position_m=(0.0, 0.0, 0.14), rotation_rad=(0.0, 0.0, 0.3))
FRAMES = 6
START_M, START_RAD = 0.008, np.deg2rad(0.8)


def plate_scene(panda, meshes, seed: int):
    """Masks of an arm carrying `PLATE` at a true pose, and a start a few mm off."""
    rng = np.random.default_rng(seed)
    T_true = camera_pose(rng)
    joints = random_joints(rng, panda, FRAMES, 0.8)
    carrying = with_link_geometry(meshes, (PLATE,))
    masks = np.stack([render_silhouette(carrying, q, T_true, CAMERA) for q in joints])
    return T_true, joints, masks, perturbed(T_true, rng, START_M, START_RAD)


def test_polish_meshes_add_the_box_and_leave_out_excluded_links(panda, meshes):
    params = PolishSettings()
    boxed = polish_meshes(panda, params, (PLATE,))
    assert boxed.num_triangles == meshes.num_triangles + 12
    link7 = meshes.links.index("panda_link7")
    gone = polish_meshes(panda, params, (LinkGeometry("panda_link7", EXCLUDE_KIND),))
    assert not np.isin(gone.faces, np.flatnonzero(meshes.vertex_link == link7)).any()
    assert gone.num_triangles < meshes.num_triangles


@pytest.mark.parametrize("seed", [11, 12])
def test_the_polish_lands_closer_with_the_plate_described(panda, meshes, seed):
    """Masks that show a plate the URDF lacks: the nominal silhouette is pulled towards the
    plate; the one with the plate described finds the pose."""
    T_true, joints, masks, T0 = plate_scene(panda, meshes, seed)
    guard = keypoints_at(panda, joints, T_true)
    nominal = polish(meshes, joints, masks, CAMERA, T0, guard)
    described = polish(polish_meshes(panda, PolishSettings(), (PLATE,)), joints, masks, CAMERA,
                       T0, guard)
    t_nominal, _ = pose_errors(nominal.T_polished, T_true)
    t_described, _ = pose_errors(described.T_polished, T_true)
    assert described.kept and t_described < 0.002, described.reason
    assert t_described < t_nominal / 2, (t_nominal, t_described)


def plate_dataset(panda, meshes, folder, seed: int = 13) -> np.ndarray:
    """A DREAM folder of masks showing the plate and 1 px labels; returns the true pose."""
    T_true, joints, masks, _ = plate_scene(panda, meshes, seed)
    rng = np.random.default_rng(seed)
    uv = project(CAMERA, transform_points(T_true, panda.forward_kinematics(joints)))
    uv = uv + rng.normal(0.0, 1.0, uv.shape)
    (folder / "masks").mkdir(parents=True)
    frames = []
    for i, (q, mask) in enumerate(zip(joints, masks, strict=True)):
        path = folder / "masks" / f"{i}.png"
        cv2.imwrite(str(path), mask.astype(np.uint8))
        frames.append(Frame(name=f"{i:06d}", joints=q, mask_path=path, uv_labels=uv[i],
                            T_cam_base_true=T_true))
    write_dream(Sequence(robot="panda", camera=CAMERA, joint_names=panda.joint_names,
                         keypoint_names=panda.keypoint_names, frames=tuple(frames),
                         T_cam_base_reference=T_true), folder / "data")
    return T_true


def test_calibrate_polish_uses_the_model_extension(panda, meshes, tmp_path, capsys):
    T_true = plate_dataset(panda, meshes, tmp_path)
    path = tmp_path / "extended_model.yaml"
    path.write_text(yaml.safe_dump({"format": "dream-model-extension", "version": 1,
                                    "effects": {"link_geometry": {
                                        "panda_hand": PLATE.to_params()}}}))
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--polish",
                 "--model-extension", str(path), "--out", str(tmp_path / "r.json")])
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "model extension" in printed and "silhouette polish" in printed
    assert "neither runs here" not in printed
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["model_extension"]["effects"]["link_geometry"]["panda_hand"]["kind"] == BOX_KIND
    assert pose_errors(np.array(doc["T_cam_base"]), T_true)[0] < 0.003


def test_the_refinements_see_the_joints_the_images_show(panda, meshes, tmp_path):
    plate_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    obs = observations_from_labels(seq, panda)
    offset = {"panda_joint4": 0.02}
    out, _ = apply_extension_to_observations(seq, panda, obs,
                                             ModelExtension(joint_offset_rad=offset))
    moved = seq.joints.copy()
    moved[:, list(seq.joint_names).index("panda_joint4")] += 0.02
    np.testing.assert_allclose(out.joints, moved)
    with pytest.raises(InputError, match="timestamps"):
        apply_extension_to_observations(seq, panda, obs,
                                        ModelExtension(held_readings=HeldReadings(0.2)))


def test_with_robot_joints_keeps_the_other_joints_and_checks_the_shape(panda, tmp_path):
    names = (*panda.joint_names, "panda_finger_joint1")
    q = random_joints(np.random.default_rng(0), panda, 2, 0.5)
    frames = tuple(Frame(name=str(i), joints=np.append(row, 0.04)) for i, row in enumerate(q))
    seq = Sequence(robot="panda", camera=CAMERA, joint_names=names,
                   keypoint_names=panda.keypoint_names, frames=frames)
    out = with_robot_joints(seq, panda, q + 0.1)
    np.testing.assert_allclose(out.joints[:, :-1], q + 0.1)
    np.testing.assert_allclose(out.joints[:, -1], 0.04)
    with pytest.raises(InputError, match="shape"):
        with_robot_joints(seq, panda, q[:1])
