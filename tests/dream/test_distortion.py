"""The lens's radial distortion the robot's outlines ask for (`dream.coarse.distortion`): fitted
with the pose on masks rendered through a distorted lens and given without its coefficients,
adopted where the overlap agrees, kept where they were given right; `dream calibrate` goes on
through the fitted camera and says so, and `--fixed-distortion` keeps the given one; the
keypoint path adopts the one its silhouettes' cross-check asks for."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from dream.cli import main
from dream.coarse.distortion import (
    DistortionSettings,
    _decision,
    corner_radius2,
    distortion_finding,
    fit_distortion,
    with_corner_shift,
)
from dream.coarse.scales import finish_scale
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.io import read_sequence, write_dream
from dream.metrics import pose_errors
from dream.pnp import increment_between
from dream.silhouette import render_silhouette, vertices_in_base
from tests.dream.test_coarse import GUESS_M, GUESS_RAD, guess_flags
from tests.dream.test_edges import CAMERA, edge_scene, image_dataset
from tests.dream.test_focal_check import CHI2_6DOF_95

K1 = -0.25          # a wide lens's barrel distortion (corner of the 320x240 image: -16 %)
K2 = 0.1            # with a k2 that straightens the border (+4 % at the corner)
FRAMES = 12


@pytest.fixture(scope="module")
def scene(panda, meshes):
    """Masks rendered through CAMERA with k1 = K1, the pose, and the vertices in the base."""
    T_true, joints, _, _ = edge_scene(panda, meshes, frames=FRAMES)
    lens = replace(CAMERA, distortion=(K1, 0.0, 0.0, 0.0, 0.0))
    masks = np.stack([render_silhouette(meshes, q, T_true, lens) for q in joints])
    return T_true, vertices_in_base(meshes, joints), masks


def test_a_distortion_left_out_is_fitted_and_the_pose_comes_back(meshes, scene):
    """Through the camera given without its distortion the finish lands off; the joint fit
    finds k1 within a tenth and the pose within a few millimetres, and the overlap agrees."""
    T_true, P, masks = scene
    T_given = finish_scale(P, meshes, masks, CAMERA, SearchSettings()).refine(T_true)
    errors_given = pose_errors(T_given, T_true)
    estimate = fit_distortion(P, meshes, masks, CAMERA, T_given, SearchSettings())
    assert estimate.adopted and estimate.iou_fitted > estimate.iou_given, estimate.reason
    assert estimate.shift == pytest.approx(K1 * corner_radius2(CAMERA), rel=0.1), estimate
    assert estimate.camera.dist_coeffs[0] == pytest.approx(K1, rel=0.1)
    assert (estimate.camera.fx, estimate.camera.cx) == (CAMERA.fx, CAMERA.cx)
    errors = pose_errors(estimate.T_cam_base, T_true)
    assert errors[0] < 0.005 and errors[0] < errors_given[0] / 2, (errors, errors_given)
    assert 0 < estimate.sigma < abs(estimate.shift) / 3
    assert estimate.k2_share == 0.0 and "k2 not asked" in estimate.reason   # k1 alone was right
    # the lens with k2 matched the outlines as well: the move to its pose enters the 1-sigma
    other_m = np.linalg.norm(estimate.xi_other_lens[3:])
    assert 0 < other_m < 0.002
    assert np.linalg.norm(estimate.pose_covariance - replace(
        estimate, xi_other_lens=np.zeros(6)).pose_covariance) == pytest.approx(
        np.linalg.norm(estimate.xi_other_lens) ** 2)
    doc = estimate.to_dict()
    assert doc["used"]["distortion"][0] == estimate.camera.dist_coeffs[0]
    assert doc["given"]["distortion"] == [0.0] * 5
    assert distortion_finding(doc)[0] == "check"
    covariance = estimate.pose_covariance
    assert covariance.shape == (6, 6) and np.all(np.linalg.eigvalsh(covariance) > -1e-15)
    assert np.trace(covariance) > 0


def test_a_lens_with_k2_left_out_is_fitted_with_k2(panda, meshes, scene):
    """Through a lens with k1 and k2 given neither, k1 alone cannot bend the outlines near the
    border as k2 does; the fit with k2 finds both and the pose, and the overlap through it
    beats the overlap through k1 alone."""
    T_true, P, _ = scene
    _, joints, _, _ = edge_scene(panda, meshes, frames=FRAMES)
    lens = replace(CAMERA, distortion=(K1, K2, 0.0, 0.0, 0.0))
    masks = np.stack([render_silhouette(meshes, q, T_true, lens) for q in joints])
    T_given = finish_scale(P, meshes, masks, CAMERA, SearchSettings()).refine(T_true)
    k1_alone = fit_distortion(P, meshes, masks, CAMERA, T_given, SearchSettings(),
                              DistortionSettings(k2=False))
    estimate = fit_distortion(P, meshes, masks, CAMERA, T_given, SearchSettings())
    assert estimate.adopted and "through k2" in estimate.reason, estimate.reason
    assert estimate.camera.dist_coeffs[:2] == pytest.approx([K1, K2], rel=0.1)
    assert estimate.k2_share == pytest.approx(K2 * corner_radius2(CAMERA) ** 2, rel=0.1)
    assert 0 < estimate.k2_sigma < estimate.k2_share / 3
    assert estimate.iou_fitted > k1_alone.iou_fitted + DistortionSettings().min_iou_gain
    errors, errors_k1 = (pose_errors(e.T_cam_base, T_true)[0] for e in (estimate, k1_alone))
    assert errors < 0.002 and errors < errors_k1 / 2, (errors, errors_k1)
    assert estimate.xi_per_unit.shape == (6, 2) and estimate.covariance_used.shape == (2, 2)
    assert not np.any(estimate.xi_other_lens)      # the overlap chose the lens with k2
    assert np.all(np.linalg.eigvalsh(estimate.pose_covariance) > -1e-15)
    doc = estimate.to_dict()
    assert doc["k2_share"] == estimate.k2_share and doc["used"]["distortion"][1] != 0.0
    assert "k1, k2 -0.25" in distortion_finding(doc)[1]


def test_a_distortion_given_right_is_kept(meshes, scene):
    T_true, P, masks = scene
    lens = replace(CAMERA, distortion=(K1, 0.0, 0.0, 0.0, 0.0))
    estimate = fit_distortion(P, meshes, masks, lens, T_true, SearchSettings())
    assert abs(estimate.shift) < DistortionSettings().min_change, estimate
    assert not estimate.adopted and "stands" in estimate.reason
    assert not estimate.pose_covariance.any()
    assert distortion_finding(estimate.to_dict()) is None


def test_the_decision_needs_the_overlap_and_a_change_within_range():
    settings = DistortionSettings()
    assert _decision(-0.1, 0.005, 0.60, 0.62, settings)[0]
    refused, why = _decision(-0.1, 0.005, 0.60, 0.59, settings)
    assert not refused and "does not agree" in why
    assert not _decision(-0.1, 0.005, 0.60, 0.6005, settings)[0]   # a gain within the noise
    assert not _decision(-0.1, 0.05, 0.60, 0.62, settings)[0]      # within 3 sigma
    assert not _decision(0.005, 1e-5, 0.60, 0.62, settings)[0]     # below min_change
    assert not _decision(-0.1, float("nan"), 0.60, 0.62, settings)[0]
    assert "+4.0 % of it through k2" in _decision(-0.1, 0.005, 0.60, 0.62, settings, 0.04,
                                                  0.002)[1]
    beyond, why = _decision(-0.6, 0.005, 0.60, 0.70, settings)
    assert not beyond and why.startswith("beyond")
    record = {"adopted": False, "corner_shift": -0.6, "reason": why}
    assert distortion_finding(record)[0] == "unreliable"


def test_distortion_settings_and_shifts_are_checked():
    with pytest.raises(InputError, match="min_change"):
        DistortionSettings(min_change=0.5)
    with pytest.raises(InputError, match="rounds"):
        DistortionSettings(rounds=0)
    with pytest.raises(InputError, match="finite"):
        with_corner_shift(CAMERA, float("nan"))
    moved = with_corner_shift(replace(CAMERA, distortion=(0.1, 0.02, 0.0, 0.0, 0.0)), -0.05)
    assert moved.dist_coeffs[1] == 0.02                       # k2 and the rest kept
    assert moved.dist_coeffs[0] == pytest.approx(0.1 - 0.05 / corner_radius2(CAMERA))
    both = with_corner_shift(CAMERA, -0.05, 0.02)             # the corner moves as much
    R = corner_radius2(CAMERA)
    assert both.dist_coeffs[0] * R + both.dist_coeffs[1] * R ** 2 == pytest.approx(-0.05)
    assert both.dist_coeffs[1] * R ** 2 == pytest.approx(0.02)
    with pytest.raises(InputError, match="finite"):
        with_corner_shift(CAMERA, -0.05, float("inf"))


def given_k1(panda, meshes, folder) -> np.ndarray:
    """Images of an undistorted lens in `folder`/data and the same given with k1 = K1 in
    `folder`/raw (a rectified recording given its raw camera); returns the true pose."""
    T_true = image_dataset(panda, meshes, folder)
    seq = read_sequence(folder / "data")
    write_dream(replace(seq, camera=replace(seq.camera, distortion=(K1, 0.0, 0.0, 0.0, 0.0))),
                folder / "raw")
    return T_true


def test_calibrate_fits_a_distortion_given_wrong_and_fixed_distortion_keeps_it(
        panda, meshes, tmp_path, capsys):
    """Images of an undistorted lens given with k1 = K1 (a rectified recording given its raw
    camera): the search adopts the radial shift that undoes it, RESULT.json and the verdict
    say so, the overlay draws through it; `--fixed-distortion` keeps the given one and lands
    farther off."""
    T_true = given_k1(panda, meshes, tmp_path)
    guess = guess_flags(T_true, GUESS_M, GUESS_RAD)
    out = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path / "raw"), "--out", str(out)] + guess)
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "distortion k1, k2" in printed and "lens distortion: adopted" in err
    doc = json.loads(out.read_text())
    record = doc["start"]["distortion"]
    assert record["adopted"] and abs(record["used"]["distortion"][0]) < abs(K1) / 4, record
    error = pose_errors(np.asarray(doc["T_cam_base"]), T_true)[0]
    assert error < 0.01
    assert doc["quality"]["verdict"] == "check"
    assert any("lens distortion" in w for w in doc["quality"]["warnings"])
    assert main(["overlay", str(tmp_path / "raw"), "--extrinsic", str(out),
                 "--out", str(tmp_path / "overlays"), "--limit", "1"]) == 0
    assert "fitted by the calibration" in capsys.readouterr()[0]
    fixed = tmp_path / "fixed.json"
    code = main(["calibrate", "--data", str(tmp_path / "raw"), "--out", str(fixed),
                 "--fixed-distortion"] + guess)
    capsys.readouterr()
    assert code == 0
    doc = json.loads(fixed.read_text())
    assert doc["start"]["distortion"] is None
    assert pose_errors(np.asarray(doc["T_cam_base"]), T_true)[0] > error


def test_the_keypoint_path_calibrates_again_through_a_distortion_given_wrong(
        panda, meshes, tmp_path, capsys):
    """The keypoint path through a camera given with k1 = K1 for undistorted images: the
    silhouettes' cross-check asks for the shift that undoes it, the keypoint fit and its
    alignment run again through it, RESULT.json's `distortion` says what was given and used,
    the verdict says so (never `good`), the overlay draws through it, and the 1-sigma holds
    the pose. `--fixed-distortion` keeps the given lens: the move to the pose through the
    asked one then enters the 1-sigma, no focal length or principal point is adopted, and the
    pose lies farther off."""
    T_true = given_k1(panda, meshes, tmp_path)
    out, fixed = tmp_path / "r.json", tmp_path / "fixed.json"
    code = main(["calibrate", "--data", str(tmp_path / "raw"), "--use-labels", "--out",
                 str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    assert "distortion k1, k2" in printed and "calibrating again through them" in printed
    doc = json.loads(out.read_text())
    record = doc["distortion"]
    assert record["adopted"] and record["asked_by"] == "silhouette_check", record
    assert record["corner_shift"] == pytest.approx(-K1 * corner_radius2(CAMERA), rel=0.25)
    assert record["given"]["distortion"][0] == K1
    assert abs(record["used"]["distortion"][0]) < abs(K1) / 4
    assert not doc["silhouette_check"]["distortion"]["asked"]     # through the adopted one
    assert doc["quality"]["verdict"] == "check"
    assert any("lens distortion" in w and "--fixed-distortion" in w
               for w in doc["quality"]["warnings"])
    assert "adopted intrinsics" in doc["uncertainty"]["method"]
    T = np.asarray(doc["T_cam_base"])
    xi = increment_between(T, T_true)
    assert xi @ np.linalg.pinv(np.asarray(doc["covariance_xi"])) @ xi < CHI2_6DOF_95
    assert main(["overlay", str(tmp_path / "raw"), "--extrinsic", str(out),
                 "--out", str(tmp_path / "overlays"), "--limit", "1"]) == 0
    assert "fitted by the calibration" in capsys.readouterr()[0]

    code = main(["calibrate", "--data", str(tmp_path / "raw"), "--use-labels", "--out",
                 str(fixed), "--fixed-distortion"])
    printed, err = capsys.readouterr()
    assert code == 0, err
    kept = json.loads(fixed.read_text())
    record = kept["silhouette_check"]["distortion"]
    assert record["asked"] and not record["adopted"], record
    assert record["used"]["distortion"][0] == K1                  # the given one, kept
    assert not {"distortion", "focal", "principal"} & set(kept)
    assert kept["quality"]["verdict"] != "good"
    assert any("lens distortion" in w for w in kept["quality"]["warnings"])
    T_kept = np.asarray(kept["T_cam_base"])
    xi = increment_between(T_kept, T_true)
    assert xi @ np.linalg.pinv(np.asarray(kept["covariance_xi"])) @ xi < CHI2_6DOF_95
    assert pose_errors(T_kept, T_true)[0] > pose_errors(T, T_true)[0]
