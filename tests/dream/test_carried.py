"""Something the arm carries that the URDF lacks, in the search without keypoints
(`dream.coarse.carried`): carved from the masks at the winner and reported (the verdict's
carried finding), or on request joined to the model as a hull and the search run again."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dream.coarse.calibration import DATA_MASKS, SearchMasks, with_carried
from dream.coarse.carried import carried_geometry, with_hull
from dream.coarse.search import search
from dream.coarse.settings import SearchSettings
from dream.coarse.verdict import carried_finding
from dream.errors import InputError
from dream.metrics import pose_errors
from dream.robot.link_geometry import BOX_KIND, LinkGeometry, with_link_geometry
from dream.sample import random_joints
from dream.silhouette import load_robot_meshes, render_silhouette
from dream.transforms import look_at
from tests.dream.test_coarse import off_by
from tests.dream.test_edges import CAMERA, TARGET

HELD = LinkGeometry("panda_hand", BOX_KIND, size_m=(0.18, 0.18, 0.18),
                    position_m=(0.0, 0.0, 0.16))      # a held block larger than the hand
FRAMES = 16
SETTINGS = SearchSettings(guess_samples=200, local_starts=4, fine_starts=2, basin_starts=2,
                          jackknife_groups=0, search_frames=8, join_carried=True)


@pytest.fixture(scope="module")
def scene(panda):
    """(meshes, joints, T_cam_base, masks with the held block, masks of the URDF alone)."""
    meshes = load_robot_meshes(panda)
    q = random_joints(np.random.default_rng(3), panda, FRAMES, 0.8)
    T = look_at(TARGET + np.array([1.3, 0.5, 0.6]), TARGET)
    holding = with_link_geometry(meshes, (HELD,))
    held = np.stack([render_silhouette(holding, qi, T, CAMERA) for qi in q])
    bare = np.stack([render_silhouette(meshes, qi, T, CAMERA) for qi in q])
    return meshes, q, T, held, bare


def test_the_carving_finds_what_the_hand_holds_and_nothing_on_a_bare_arm(scene):
    meshes, q, T, held, bare = scene
    found = carried_geometry(meshes, q, held, CAMERA, T)
    assert found.finding is not None
    assert found.finding.geometry.link in ("panda_link7", "panda_link8", "panda_hand")
    assert found.finding.points_link.shape == (found.finding.points, 3)
    assert carried_geometry(meshes, q, bare, CAMERA, T).finding is None
    with pytest.raises(InputError, match="masks have shape"):
        carried_geometry(meshes, q, held[:-1], CAMERA, T)


def test_the_hull_joined_to_the_model_explains_the_held_pixels(scene):
    meshes, q, T, held, _ = scene
    finding = carried_geometry(meshes, q, held, CAMERA, T).finding
    hull = with_hull(meshes, finding.geometry.link, finding.points_link, 0.02)

    def iou(model):
        masks = np.stack([render_silhouette(model, qi, T, CAMERA) for qi in q])
        return (masks & held).sum() / (masks | held).sum()

    assert iou(hull) > iou(meshes) + 0.05 and iou(hull) > 0.85, (iou(hull), iou(meshes))
    with pytest.raises(InputError, match="no link"):
        with_hull(meshes, "tool_tip", finding.points_link, 0.02)
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        with_hull(meshes, "panda_hand", np.zeros((0, 3)), 0.02)


def test_the_carried_block_is_reported_or_joined_and_searched_again(scene):
    """From 4 cm / 3 deg off, on masks with the block: the carving at the first winner finds
    it; by default it is reported (the verdict's `check`) and the winner kept; on request the
    search again from there with its hull explains the masks better and lands within 1 cm.
    (On these clean masks the first search is not pulled off: the round check refuses the
    rounds the block would drag. On rendered scenes' motion masks it is, by 2-4 cm, and the
    search again brings it nearer but not within 1 cm: docs/benchmarks.md.)"""
    meshes, q, T, held, _ = scene
    start = off_by(T, 0.04, np.deg2rad(3.0), 0)
    inputs = SearchMasks(meshes, np.arange(FRAMES), q, held, DATA_MASKS, (),
                         np.arange(0, FRAMES, 2))
    first = search(meshes, q, held, CAMERA, {"guess": start[None]}, SETTINGS,
                   search_frames=inputs.search)
    reported, inputs_reported = with_carried(CAMERA, inputs, first,
                                             replace(SETTINGS, join_carried=False))
    assert reported is first and inputs_reported.meshes is meshes
    assert inputs_reported.carried.finding.geometry.link in ("panda_link7", "panda_link8",
                                                             "panda_hand")
    assert carried_finding(inputs_reported.carried.finding.geometry.link,
                           inputs_reported.carried.finding.geometry.size_m)[0] == "check"
    again, carried = with_carried(CAMERA, inputs, first, SETTINGS)
    assert carried.carried is not None and carried.carried.finding is not None
    assert len(carried.meshes.vertices) > len(meshes.vertices)
    assert again.hypotheses["carried"] >= 2 and "guess" in again.hypotheses
    assert again.best.iou > first.best.iou + 0.05, (first.best.iou, again.best.iou)
    assert pose_errors(again.best.T_cam_base, T)[0] < 0.01
