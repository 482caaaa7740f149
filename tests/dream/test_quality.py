"""The quality verdict of a calibration (`dream.quality`): kept share, condition, duplicate
frames, a static arm."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dream.calibration import Observations
from dream.cli import main
from dream.errors import InputError
from dream.quality import (
    CHECK,
    GOOD,
    MIN_KEPT_SHARE,
    UNRELIABLE,
    Quality,
    camera_position_covariance,
    condition_findings,
    duplicate_finding,
    frames_agreement_finding,
    kept_finding,
    quality_from,
    static_finding,
)
from dream.transforms import R_from_rotvec, invert_T, look_at


def test_a_fit_on_a_small_consensus_is_unreliable():
    level, text = kept_finding(70, 20)
    assert level == UNRELIABLE and "20 of 70" in text and "--polish" in text
    assert kept_finding(100, int(100 * MIN_KEPT_SHARE)) is None
    assert kept_finding(0, 0)[0] == UNRELIABLE
    q = quality_from(70, 20, [kept_finding(70, 20)])
    assert q.verdict == UNRELIABLE and q.kept_share == pytest.approx(20 / 70)


def test_a_kept_image_refinement_softens_the_verdict_but_the_warning_stays():
    q = quality_from(70, 20, [kept_finding(70, 20, refined_by="the edge alignment")])
    assert q.verdict == CHECK and "the edge alignment" in q.warnings[0]
    assert q.to_dict() == {"detections": 70, "kept": 20, "kept_share": 20 / 70,
                           "verdict": CHECK, "warnings": list(q.warnings)}
    assert quality_from(70, 60, [None]).verdict == GOOD


def test_quality_checks_its_input():
    with pytest.raises(InputError, match="kept"):
        Quality(10, 11, GOOD, ())
    with pytest.raises(InputError, match="verdict"):
        Quality(10, 5, "fine", ())
    with pytest.raises(InputError, match="min_kept_share"):
        kept_finding(10, 5, min_kept_share=0.0)


def _camera_centre(T_cam_base: np.ndarray) -> np.ndarray:
    return invert_T(T_cam_base)[:3, 3]


def test_camera_position_covariance_matches_finite_differences():
    """The Jacobian of the camera centre (camera axes) with respect to the fit's parameters
    (rotation about, translation along the camera axes), by finite differences."""
    T = look_at(np.array([1.2, -0.4, 0.9]), np.array([0.0, 0.1, 0.4]), 0.2)
    R, c0 = T[:3, :3], _camera_centre(T)
    eps, J = 1e-7, np.zeros((3, 6))
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = eps
        T2 = T.copy()
        T2[:3, :3] = R_from_rotvec(xi[:3]) @ R
        T2[:3, 3] = T[:3, 3] + xi[3:]
        J[:, k] = R @ (_camera_centre(T2) - c0) / eps
    for k in range(6):
        e = np.zeros((6, 6))
        e[k, k] = 1.0
        assert np.allclose(camera_position_covariance(e, T), np.outer(J[:, k], J[:, k]),
                           atol=1e-6)


def test_condition_names_the_poorly_constrained_direction():
    T = look_at(np.array([1.5, 0.0, 0.5]), np.array([0.0, 0.0, 0.5]), 0.0)
    depth = np.diag([1e-8] * 3 + [1e-8, 1e-8, 0.02 ** 2])     # 20 mm along the optical axis
    (level, text), = condition_findings(depth, T)
    assert level == CHECK and "depth along the camera axis" in text and "20.0 mm" in text
    across = np.diag([1e-8] * 3 + [0.08 ** 2, 1e-8, 1e-8])    # 80 mm sideways
    (level, text), = condition_findings(across, T)
    assert level == UNRELIABLE and "across the view" in text
    assert condition_findings(np.diag([1e-8] * 6), T) == []
    rotation = np.diag([np.deg2rad(2.0) ** 2, 1e-8, 1e-8, 1e-8, 1e-8, 1e-8])
    assert any("rotation 1-sigma 2.00 deg" in t for _, t in condition_findings(rotation, T))


def _observations(P_base: np.ndarray, uv: np.ndarray) -> Observations:
    F, K = uv.shape[:2]
    return Observations(P_base, uv, np.ones((F, K)), tuple(f"{i:06d}" for i in range(F)),
                        tuple(f"k{i}" for i in range(K)))


def test_duplicate_and_static_frames():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(5, 7, 3))
    uv = rng.uniform(0, 300, (5, 7, 2))
    assert duplicate_finding(_observations(P, uv)) is None
    assert static_finding(_observations(P, uv)) is None
    P[3], uv[3] = P[1], uv[1] + 0.01                     # frame 3 repeats frame 1
    level, text = duplicate_finding(_observations(P, uv))
    assert level == CHECK and text.startswith("1 of 5 frames")
    uv[3] = uv[1] + 20.0                                 # same readings, another image
    assert duplicate_finding(_observations(P, uv)) is None
    still = np.repeat(P[:1], 5, axis=0) + rng.normal(0, 1e-4, (5, 7, 3))
    level, text = static_finding(_observations(still, np.repeat(uv[:1], 5, axis=0) + 0.5))
    assert level == CHECK and "add no geometry" in text
    level, text = static_finding(_observations(still, uv))   # the arm moves in the images
    assert level == UNRELIABLE and "joint log is frozen" in text


def test_calibrate_writes_the_verdict(tmp_path, capsys):
    """Keypoints only from six frames: they ask for a focal length 1 % shorter within their
    noise, and its move along the camera's axis, in the 1-sigma, makes the verdict `check`."""
    from dream.robot import load_robot
    from dream.silhouette import load_robot_meshes
    from tests.dream.test_polish import masked_dataset

    panda = load_robot("panda")
    masked_dataset(panda, load_robot_meshes(panda), tmp_path)
    result = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--refine",
                 "none", "--out", str(result)])
    out, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(result.read_text())
    quality = doc["quality"]
    assert quality["verdict"] == CHECK and len(quality["warnings"]) == 1
    assert "depth along the camera axis" in quality["warnings"][0]
    assert doc["uncertainty"]["keypoint_intrinsics_added"] == ["focal length"]
    assert quality["detections"] == sum(f["keypoints_found"] for f in doc["per_frame"])
    assert quality["kept"] == doc["keypoints_used"]
    assert "quality: check" in out


