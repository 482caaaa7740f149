"""Finding what a link carries that the URDF lacks (`dream.diagnosis.attached`): rigid groups of
links, the carving of unexplained motion, and `dream diagnose` naming a hidden plate."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from dream.cli import main
from dream.diagnosis.attached import AttachedSettings, carve, find_attached_geometry, rigid_groups
from dream.errors import InputError
from dream.extension import HeldReadings, ModelExtension, extension_yaml, read_extension
from dream.io import read_sequence
from dream.robot.link_geometry import BOX_KIND, LinkGeometry, with_link_geometry
from dream.sample import random_joints
from dream.silhouette import load_robot_meshes, render_silhouette
from dream.transforms import look_at
from tests.dream.test_edges import CAMERA, TARGET, image_dataset

PLATE = LinkGeometry("panda_hand", BOX_KIND, size_m=(0.30, 0.22, 0.01),
                     position_m=(0.0, 0.0, 0.14))


def test_links_that_keep_their_relative_pose_form_one_group(panda):
    q = random_joints(np.random.default_rng(0), panda, 6, 0.8)
    links = ("panda_link6", "panda_link7", "panda_hand", "panda_leftfinger")
    assert rigid_groups(panda, q, links) == [("panda_link6",),
                                             ("panda_link7", "panda_hand", "panda_leftfinger")]
    q[:, 6] = q[0, 6]                                   # a wrist joint that never turns
    assert rigid_groups(panda, q, links) == [links]


def _plate_silhouettes(panda):
    """16 random joint vectors seen from one camera: (q, T_cam_base, the silhouettes with the
    plate at the hand, the URDF's silhouettes)."""
    meshes = load_robot_meshes(panda)
    q = random_joints(np.random.default_rng(1), panda, 16, 0.8)
    T = look_at(TARGET + np.array([1.3, 0.5, 0.6]), TARGET)
    true = with_link_geometry(meshes, (PLATE,))
    moving = np.stack([render_silhouette(true, qi, T, CAMERA) for qi in q])
    model = np.stack([render_silhouette(meshes, qi, T, CAMERA) for qi in q])
    return q, T, moving, model


def test_carving_recovers_a_plate_from_silhouettes(panda):
    """Frames whose moving pixels are the robot with a plate, explained by the URDF's: the
    points kept in the hand's frame span the plate's extent (its thickness is a visual hull)."""
    q, T, moving, model = _plate_silhouettes(panda)
    settings = AttachedSettings()
    points = carve(panda, "panda_hand", q, T, CAMERA, moving | model, moving & ~model, settings)
    assert len(points) >= settings.min_points
    extent = np.ptp(points, axis=0) + settings.voxel_m
    assert np.all(np.abs(extent[:2] - np.array(PLATE.size_m[:2])) < 0.06), extent
    assert abs(np.median(points[:, 2]) - PLATE.position_m[2]) < 0.05
    none = carve(panda, "panda_hand", q, T, CAMERA, model, np.zeros_like(model), settings)
    assert len(none) == 0


class _Sequence:
    """What the carving reads of a sequence once its masks are given: its length and camera."""

    def __init__(self, frames: int, camera):
        self.frames, self.camera = frames, camera

    def __len__(self) -> int:
        return self.frames


def test_the_looser_carving_picks_the_link_when_the_object_drops_out_of_some_masks(
        panda, monkeypatch):
    """A plate missing from the motion masks in a quarter of the frames (seen edge-on, or in
    the background's colour): the strict carving alone keeps too little of it in the hand's
    frame, the looser one names the hand, and the box still spans the plate."""
    import dream.diagnosis.attached as attached

    q, T, moving, model = _plate_silhouettes(panda)
    moving[::4] = model[::4]                          # the plate drops out of 4 of 16 masks
    masks = (moving | model, moving & ~model, float((moving & ~model).sum() / moving.sum()))
    monkeypatch.setattr(attached, "unexplained_motion", lambda *args: masks)
    seq = _Sequence(len(q), CAMERA)

    found = find_attached_geometry(seq, panda, q, T)
    assert found.finding is not None and found.finding.geometry.link == "panda_hand"
    size = np.array(found.finding.geometry.size_m)
    assert np.all(np.abs(size[:2] - np.array(PLATE.size_m[:2])) < 0.06), size
    settings = AttachedSettings()
    loose = carve(panda, "panda_hand", q, T, CAMERA, *masks[:2], settings,
                  settings.link_moving_share)
    strict = carve(panda, "panda_hand", q, T, CAMERA, *masks[:2], settings)
    assert found.finding.points == len(loose) > len(strict) / settings.box_share  # a part
    extent = np.ptp(strict, axis=0)[:2] + settings.voxel_m
    assert np.any(extent < np.array(PLATE.size_m[:2]) - 0.06), extent
    with pytest.raises(InputError, match="must not exceed moving_share"):
        AttachedSettings(moving_share=0.6, link_moving_share=0.7)


def test_carving_says_what_it_kept_and_why_nothing_is_named(panda, meshes, tmp_path):
    """Ten images of a cluttered scene: with the URDF's own silhouettes nothing is kept; with a
    plate at the hand the hand is named, and a bar set above every group's points, or a pose
    that explains little, names nothing and says which rule stopped it."""
    image_dataset(panda, meshes, tmp_path / "urdf")
    seq = read_sequence(tmp_path / "urdf" / "data")
    joints, T_true = np.stack([f.joints for f in seq.frames]), seq.T_cam_base_reference
    outcome = find_attached_geometry(seq, panda, joints, T_true)
    assert outcome.finding is None and outcome.to_dict()["named"] is None
    assert set(outcome.points_per_link.values()) == {0} and outcome.unexplained_share < 0.05
    assert outcome.note().startswith("link_geometry: not named: no point near a moving link")
    with pytest.raises(InputError, match="usable must be"):
        find_attached_geometry(seq, panda, joints, T_true, usable=np.ones(3, bool))

    image_dataset(panda, with_link_geometry(meshes, (PLATE,)), tmp_path / "plate")
    seq = read_sequence(tmp_path / "plate" / "data")
    settings = AttachedSettings(min_seen_frames=5, moving_share=0.6,  # the plate leaves
                                link_moving_share=0.6)               # the view
    found = find_attached_geometry(seq, panda, joints, T_true, settings)
    assert found.finding is not None and found.finding.geometry.link == "panda_hand"
    counts = found.points_per_link
    strongest = max(counts, key=counts.get)
    assert counts["panda_hand"] > 0 and found.reason == ""
    bar = counts[strongest] + 1
    outcome = find_attached_geometry(seq, panda, joints, T_true,
                                     dataclasses.replace(settings, min_points=bar))
    assert outcome.finding is None and outcome.points_per_link == counts
    assert outcome.reason == (f"the most points kept, {counts[strongest]} in the frame of "
                              f"{strongest}, are fewer than the {bar} that name a carried shape")
    far = T_true.copy()
    far[:3, 3] += np.array([0.15, -0.1, 0.0])
    outcome = find_attached_geometry(seq, panda, joints, far, settings)
    assert outcome.finding is None and outcome.points_per_link == {}
    assert "of the moving pixels unexplained" in outcome.reason


@pytest.mark.slow
def test_diagnose_names_a_hidden_plate_and_held_readings_in_rendered_images(tmp_path, capsys):
    hidden = tmp_path / "hidden.yaml"
    hidden.write_text(extension_yaml(ModelExtension(
        held_readings=HeldReadings(0.2), link_geometry=(PLATE,), robot="panda")))
    base = ["synth", "--robot", "panda", "--config", "configs/synth/panda_teleop_like.yaml",
            "--num", "60", "--seed", "4"]
    assert main([*base, "--out", str(tmp_path / "plate"), "--model-extension",
                 str(hidden)]) == 0
    assert main([*base, "--out", str(tmp_path / "null")]) == 0
    capsys.readouterr()
    assert main(["diagnose", "--data", str(tmp_path / "plate"), "--use-labels", "--out",
                 str(tmp_path / "r1")]) == 0
    assert "cm in the frame of panda_hand (found in the images)" in capsys.readouterr().out
    assert "| link_geometry | panda_hand.size_m[0] |" in (tmp_path / "r1" / "report.md").read_text()
    doc = json.loads((tmp_path / "r1" / "diagnosis.json").read_text())
    assert doc["verdict"][0] == "held_readings" and "link_geometry" in doc["verdict"]
    found = read_extension(tmp_path / "r1" / "extended_model.yaml").link_geometry
    assert [(g.link, g.kind) for g in found] == [("panda_hand", BOX_KIND)]
    size, centre = np.array(found[0].size_m), np.array(found[0].position_m)
    assert np.all(np.abs(size[:2] - np.array(PLATE.size_m[:2])) < 0.06), size
    assert np.linalg.norm(centre - np.array(PLATE.position_m)) < 0.08, centre
    assert doc["truth"]["after"]["translation_error_m"] <= \
        0.5 * doc["truth"]["before"]["translation_error_m"]
    assert main(["diagnose", "--data", str(tmp_path / "null"), "--use-labels", "--out",
                 str(tmp_path / "r2")]) == 0
    assert "link_geometry: not named: " in capsys.readouterr().out
    doc = json.loads((tmp_path / "r2" / "diagnosis.json").read_text())
    assert "link_geometry" not in doc["verdict"] and "image_findings" not in doc
    assert doc["attached_search"]["named"] is None and doc["attached_search"]["reason"]
    assert any(n.startswith("link_geometry: not named: ") for n in doc["notes"])
