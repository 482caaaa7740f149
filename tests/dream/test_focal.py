"""The focal length the robot's outlines ask for (`dream.coarse.focal`): fitted with the pose on
masks rendered through a camera whose fx, fy were given wrong, adopted where the overlap
agrees, and kept where they were given right; `dream calibrate` goes on with the fitted camera
and says so."""

from __future__ import annotations

import json
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from dream.camera import CameraIntrinsics
from dream.cli import main
from dream.coarse.calibration import MOTION_MASKS, SearchMasks
from dream.coarse.camera_fit import parameter_covariance
from dream.coarse.focal import (
    FocalSettings,
    _decision,
    camera_fit,
    fit_focal,
    with_focal_scale,
)
from dream.coarse.intrinsics import with_asked_intrinsics
from dream.coarse.scales import finish_scale
from dream.coarse.search import find_winner
from dream.coarse.settings import SearchSettings
from dream.coarse.verdict import focal_finding
from dream.errors import InputError
from dream.io import read_sequence, write_dream
from dream.metrics import pose_errors
from dream.polish.objective import Contour, Objective, signed_distance
from dream.polish.settings import PolishSettings
from dream.silhouette import vertices_in_base
from tests.dream.test_coarse import GUESS_M, GUESS_RAD, SMALL, guess_flags, rendered_masks
from tests.dream.test_edges import CAMERA, image_dataset

GIVEN_SHORT = 1 / 1.05      # fx, fy given 5 % short of those the masks were rendered with
FRAMES = 12


@pytest.fixture(scope="module")
def scene(panda, meshes):
    T_true, joints, masks = rendered_masks(panda, meshes, frames=FRAMES)
    return T_true, vertices_in_base(meshes, joints), masks


def test_a_focal_length_given_short_is_fitted_and_the_pose_comes_back(meshes, scene):
    """Through the camera as given, the finish lands centimetres off along the optical axis;
    the joint fit finds the focal length within 0.5 % and the pose within a few millimetres,
    and the overlap confirms it."""
    T_true, P, masks = scene
    given = with_focal_scale(CAMERA, GIVEN_SHORT)
    T_given = finish_scale(P, meshes, masks, given, SearchSettings()).refine(T_true)
    assert pose_errors(T_given, T_true)[0] > 0.02
    estimate = fit_focal(P, meshes, masks, given, T_given, SearchSettings())
    assert estimate.scale * GIVEN_SHORT == pytest.approx(1.0, abs=0.005), estimate
    assert estimate.adopted and estimate.iou_fitted > estimate.iou_given, estimate.reason
    assert estimate.camera.fx == pytest.approx(given.fx * estimate.scale)
    assert (estimate.camera.cx, estimate.camera.cy) == (given.cx, given.cy)
    assert pose_errors(estimate.T_cam_base, T_true)[0] < 0.005
    assert 0 < estimate.sigma < 0.01
    doc = estimate.to_dict()
    assert doc["given"]["fx"] == given.fx and doc["used"]["fx"] == estimate.camera.fx
    assert focal_finding(doc)[0] == "check"
    # a longer focal length moves the camera back along its axis: the scale's 1-sigma enters
    # the pose's covariance mostly there (xi's translation is in camera axes)
    xi = estimate.xi_per_log_scale
    assert abs(xi[5]) > 3 * max(abs(xi[3]), abs(xi[4])), xi
    covariance = estimate.pose_covariance
    assert covariance[5, 5] == pytest.approx((estimate.sigma_used * xi[5]) ** 2)
    assert estimate.sigma_used >= FocalSettings().sigma_floor


def test_a_focal_length_given_right_is_kept(meshes, scene):
    T_true, P, masks = scene
    estimate = fit_focal(P, meshes, masks, CAMERA, T_true, SearchSettings())
    assert estimate.scale == pytest.approx(1.0, abs=0.005)
    assert not estimate.adopted and "stand" in estimate.reason
    assert not estimate.pose_covariance.any()
    assert focal_finding(estimate.to_dict()) is None


def test_the_decision_needs_the_overlap_and_a_change_within_range():
    settings = FocalSettings()
    assert _decision(0.05, 0.002, 0.60, 0.62, settings)[0]
    refused, why = _decision(0.05, 0.002, 0.60, 0.59, settings)
    assert not refused and "does not agree" in why
    assert not _decision(0.05, 0.002, 0.60, 0.6005, settings)[0]   # a gain within the noise
    assert not _decision(0.05, 0.02, 0.60, 0.62, settings)[0]      # within 3 sigma
    assert not _decision(0.001, 1e-5, 0.60, 0.62, settings)[0]     # below min_change
    beyond, why = _decision(0.3, 0.002, 0.60, 0.70, settings)
    assert not beyond and why.startswith("beyond")
    assert "stand" in _decision(0.3, 0.002, 0.60, 0.59, settings)[1]   # the overlap disagrees
    assert "stand" in _decision(0.3, 0.2, 0.60, 0.70, settings)[1]     # not resolved
    assert focal_finding({"adopted": False, "scale": 1.35, "reason": why})[0] == "unreliable"


