"""Edge alignment (`dream.edges`): the edge search, the background cue, the coarse-to-fine
alignment on images made from the project's own silhouettes over a cluttered scene, the keep
rule, and `dream calibrate --refine edges` end to end.

The images are the robot's silhouette (`render_silhouette`) painted over a background of random
grey blocks, so the alignment must find the rendering pose back against clutter; MuJoCo renders
are measured by `benchmarks/edge_align.py`.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from dream.camera import CameraIntrinsics, project
from dream.cli import main
from dream.edges import EdgeSettings, refine_with_edges
from dream.edges.background import background_model
from dream.edges.calibration import decide_edges, usable_vertices
from dream.edges.refine import align_edges
from dream.edges.score import EdgeScore
from dream.edges.search import match_edges, scale_images
from dream.errors import InputError
from dream.io import write_dream
from dream.metrics import pose_errors
from dream.sample import random_joints
from dream.sequence import Frame, Sequence
from dream.silhouette import render_silhouette, vertices_in_base
from dream.transforms import T_from_rotvec_t, look_at, transform_points

WIDTH, HEIGHT = 320, 240
CAMERA = CameraIntrinsics(250.0, 250.0, (WIDTH - 1) / 2, (HEIGHT - 1) / 2, WIDTH, HEIGHT)
TARGET = np.array([0.0, 0.0, 0.4])     # the camera aims at this point of the base frame, m
ROBOT_GREY, BLOCKS = 0.85, 60          # the robot's grey level; clutter blocks in the scene
START_OFFSET_M, START_TURN_RAD = 0.04, np.deg2rad(3.0)   # a keypoint start's error
NUM_FRAMES = 10


def cluttered_background(rng: np.random.Generator) -> np.ndarray:
    """(H, W) grey levels: random blocks of random grey, edges everywhere."""
    image = np.full((HEIGHT, WIDTH), 0.4, np.float32)
    for _ in range(BLOCKS):
        x, y = rng.integers(0, WIDTH), rng.integers(0, HEIGHT)
        w, h = rng.integers(5, 60, size=2)
        image[y:y + h, x:x + w] = rng.uniform(0.0, 0.7)
    return image


def edge_scene(panda, meshes, seed: int = 0, frames: int = NUM_FRAMES):
    """(T_true, joints (F, J), grey images (F, H, W), background (H, W))."""
    rng = np.random.default_rng(seed)
    T_true = look_at(TARGET + np.array([1.3, 0.5, 0.6]), TARGET)
    joints = random_joints(rng, panda, frames, 0.8)
    background = cluttered_background(rng)
    images = np.stack([np.where(render_silhouette(meshes, q, T_true, CAMERA), ROBOT_GREY,
                                background) for q in joints]).astype(np.float32)
    return T_true, joints, images, background


def moved(T: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    out = T_from_rotvec_t(axis / np.linalg.norm(axis) * START_TURN_RAD, np.zeros(3)) @ T
    shift = rng.normal(size=3)
    out[:3, 3] += shift / np.linalg.norm(shift) * START_OFFSET_M
    return out


def test_edge_search_finds_a_step_to_a_fraction_of_a_pixel():
    for edge_x in (10.0, 10.3, 10.7):
        xs = np.arange(40) - edge_x
        gray = np.tile(np.clip(xs + 0.5, 0.0, 1.0), (30, 1)).astype(np.float32)  # area model
        camera = CameraIntrinsics(40.0, 40.0, 19.5, 14.5, 40, 30)
        images = scale_images(gray[None], camera, 40, EdgeSettings())
        origin, normal = np.array([[7.0, 15.0]]), np.array([[1.0, 0.0]])
        d, found = match_edges(images, np.zeros(1, int), origin, normal, EdgeSettings())
        assert found[0]
        assert abs(origin[0, 0] + d[0] - edge_x) < 0.1


def test_background_cue_passes_over_the_scenes_own_edges():
    """An edge with the background on both sides (the scene's own) is passed over; one with
    the background only outside (the robot's outline) is found."""
    camera = CameraIntrinsics(40.0, 40.0, 19.5, 14.5, 40, 30)
    background = np.zeros((30, 40), np.float32)
    background[:, 12:] = 0.5                      # a scene edge at x = 11.5
    frame = background.copy()
    frame[:, :8] = 1.0                            # the robot, up to x = 7.5
    images = scale_images(frame[None], camera, 40, EdgeSettings(), background)
    origin, normal = np.array([[9.5, 15.0]]), np.array([[1.0, 0.0]])   # outline facing +x
    d, found = match_edges(images, np.zeros(1, int), origin, normal, EdgeSettings())
    assert found[0] and abs(origin[0, 0] + d[0] - 7.5) < 0.1
    bare = scale_images(frame[None], camera, 40, EdgeSettings())
    d, _ = match_edges(bare, np.zeros(1, int), np.array([[11.0, 15.0]]), normal,
                       EdgeSettings())
    assert abs(11.0 + d[0] - 11.5) < 0.1          # without the cue the nearest edge wins


@pytest.mark.parametrize("with_background", [True, False])
def test_alignment_finds_the_rendering_pose_in_clutter(panda, meshes, with_background):
    T_true, joints, images, background = edge_scene(panda, meshes)
    P = vertices_in_base(meshes, joints)
    T0 = moved(T_true, np.random.default_rng(1))
    T, trace = align_edges(P, meshes.faces, images, CAMERA, T0, EdgeSettings(),
                           background if with_background else None)
    t, r = pose_errors(T, T_true)
    assert t < 0.002 and r < np.deg2rad(0.1), (t, np.rad2deg(r), trace)


def test_background_model_is_the_median_and_needs_frames():
    frames = np.random.default_rng(0).uniform(size=(9, 5, 6))
    assert np.allclose(background_model(frames, EdgeSettings()), np.median(frames, axis=0))
    with pytest.raises(InputError, match="too few for a background model"):
        background_model(frames[:3], EdgeSettings())


def test_keep_rule_weighs_the_image_against_all_keypoints():
    settings = EdgeSettings()
    low, high = EdgeScore(1000, 0.4, ()), EdgeScore(1000, 0.6, ())
    assert decide_edges(low, high, 3.0, 4.0, settings)[0]
    assert not decide_edges(high, low, 3.0, 3.0, settings)[0]
    kept, reason = decide_edges(low, high, 3.0, 12.0, settings)   # limit max(6, 6) px
    assert not kept and "median distance would grow" in reason
    assert decide_edges(low, high, float("nan"), float("nan"), settings)[0]


def test_links_left_out_by_name_are_checked(meshes):
    usable = usable_vertices(meshes, ("panda_hand",))
    hand = meshes.links.index("panda_hand")
    assert not usable[meshes.vertex_link == hand].any() and usable.sum() > 0
    with pytest.raises(InputError, match="unknown link"):
        usable_vertices(meshes, ("gripper",))
    with pytest.raises(InputError, match="every link"):
        usable_vertices(meshes, meshes.links)


def test_settings_refuse_nonsense():
    for bad in ({"scale_widths_px": (320, 80)}, {"search_range_px": 0.0},
                {"max_edge_angle_rad": 2.0}, {"max_keypoint_factor": 0.5},
                {"huber_scale_px": 8.0}):
        with pytest.raises(InputError):
            EdgeSettings(**bad)


# ----- a sequence and the command line ---------------------------------------------------------

def image_dataset(panda, meshes, folder: Path, blank: bool = False,
                  frames: int = NUM_FRAMES) -> np.ndarray:
    """A DREAM-layout folder with RGB images (no masks) and noisy labels; returns the pose."""
    T_true, joints, images, _ = edge_scene(panda, meshes, frames=frames)
    rng = np.random.default_rng(2)
    uv = project(CAMERA, transform_points(T_true, panda.forward_kinematics(joints)))
    uv = uv + rng.normal(0.0, 2.0, uv.shape)
    src = folder / "images"
    src.mkdir(parents=True)
    frames = []
    for i, (q, gray) in enumerate(zip(joints, images, strict=True)):
        path = src / f"{i}.png"
        pixels = np.zeros_like(gray) if blank else gray
        cv2.imwrite(str(path), np.repeat((pixels * 255).astype(np.uint8)[..., None], 3, 2))
        frames.append(Frame(name=f"{i:06d}", joints=q, image_path=path, uv_labels=uv[i],
                            T_cam_base_true=T_true))
    seq = Sequence(robot="panda", camera=CAMERA, joint_names=panda.joint_names,
                   keypoint_names=panda.keypoint_names, frames=tuple(frames),
                   T_cam_base_reference=T_true)
    write_dream(seq, folder / "data")
    return T_true


def ordered_sequence(panda, images: np.ndarray, joints: np.ndarray, order, folder: Path,
                     jitter_rad: float = 0.0) -> Sequence:
    """A sequence of images only (RGB PNGs written to `folder`): its frame k shows `edge_scene`'s
    grey image and joints number `order[k]`, the readings jittered by `jitter_rad` (an
    encoder's noise at rest)."""
    rng = np.random.default_rng(4)
    frames = []
    for k, i in enumerate(order):
        path = folder / f"{k}.png"
        cv2.imwrite(str(path), np.repeat((images[i] * 255).astype(np.uint8)[..., None], 3, 2))
        q = joints[i] + (rng.normal(0.0, jitter_rad, joints.shape[1]) if jitter_rad else 0.0)
        frames.append(Frame(name=f"{k:06d}", joints=q, image_path=path))
    return Sequence(robot="panda", camera=CAMERA, joint_names=panda.joint_names,
                    keypoint_names=panda.keypoint_names, frames=tuple(frames))


def test_calibrate_aligns_edges_by_default_without_masks(panda, meshes, tmp_path, capsys):
    T_true = image_dataset(panda, meshes, tmp_path)
    out = tmp_path / "result.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--out",
                 str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "edge alignment (10 frames" in printed
    doc = json.loads(out.read_text())
    edges = doc["edges"]
    assert edges["kept"] and edges["background_model"]
    assert edges["agreement_after"] > edges["agreement_before"]
    assert "panda_link0" in edges["static_links"]
    assert np.allclose(doc["T_cam_base"], edges["T_cam_base_aligned"])
    t_keypoints, _ = pose_errors(np.array(edges["T_cam_base_keypoints"]), T_true)
    t_edges, _ = pose_errors(np.array(doc["T_cam_base"]), T_true)
    assert t_edges < 0.002 and t_edges < t_keypoints
    # the 1-sigma written is the aligned pose's own: its jackknife, plus the difference from
    # the silhouettes' optimum (their cross-check)
    unc = doc["uncertainty"]
    assert unc["method"] == "jackknife of the edge alignment + the image cues' disagreement"
    assert doc["silhouette_check"]["ran"] and doc["silhouette_check"]["distance_m"] < 0.005
    assert len(unc["cue_disagreement_xi"]) == 6
    assert sum(g.startswith("frames ") for g in unc["jackknife_left_out"]) == 5
    assert not np.allclose(doc["covariance_xi"], unc["covariance_xi_keypoint_pose"])
    assert t_edges < 5 * np.linalg.norm(doc["sigma_camera_position_base_m"]) + 1e-3


def test_the_refinements_draw_the_joints_the_data_logs_off_the_keypoints(panda, meshes,
                                                                        tmp_path, monkeypatch):
    """A finger the joint log records moves in the edge alignment's and the silhouette
    check's outline (drawn at its reading, here closed as imaged); the keypoint fit and the
    readings check keep the keypoint robot."""
    import dream.cli.keypoint_pass as cli_keypoint_pass
    from dream.io import read_sequence

    T_true = image_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    frames = tuple(dataclasses.replace(f, joints=np.r_[f.joints, 0.0]) for f in seq.frames)
    write_dream(dataclasses.replace(seq, joint_names=seq.joint_names + ("panda_finger_joint1",),
                                    frames=frames), tmp_path / "fingers")
    drawn = {}
    for name in ("add_edges", "add_silhouette_check", "_readings_check"):
        real = getattr(cli_keypoint_pass, name)

        def spy(*args, real=real, name=name, **kwargs):
            robot = args[3] if name == "_readings_check" else args[1]   # (result, obs, seq, robot)
            drawn[name] = robot.keypoint_names
            return real(*args, **kwargs)

        monkeypatch.setattr(cli_keypoint_pass, name, spy)
    out = tmp_path / "result.json"
    assert main(["calibrate", "--data", str(tmp_path / "fingers"), "--use-labels", "--out",
                 str(out)]) == 0
    assert drawn["add_edges"] == drawn["add_silhouette_check"] == panda.keypoint_names + (
        "panda_leftfinger",)
    assert drawn["_readings_check"] == panda.keypoint_names    # the fit's robot
    doc = json.loads(out.read_text())
    assert doc["edges"]["kept"] and doc["readings_check"]["tried"] == []
    assert pose_errors(np.array(doc["T_cam_base"]), T_true)[0] < 0.002


@pytest.mark.parametrize("extra, message", [
    (["--refine", "edges", "--polish"], "both refine the extrinsic"),
    (["--exclude-links", "gripper"], "unknown link"),
    (["--refine", "none", "--exclude-links", "panda_hand"], "--refine none turns it off"),
    (["--exclude-links", "panda_hand", "--polish"], "it does not run here"),
])
def test_refine_misuse_is_one_clear_error(panda, meshes, tmp_path, capsys, extra, message):
    image_dataset(panda, meshes, tmp_path)
    out = tmp_path / "result.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--out",
                 str(out), *extra])
    _, err = capsys.readouterr()
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_images_without_edges_are_one_clear_error(panda, meshes, tmp_path, capsys):
    image_dataset(panda, meshes, tmp_path, blank=True)
    out = tmp_path / "result.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--refine",
                 "edges", "--out", str(out)])
    _, err = capsys.readouterr()
    assert code == 2 and "no image edges near the robot's outline" in err
    assert not out.exists()


