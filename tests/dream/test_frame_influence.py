"""The finish's outlying-frames check (`dream.coarse.scales`): one frame's mask shifted by a few
pixels pulls the finish's pose far harder than the others; it is named and left out."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from dream.coarse.carried import carried_region
from dream.coarse.scales import finish_scale, frame_influence, outlying_frames
from dream.coarse.settings import SearchSettings
from dream.metrics import pose_errors
from dream.polish.objective import Objective, signed_distance
from dream.silhouette import vertices_in_base
from tests.dream.test_coarse import rendered_masks
from tests.dream.test_edges import CAMERA

WRONG_FRAME, SHIFT_PX = 3, 6     # a frame whose mask lies 6 px off the robot (a wrong mask)
FAR_LINK_POINT = np.array([[0.0, 0.0, 0.3]])   # a "carried" voxel 0.3 m past the hand: the
#   region only switches the check on; it covers no pixel of the robot


def shifted_scene(panda, meshes):
    T_true, joints, masks = rendered_masks(panda, meshes, frames=10)
    masks[WRONG_FRAME] = np.roll(masks[WRONG_FRAME], (SHIFT_PX, SHIFT_PX), axis=(0, 1))
    return T_true, joints, masks


def test_the_frame_with_a_shifted_mask_pulls_hardest(panda, meshes):
    T_true, joints, masks = shifted_scene(panda, meshes)
    scales = finish_scale(vertices_in_base(meshes, joints), meshes, masks, CAMERA,
                          SearchSettings())
    camera, small = scales.levels[-1]
    objective = Objective(np.stack([signed_distance(m) for m in small]), camera, scales.params)
    influence = frame_influence(objective, scales.contour(T_true), T_true, len(joints))
    assert influence.argmax() == WRONG_FRAME, influence
    assert outlying_frames(influence, SearchSettings().frame_influence,
                           SearchSettings().max_outlying_share).tolist() == [WRONG_FRAME]


def test_with_a_carried_region_the_finish_leaves_the_outlying_frame_out(panda, meshes):
    T_true, joints, masks = shifted_scene(panda, meshes)
    region = carried_region(panda, joints, "panda_hand", FAR_LINK_POINT, 0.02, 2)
    P = vertices_in_base(meshes, joints)
    errors, left_out = {}, {}
    for factor in (0.0, SearchSettings().frame_influence):
        settings = replace(SearchSettings(), frame_influence=factor)
        T, left_out[factor] = finish_scale(P, meshes, masks, CAMERA, settings,
                                           region=region).refine_reporting(T_true)
        errors[factor] = pose_errors(T, T_true)
    (m_all, rad_all), (m_kept, rad_kept) = errors.values()
    assert m_kept < 0.5 * m_all and m_kept < 0.002, errors
    assert left_out[0.0].tolist() == [] and left_out[settings.frame_influence].tolist() == [
        WRONG_FRAME], left_out


def test_without_a_carried_region_no_frame_is_left_out(panda, meshes):
    T_true, joints, masks = shifted_scene(panda, meshes)
    scales = finish_scale(vertices_in_base(meshes, joints), meshes, masks, CAMERA,
                          SearchSettings())
    assert scales.outliers is None
    assert scales.refine_reporting(T_true)[1].tolist() == []