def test_static_frames_are_named(tmp_path, capsys):
    """Twelve frames of one configuration, each with its own 1 px detection noise: one view's
    geometry, a 1-sigma of centimetres."""
    data = tmp_path / "static"
    assert main(["sample", "--out", str(data), "--num", "12", "--seed", "3"]) == 0
    first = json.loads((data / "000000.json").read_text())
    rng = np.random.default_rng(1)
    for path in sorted(data.glob("0*.json")):
        doc = json.loads(path.read_text())
        doc["sim_state"]["joints"] = first["sim_state"]["joints"]
        doc["objects"][0]["keypoints"] = json.loads(json.dumps(first["objects"][0]["keypoints"]))
        for keypoint in doc["objects"][0]["keypoints"]:
            keypoint["projected_location"] = (np.asarray(keypoint["projected_location"])
                                              + rng.normal(0, 1.0, 2)).tolist()
        path.write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(["calibrate", "--data", str(data), "--use-labels", "--out",
                 str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    quality = json.loads((tmp_path / "r.json").read_text())["quality"]
    assert quality["verdict"] == CHECK and "quality: check" in out
    assert any("add no geometry" in w for w in quality["warnings"])
    assert any("poorly constrained" in w for w in quality["warnings"])


def test_a_per_frame_result_is_judged_by_its_own_sigma_and_the_frames_agreement(rng):
    """`--frames each` on detections 20 px off: the reported frame's own 1-sigma and the
    spread of the other frames' poses keep the verdict from `good`; on exact detections it is
    `good`."""
    from scenes import CAMERA, random_scene

    from dream.calibration import calibrate_each
    from dream.quality import result_quality

    obs, _, _ = random_scene(rng, frames=8, noise_px=20.0)
    noisy = result_quality(calibrate_each(obs, CAMERA), obs)
    assert noisy.verdict != GOOD
    assert any("frames' poses lie" in w for w in noisy.warnings)
    assert any("1-sigma" in w for w in noisy.warnings)
    exact, _, _ = random_scene(rng, frames=8)
    assert result_quality(calibrate_each(exact, CAMERA), exact).verdict == GOOD


def test_frames_agreement_finding_reads_the_poses_written():
    T = look_at(np.array([1.5, 0.0, 1.0]), np.array([0.0, 0.0, 0.4]), 0.0)
    near = T.copy()
    near[0, 3] += 0.003
    far = T.copy()
    far[0, 3] += 0.08
    nan = np.full((4, 4), np.nan)
    assert frames_agreement_finding(T, np.stack([T, near, near, nan])) is None
    level, text = frames_agreement_finding(T, np.stack([T, far, far, near, nan]))
    assert level == CHECK and "the other 3 frames' poses lie a median 80.0 mm" in text
    assert frames_agreement_finding(T, np.stack([T, far])) is None   # too few to judge
    with pytest.raises(InputError, match="frame poses"):
        frames_agreement_finding(T, np.zeros((3, 3, 3)))