def test_a_pull_on_one_link_in_every_frame_widens_the_scale_s_1_sigma(monkeypatch):
    """Something the arm carries pulls the hand's outline alike in every frame: the frame
    groups' fits agree, and only the fits without the hand's points tell the pull."""
    links = ("upper", "fore", "wrist", "hand")
    per_link, frames = 30, 10
    vertex_link = np.repeat(np.arange(len(links)), 5)                      # 5 vertices each
    vertex = np.tile(np.arange(len(vertex_link)), frames * per_link * len(links)
                     // len(vertex_link))
    frame = np.repeat(np.arange(frames), len(vertex) // frames)
    contour = Contour(np.zeros((len(vertex), 3)), frame, np.zeros(len(vertex)), vertex)
    hand = vertex_link[vertex] == links.index("hand")

    def fit(self, objective, contour, T, damping, keep):        # the hand asks for +2 %
        return T, np.array([0.02 * keep[hand].sum() / hand.sum()])

    monkeypatch.setattr("dream.coarse.camera_fit.CameraFit.fit", fit)
    meshes = SimpleNamespace(vertex_link=vertex_link, links=links)
    settings = FocalSettings()

    def sigma(contour: Contour, by_links: bool) -> float:
        covariance = parameter_covariance(camera_fit(settings), None, contour, np.eye(4), 1e-3,
                                          frames, settings.jackknife_groups, meshes, by_links)
        return float(np.sqrt(covariance[0, 0]))


    # the frame groups' steps are all 0.016 (each keeps 4 of 5 frames); the links' 0.02
    # but without the hand, 0: jackknife variance 3/4 * (3 * 0.005 ** 2 + 0.015 ** 2)
    assert sigma(contour, True) == pytest.approx(0.015)
    without = replace(contour, vertex=None)                   # no vertices: frame groups only
    for args in ((without, True), (contour, False)):          # nothing carried: the same
        assert sigma(*args) == pytest.approx(0.0, abs=1e-12)


def test_focal_settings_and_scales_are_checked():
    with pytest.raises(InputError, match="min_change"):
        FocalSettings(min_change=0.2)
    with pytest.raises(InputError, match="rounds"):
        FocalSettings(rounds=0)
    with pytest.raises(InputError, match="positive"):
        with_focal_scale(CAMERA, 0.0)
    objective = Objective(signed_distance(np.ones((4, 6), bool))[None],
                          CameraIntrinsics(5.0, 5.0, 2.5, 1.5, 6, 4), PolishSettings())
    with pytest.raises(InputError, match="distance fields"):
        objective.with_camera(CAMERA)


def test_calibrate_fits_a_focal_length_given_short_and_fixed_focal_keeps_it(
        panda, meshes, tmp_path, capsys):
    """Images only, fx, fy given 5 % short: the search adopts the fitted focal length, the
    refinements after it use it, RESULT.json and the verdict say so; `--fixed-focal` keeps the
    given one and lands centimetres off."""
    T_true = image_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    write_dream(replace(seq, camera=with_focal_scale(seq.camera, GIVEN_SHORT)),
                tmp_path / "short")
    guess = guess_flags(T_true, GUESS_M, GUESS_RAD)
    out = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path / "short"), "--out", str(out)] + guess)
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "intrinsics: fx, fy, cx, cy" in printed and "searching again with it" in err
    doc = json.loads(out.read_text())
    focal = doc["start"]["focal"]
    assert focal["adopted"] and focal["scale"] * GIVEN_SHORT == pytest.approx(1.0, abs=0.01)
    assert focal["used"]["fx"] == pytest.approx(CAMERA.fx, rel=0.01)
    assert pose_errors(np.asarray(doc["T_cam_base"]), T_true)[0] < 0.01
    assert doc["quality"]["verdict"] == "check"
    assert any("focal length" in w for w in doc["quality"]["warnings"])
    assert main(["overlay", str(tmp_path / "short"), "--extrinsic", str(out),
                 "--out", str(tmp_path / "overlays"), "--limit", "1"]) == 0
    assert "fitted by the calibration" in capsys.readouterr()[0]
    fixed = tmp_path / "fixed.json"
    code = main(["calibrate", "--data", str(tmp_path / "short"), "--out", str(fixed),
                 "--fixed-focal"] + guess)
    capsys.readouterr()
    assert code == 0
    doc = json.loads(fixed.read_text())
    assert doc["start"]["focal"] is None
    assert pose_errors(np.asarray(doc["T_cam_base"]), T_true)[0] > 0.02


def test_no_focal_fit_where_the_robot_was_found_only_with_the_held_pixels_kept(panda, meshes):
    """Masks of the whole silhouette read as motion masks hold the pixels the silhouettes cover
    in most frames, which the fit leaves out of them. Where the robot is found only with those
    pixels kept, neither the focal length nor the principal point is fitted; found without
    them, both are."""
    T_true, joints, masks = rendered_masks(panda, meshes, frames=FRAMES)
    given = with_focal_scale(CAMERA, GIVEN_SHORT)
    frames = np.arange(len(joints))
    inputs = SearchMasks(meshes, frames, joints, masks, MOTION_MASKS, (), frames)
    held_kept_only = replace(SMALL, min_found_iou=1.0)
    winner = find_winner(meshes, joints, masks, given, {"guess": T_true[None]},
                         held_kept_only, held=True)
    assert held_kept_only.robot_found(winner.best.iou, winner.best.found_iou)
    assert not held_kept_only.robot_found(winner.best.iou)
    lines: list[str] = []
    _, unfitted = with_asked_intrinsics(given, inputs, winner, held_kept_only,
                                        progress=lines.append)
    assert unfitted.focal is None and unfitted.principal is None and "not fitted" in lines[-1]
    _, fitted = with_asked_intrinsics(given, inputs, winner,
                                      replace(held_kept_only, min_found_iou=0.0))
    assert fitted.focal is not None and fitted.principal is not None
