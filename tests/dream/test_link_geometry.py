"""The `link_geometry` effect (`dream.robot.link_geometry`): a box at a link, a scaled link or an
excluded outline, written in extended_model.yaml, applied to the refinement's meshes and to the
URDF visuals synth renders, and honoured by `dream calibrate --model-extension`."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from dream.cli import main
from dream.edges import EdgeSettings
from dream.edges.score import edge_score
from dream.edges.search import scale_images
from dream.errors import InputError
from dream.extension import extension_yaml, read_extension
from dream.robot.link_geometry import (
    BOX_KIND,
    EXCLUDE_KIND,
    SCALE_KIND,
    LinkGeometry,
    extended_visuals,
    with_link_geometry,
)
from dream.robot.visuals import BOX, read_link_visuals
from dream.sample import random_joints
from dream.silhouette import render_silhouette, vertices_in_base
from dream.transforms import look_at
from tests.dream.test_edges import CAMERA, ROBOT_GREY, TARGET, cluttered_background, image_dataset

PLATE = LinkGeometry("panda_hand", BOX_KIND, size_m=(0.30, 0.22, 0.01),
                     position_m=(0.0, 0.0, 0.14), rotation_rad=(0.0, 0.0, 0.3))


def _write(tmp_path, effects: dict):
    path = tmp_path / "extended_model.yaml"
    path.write_text(yaml.safe_dump({"format": "dream-model-extension", "version": 1,
                                    "effects": effects}))
    return path


def test_each_kind_reads_and_writes_back(tmp_path):
    path = _write(tmp_path, {"link_geometry": {
        "panda_hand": PLATE.to_params(), "panda_link7": {"kind": SCALE_KIND, "scale": 1.2},
        "panda_link6": EXCLUDE_KIND}})
    extension = read_extension(path)
    kinds = {g.link: g.kind for g in extension.link_geometry}
    assert kinds == {"panda_hand": BOX_KIND, "panda_link7": SCALE_KIND,
                     "panda_link6": EXCLUDE_KIND}
    assert extension.effects == ("link_geometry",)
    again = tmp_path / "again.yaml"
    again.write_text(extension_yaml(extension))
    assert read_extension(again) == extension


@pytest.mark.parametrize("params, message", [
    ({"kind": "box", "size_m": [300, 220, 10]}, "millimetres"),
    ({"kind": "box", "size_m": [0.3, 0.2, 0.01], "position_m": [0, 0, 140]}, "millimetres"),
    ({"kind": "box", "size_m": [0.3, 0.2]}, "3 finite numbers"),
    ({"kind": "scale", "scale": 10}, "factor in"),
    ({"kind": "glue"}, "needs a kind"),
    ({"kind": "scale", "scale": 1.1, "size_m": [1, 1, 1]}, "unknown parameter 'size_m'"),
])
def test_implausible_geometry_is_one_error_naming_the_file(tmp_path, params, message):
    path = _write(tmp_path, {"link_geometry": {"panda_hand": params}})
    with pytest.raises(InputError, match=message) as info:
        read_extension(path)
    assert str(info.value).startswith(str(path)) and "\n" not in str(info.value)


def test_a_box_moves_with_its_link_and_a_scale_scales_about_the_link_origin(panda, meshes):
    q = random_joints(np.random.default_rng(0), panda, 1, 0.8)[0]
    scaled = LinkGeometry("panda_link7", SCALE_KIND, scale=1.5)
    out = with_link_geometry(meshes, (PLATE, scaled))
    assert out.num_triangles == meshes.num_triangles + 12
    P = vertices_in_base(out, q)
    T_hand = panda.link_poses(q, ["panda_hand"])[0]
    corners, _ = PLATE.box_mesh()
    np.testing.assert_allclose(P[len(meshes.vertices):], corners @ T_hand[:3, :3].T
                               + T_hand[:3, 3], atol=1e-9)
    link7 = meshes.links.index("panda_link7")
    old = len(meshes.vertices)
    np.testing.assert_allclose(out.vertices[:old][meshes.vertex_link == link7],
                               1.5 * meshes.vertices[meshes.vertex_link == link7])
    with pytest.raises(InputError, match="unknown link"):
        with_link_geometry(meshes, (LinkGeometry("tool0", BOX_KIND, size_m=(0.1,) * 3),))


def test_synth_visuals_gain_the_box_and_cannot_render_an_unknown_outline(panda):
    visuals = read_link_visuals(panda.urdf_path)
    out = extended_visuals(visuals, (PLATE,))
    box = out["panda_hand"][-1]
    assert len(out["panda_hand"]) == len(visuals["panda_hand"]) + 1 and box.kind == BOX
    np.testing.assert_allclose(box.size, np.array(PLATE.size_m) / 2)
    with pytest.raises(InputError, match="cannot be rendered"):
        extended_visuals(visuals, (LinkGeometry("panda_hand", EXCLUDE_KIND),))


def test_the_extended_outline_agrees_with_images_of_the_extended_robot(panda, meshes):
    """Images of an arm carrying a plate: its outline with the plate lies on their edges more
    often than the URDF's, whose hand outline runs inside the plate."""
    rng = np.random.default_rng(3)
    T = look_at(TARGET + np.array([1.3, 0.5, 0.6]), TARGET)
    joints = random_joints(rng, panda, 6, 0.8)
    true = with_link_geometry(meshes, (PLATE,))
    background = cluttered_background(rng)
    gray = np.stack([np.where(render_silhouette(true, q, T, CAMERA), ROBOT_GREY, background)
                     for q in joints]).astype(np.float32)
    settings = EdgeSettings()
    images = scale_images(gray, CAMERA, CAMERA.width, settings)
    hand = meshes.links.index("panda_hand")

    def hand_agreement(m):
        score = edge_score(m, vertices_in_base(m, joints), T, images, settings)
        return next(a.agreement for a in score.links if a.link == m.links[hand])

    assert hand_agreement(true) > hand_agreement(meshes) + 0.1


def test_calibrate_honours_link_geometry_in_the_edge_alignment(panda, meshes, tmp_path,
                                                              capsys):
    image_dataset(panda, meshes, tmp_path)
    path = _write(tmp_path, {"link_geometry": {"panda_hand": PLATE.to_params(),
                                               "panda_link7": EXCLUDE_KIND}})
    out = tmp_path / "result.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels",
                 "--refine", "edges", "--model-extension", str(path), "--out", str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(out.read_text())
    assert doc["edges"]["excluded_links"] == ["panda_link7"]
    assert doc["model_extension"]["effects"]["link_geometry"]["panda_hand"]["kind"] == BOX_KIND
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--refine",
                 "none", "--model-extension", str(path), "--out", str(tmp_path / "r2.json")])
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "link_geometry changes only the image refinements" in printed


def test_calibrate_refuses_link_geometry_of_an_unknown_link(panda, meshes, tmp_path, capsys):
    image_dataset(panda, meshes, tmp_path)
    path = _write(tmp_path, {"link_geometry": {"tool0": {"kind": "scale", "scale": 1.1}}})
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels",
                 "--refine", "edges", "--model-extension", str(path), "--out",
                 str(tmp_path / "r.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "tool0" in err[0]
    assert not (tmp_path / "r.json").exists()