def test_refine_with_edges_needs_images(panda):
    frames = tuple(Frame(name=f"{i:06d}", joints=np.zeros(panda.num_joints)) for i in range(3))
    seq = Sequence(robot="panda", camera=CAMERA, joint_names=panda.joint_names,
                   keypoint_names=panda.keypoint_names, frames=frames)
    with pytest.raises(InputError, match="needs the images"):
        refine_with_edges(seq, panda, np.eye(4))


def test_api_refine_edges_aligns_all_frames_or_each_frame(panda, meshes, tmp_path):
    import dream

    T_true = image_dataset(panda, meshes, tmp_path)
    seq = dream.read_sequence(tmp_path / "data")
    robot = dream.load_robot(seq)
    obs = dream.labels(seq, robot)
    result = dream.calibrate(seq, obs)
    res = dream.refine_edges(seq, robot, result, obs)
    assert res.kept and pose_errors(res.T_after, T_true)[0] < 0.002
    each = dream.calibrate(seq, obs, mode="each")
    frames = dream.refine_edges(seq, robot, each, obs)
    assert len(frames) == len(seq) and sum(f.kept for f in frames if f is not None) >= 7


def test_api_result_document_writes_the_refined_pose(panda, meshes, tmp_path):
    """A script that saves a refined result gets the aligned pose, its 1-sigma and verdict, as
    `dream calibrate` writes them (it got the keypoint pose); a refinement of another result
    or mode is refused."""
    import dataclasses

    import dream

    image_dataset(panda, meshes, tmp_path)
    seq = dream.read_sequence(tmp_path / "data")
    robot = dream.load_robot(seq)
    obs = dream.labels(seq, robot)
    result = dream.calibrate(seq, obs)
    res = dream.refine_edges(seq, robot, result, obs)
    doc = dream.result_document(result, obs, robot, seq, refined=res)
    assert res.kept and doc["edges"]["kept"]
    assert np.allclose(doc["T_cam_base"], res.T_after)
    assert not np.allclose(doc["T_cam_base"], result.T_cam_base, atol=1e-9)
    assert np.allclose(doc["T_base_cam"], np.linalg.inv(res.T_after))
    assert doc["uncertainty"]["method"] == f"jackknife of {res.jackknife.refined_by}"
    assert np.allclose(doc["covariance_xi"], res.jackknife.covariance)
    assert doc["quality"]["verdict"] == "good"
    with pytest.raises(dream.InputError, match="needs the sequence"):
        dream.result_document(result, obs, robot, refined=res)
    other = dataclasses.replace(res, T_before=res.T_before @ T_from_rotvec_t(
        np.zeros(3), np.array([0.05, 0.0, 0.0])))
    with pytest.raises(dream.InputError, match="another pose"):
        dream.result_document(result, obs, robot, seq, refined=other)
    each = dream.calibrate(seq, obs, mode="each")
    with pytest.raises(dream.InputError, match="not a refinement of this each-frames"):
        dream.result_document(each, obs, robot, seq, refined=res)
    unrefined = dream.result_document(each, obs, robot, seq, refined=(None,) * len(seq))
    assert "edges" not in unrefined and unrefined["per_frame"] == dream.result_document(
        each, obs, robot, seq)["per_frame"]
    with pytest.raises(dream.InputError, match="refined holds 3 frames, the result 10"):
        dream.result_document(each, obs, robot, seq, refined=(None,) * 3)
    frames = dream.refine_edges(seq, robot, each, obs)
    doc_each = dream.result_document(each, obs, robot, seq, refined=frames)
    kept = [e for e in doc_each["per_frame"] if e.get("edges", {}).get("kept")]
    assert doc_each["edges"]["frames_kept"] == len(kept) >= 7
    assert all(np.allclose(e["T_cam_base"], e["edges"]["T_cam_base_aligned"]) for e in kept)
