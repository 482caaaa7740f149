"""What `dream calibrate` writes, prints and draws describes the pose it wrote: a kept image
refinement's own 1-sigma, overlays at that pose, the data's masks deciding over a biased
detector, and one verdict for every mode."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from dream.cli import main
from dream.errors import InputError
from dream.io import read_sequence
from dream.metrics import pose_errors
from dream.overlay import OUTLINE_RGB
from dream.refined_uncertainty import (
    RefinementJackknife,
    combined,
    frame_groups,
    group_jackknife,
    jackknife_covariance,
    with_refined_uncertainty,
)
from dream.transforms import T_from_rotvec_t

BIAS_PX = (9.0, -7.0)        # every label moved the same way: a detector biased on these images
OUTLINE_NEAR_MASK_PX = 3     # an outline pixel this close to the mask's boundary lies on it


@pytest.fixture(scope="module")
def biased_scene(tmp_path_factory) -> Path:
    """A rendered fixed-camera Panda scene with masks whose keypoint labels are all moved by
    `BIAS_PX`."""
    from synth.demo import render_demo_scene

    data = render_demo_scene(tmp_path_factory.mktemp("scene") / "data", seed=3, num_frames=6)
    for path in sorted(data.glob("[0-9]*.json")):
        doc = json.loads(path.read_text())
        for kp in doc["objects"][0]["keypoints"]:
            kp["projected_location"] = (np.asarray(kp["projected_location"]) + BIAS_PX).tolist()
        path.write_text(json.dumps(doc))
    return data


def _calibrate(data: Path, out: Path, capsys, *options: str) -> tuple[dict, str]:
    code = main(["calibrate", "--data", str(data), "--use-labels", "--out", str(out),
                 *options])
    printed, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out.read_text()), printed


def _error_mm(doc: dict, data: Path) -> float:
    truth = read_sequence(data).frames[0].T_cam_base_true
    return 1000 * float(pose_errors(np.asarray(doc["T_cam_base"]), truth)[0])


def test_refine_auto_polishes_with_the_data_masks_over_a_biased_detector(biased_scene,
                                                                         tmp_path, capsys):
    kept, printed = _calibrate(biased_scene, tmp_path / "auto.json", capsys)
    keypoints, _ = _calibrate(biased_scene, tmp_path / "none.json", capsys, "--refine", "none")
    assert "--refine auto polishes the silhouettes" in printed
    polish = kept["polish"]
    assert polish["kept"] and polish["keypoint_guard"] == "none"
    assert "the detector's disagreement" in polish["reason"]
    assert polish["median_px_after"] > polish["median_px_before"]   # the detections disagree
    assert _error_mm(kept, biased_scene) < 0.3 * _error_mm(keypoints, biased_scene)
    assert "error vs ground truth" in printed
    # the 1-sigma written and printed is the polished pose's, not the keypoint fit's
    unc = kept["uncertainty"]
    assert unc["method"].startswith("jackknife of the silhouette polish")
    groups = unc["jackknife_left_out"]
    assert sum(g.startswith("frames ") for g in groups) == 5 and len(groups) >= 8
    assert not np.allclose(kept["covariance_xi"], keypoints["covariance_xi"])
    # the keypoint fit's own: the fit's and its jackknife's (--refine none adds the move
    # through the intrinsics the keypoints ask for)
    fit = keypoints["uncertainty"]
    np.testing.assert_allclose(unc["covariance_xi_keypoint_pose"],
                               np.add(fit["covariance_xi_fit"],
                                      fit["covariance_xi_keypoint_jackknife"]))
    np.testing.assert_allclose(kept["sigma_rotation_rad"],
                               np.sqrt(np.diag(kept["covariance_xi"])[:3]))
    sc = np.asarray(kept["sigma_camera_position_base_m"]) * 1e3
    assert f"(1-sigma {sc[0]:.2f}, {sc[1]:.2f}, {sc[2]:.2f} mm)" in printed
    assert "links and 5 frame groups left out in turn" in printed


def test_overlays_draw_the_outline_at_the_pose_written(biased_scene, tmp_path, capsys):
    _calibrate(biased_scene, tmp_path / "auto.json", capsys, "--overlays", str(tmp_path / "a"))
    _calibrate(biased_scene, tmp_path / "none.json", capsys, "--refine", "none", "--overlays",
               str(tmp_path / "n"))

    def on_mask_boundary(folder: Path) -> float:
        """The share of the outline's pixels within reach of the data mask's boundary."""
        image = cv2.cvtColor(cv2.imread(str(folder / "000002.result.png")), cv2.COLOR_BGR2RGB)
        outline = np.all(image == OUTLINE_RGB, axis=-1)
        mask = cv2.imread(str(biased_scene / "000002.seg.png"), cv2.IMREAD_UNCHANGED) > 0
        boundary = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_GRADIENT,
                                    np.ones((3, 3), np.uint8))
        near = cv2.dilate(boundary, np.ones((2 * OUTLINE_NEAR_MASK_PX + 1,) * 2, np.uint8)) > 0
        assert outline.sum() > 50
        return float(near[outline].mean())

    assert on_mask_boundary(tmp_path / "a") > 0.9 > on_mask_boundary(tmp_path / "n")
    summary = cv2.imread(str(tmp_path / "a" / "summary.png"))
    plain = cv2.imread(str(tmp_path / "n" / "summary.png"))
    # a legend band below the residuals, with a line for the keypoint pose where it moved
    assert summary.shape[0] > plain.shape[0] > read_sequence(biased_scene).camera.height


def test_dream_overlay_draws_a_results_pose(biased_scene, tmp_path, capsys):
    _calibrate(biased_scene, tmp_path / "auto.json", capsys)
    assert main(["overlay", str(biased_scene), "--extrinsic", str(tmp_path / "auto.json"),
                 "--out", str(tmp_path / "o"), "--limit", "2"]) == 0
    image = cv2.cvtColor(cv2.imread(str(tmp_path / "o" / "000000.overlay.png")),
                         cv2.COLOR_BGR2RGB)
    assert np.all(image == OUTLINE_RGB, axis=-1).sum() > 50


def test_each_frame_run_prints_its_errors_against_the_truth(biased_scene, tmp_path, capsys):
    doc, printed = _calibrate(biased_scene, tmp_path / "each.json", capsys, "--frames", "each",
                              "--refine", "none")
    assert f"error vs ground truth: reported frame {doc['reported_frame']}" in printed
    assert "median camera position" in printed
    assert doc["quality"]["verdict"] in ("good", "check", "unreliable")


def test_jackknife_covariance_is_the_spread_of_the_leave_outs():
    xis = np.array([[0, 0, 0, 0.002, 0, 0], [0, 0, 0, -0.002, 0, 0], [0, 0, 0, 0, 0, 0]],
                   dtype=float)
    cov = jackknife_covariance(xis)
    assert cov[3, 3] == pytest.approx(2 / 3 * 8e-6)
    assert np.count_nonzero(cov) == 1
    with pytest.raises(InputError):
        jackknife_covariance(np.zeros((3, 5)))


def test_group_jackknife_repeats_the_refinement_without_each_group():
    T = T_from_rotvec_t(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    shifts = {"a": 0.001, "b": -0.001, "c": 0.0, "d": None}

    def refine_without(link):
        if shifts[link] is None:
            return None
        return T_from_rotvec_t(np.zeros(3), np.array([shifts[link], 0.0, 1.0]))

    jk = group_jackknife(T, tuple(shifts), refine_without, "a test")
    assert jk.left_out == ("a", "b", "c")
    assert jk.covariance[3, 3] == pytest.approx(2 / 3 * 2e-6)
    assert group_jackknife(T, ("a", "d"), refine_without, "a test") is None
    with pytest.raises(InputError):
        RefinementJackknife(np.eye(6), ("a", "b"), "a test")
    both = combined(jk, None, jk)
    np.testing.assert_allclose(both.covariance, 2 * jk.covariance)
    assert both.left_out == ("a", "b", "c") * 2 and combined(None) is None


def test_frame_groups_leave_out_every_fifth_frame():
    groups = frame_groups(12)
    assert list(groups)[0] == "frames 0, 5, 10" and len(groups) == 5
    assert sorted(np.concatenate(list(groups.values()))) == list(range(12))
    assert len(frame_groups(3)) == 3 and frame_groups(2) == {}


def test_with_refined_uncertainty_replaces_the_keypoint_sigma():
    T = T_from_rotvec_t(np.zeros(3), np.array([0.1, 0.0, 1.0]))
    doc = {"T_cam_base": T.tolist(), "covariance_xi": np.eye(6).tolist(),
           "uncertainty": {"method": "fit + keypoint jackknife"}}
    kept = dict(doc)
    with_refined_uncertainty(kept, RefinementJackknife(np.eye(6) * 1e-8, ("a", "b", "c"), "x"))
    assert kept["uncertainty"]["method"] == "jackknife of x"
    np.testing.assert_allclose(kept["sigma_translation_m"], [1e-4] * 3)
    np.testing.assert_allclose(kept["uncertainty"]["covariance_xi_keypoint_pose"], np.eye(6))
    none = dict(doc)
    with_refined_uncertainty(none, None)
    assert "of the keypoint pose" in none["uncertainty"]["method"]
    assert none["covariance_xi"] == doc["covariance_xi"]
