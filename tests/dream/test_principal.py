"""The principal point the robot's outlines ask for (`dream.coarse.principal`): on masks rendered
through the camera, given cx, cy off the fit asks for the shift back, its pose returns near the
truth and the verdict says so; given them right, nothing is flagged."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from dream.cli import main
from dream.coarse.camera_fit import principal_turn
from dream.coarse.principal import (
    PrincipalSettings,
    _decision,
    fit_principal,
    with_principal_shift,
)
from dream.coarse.scales import finish_scale
from dream.coarse.settings import SearchSettings
from dream.coarse.verdict import principal_finding
from dream.errors import InputError
from dream.metrics import pose_errors
from dream.pnp import increment_between
from dream.silhouette import vertices_in_base
from tests.dream.test_coarse import GUESS_M, GUESS_RAD, off_by, rendered_masks
from tests.dream.test_edges import CAMERA, TARGET, image_dataset

GIVEN_OFF_PX = np.array([12.0, -8.0])   # the principal point given this far from the rendered
CLI_OFF_PX = np.array([24.0, -16.0])    # the same through the motion masks of a few grey frames
FRAMES = 12


def turned(T_cam_base: np.ndarray, shift_px: np.ndarray, camera) -> np.ndarray:
    """The camera turned so that its image centre moves by -shift_px (`principal_turn`): to
    first order what a principal point `shift_px` off asks of the pose (the search's optimum
    lies near it)."""
    C = np.eye(4)
    C[:3, :3] = principal_turn(camera, shift_px)
    return C @ T_cam_base


@pytest.fixture(scope="module")
def scene(panda, meshes):
    T_true, joints, masks = rendered_masks(panda, meshes, frames=FRAMES)
    return T_true, vertices_in_base(meshes, joints), masks


def test_a_principal_point_given_off_is_asked_back_and_flagged(meshes, scene):
    """Through the camera as given, the finish turns the camera by about atan(shift / f); the
    joint fit asks for the shift back within a pixel, its pose lies near the truth, and the
    move enters the covariance."""
    T_true, P, masks = scene
    given = with_principal_shift(CAMERA, GIVEN_OFF_PX)
    T_given = finish_scale(P, meshes, masks, given, SearchSettings()).refine(
        turned(T_true, GIVEN_OFF_PX, CAMERA))
    assert np.rad2deg(pose_errors(T_given, T_true)[1]) > 2.0
    estimate = fit_principal(P, meshes, masks, given, T_given, SearchSettings())
    np.testing.assert_allclose(estimate.shift_px, -GIVEN_OFF_PX, atol=1.0)
    assert estimate.flagged, estimate.reason
    assert np.all(estimate.sigma_px > 0) and np.all(estimate.sigma_px < 1.0)
    assert np.rad2deg(pose_errors(estimate.T_cam_base, T_true)[1]) < 0.5
    covariance = estimate.pose_covariance
    np.testing.assert_allclose(covariance, np.outer(estimate.xi, estimate.xi) + estimate.spread)
    assert np.all(np.linalg.eigvalsh(estimate.spread) > -1e-12) and estimate.spread.trace() > 0
    # the truth lies one move along xi from the given camera's pose, little beside it (the
    # rotation and the translation apart)
    offset = increment_between(T_given, T_true)
    for part in (slice(0, 3), slice(3, 6)):
        xi = estimate.xi[part]
        along = offset[part] @ xi / (xi @ xi)
        assert along == pytest.approx(1.0, abs=0.1), part
        assert np.linalg.norm(offset[part] - along * xi) < 0.1 * np.linalg.norm(xi), part
    assert np.sqrt(covariance[:3, :3].trace()) > np.deg2rad(2.0)   # the turn, in the 1-sigma
    doc = estimate.to_dict()
    assert doc["asked"]["cx"] == pytest.approx(given.cx + estimate.shift_px[0])
    assert doc["iou_asked"] > doc["iou_given"]        # the overlap agrees
    level, warning = principal_finding(doc)
    assert level == "check" and "calibrated cx, cy" in warning


def test_the_shift_s_1_sigma_holds_the_links_spread_besides_the_frames(meshes, scene):
    """A principal point moves every link's outline alike, a joint reading that is off only
    those beyond it: the shift's 1-sigma and the pose's spread hold the jackknife over the
    links on top of that over the frame groups."""
    from unittest import mock

    from dream.coarse import principal

    T_true, P, masks = scene
    given = with_principal_shift(CAMERA, GIVEN_OFF_PX)
    scales = finish_scale(P, meshes, masks, given, SearchSettings())
    T = scales.refine(turned(T_true, GIVEN_OFF_PX, CAMERA))
    objective = principal.finest_objective(scales)
    both = principal._jackknife(objective, scales, T, PrincipalSettings(), FRAMES, meshes)
    with mock.patch.object(principal, "link_keeps", lambda contour, meshes: None):
        frames = principal._jackknife(objective, scales, T, PrincipalSettings(), FRAMES, meshes)
    assert np.all(both[0] > frames[0]) and np.all(np.isfinite(both[0]))
    assert np.all(np.linalg.eigvalsh(both[1] - frames[1]) > -1e-12)
    assert both[1].trace() > frames[1].trace()


def test_a_principal_point_given_right_stands(meshes, scene):
    T_true, P, masks = scene
    estimate = fit_principal(P, meshes, masks, CAMERA, T_true, SearchSettings())
    assert np.all(np.abs(estimate.shift_px) < 1.0), estimate.shift_px
    assert not estimate.flagged and "stand" in estimate.reason
    assert not estimate.pose_covariance.any()
    assert principal_finding(estimate.to_dict()) is None


def test_the_decision_needs_a_turn_beyond_the_limit_and_the_noise_and_nothing_carried():
    settings = PrincipalSettings()
    big = np.deg2rad(3.0)
    off, tight = np.array([12.0, -8.0]), np.array([0.3, 0.3])
    assert _decision(off, tight, big, False, settings)[0]
    assert not _decision(np.array([2.0, 1.0]), np.full(2, np.nan), np.deg2rad(0.5), False,
                         settings)[0]                          # within the angle limit
    flagged, reason = _decision(off, np.array([5.0, 5.0]), big, False, settings)
    assert not flagged and "within 3 sigma" in reason          # within the noise
    assert not _decision(off, np.full(2, np.nan), big, False, settings)[0]
    flagged, reason = _decision(off, tight, big, True, settings)
    assert not flagged and reason.startswith("not judged")     # something carried pulls it
    assert _decision(off, tight, big, False, settings, (0.60, 0.65))[0]
    flagged, reason = _decision(off, tight, big, False, settings, (0.469, 0.468))
    assert not flagged and "the overlap does not agree" in reason   # the second cue refuses



@pytest.mark.parametrize("field, value", [("rounds", 0), ("min_sigmas", -1.0),
                                          ("min_angle_rad", 0.0), ("derivative_step_px", -1.0)])
def test_settings_out_of_range_are_refused(field, value):
    with pytest.raises(InputError, match=field):
        PrincipalSettings(**{field: value})


def test_calibrate_records_the_check_and_a_flag_reaches_the_verdict_and_1_sigma(
        panda, meshes, tmp_path, capsys, monkeypatch):
    """Images only (motion masks of a few grey frames, too few to resolve the principal
    point): RESULT.json records the check, nothing flagged; with the check's estimate flagged
    and kept (`--fixed-principal`), the verdict names it and the covariance holds its move;
    adopted (the default), the pose is found through it, RESULT.json and the verdict say
    so, and the covariance holds the turn of its error."""
    T_true = image_dataset(panda, meshes, tmp_path)
    position = np.linalg.inv(off_by(T_true, GUESS_M, GUESS_RAD, 3))[:3, 3]
    argv = ["calibrate", "--data", str(tmp_path / "data"), "--camera-guess",
            ",".join(f"{v:.3f}" for v in position),
            "--look-at", ",".join(f"{v:.3f}" for v in TARGET), "--out"]
    assert main(argv + [str(tmp_path / "r.json")]) == 0, capsys.readouterr()[1]
    doc = json.loads((tmp_path / "r.json").read_text())
    principal = doc["start"]["principal"]
    assert not principal["flagged"] and len(principal["shift_px"]) == 2
    assert principal["given"] == {"cx": CAMERA.cx, "cy": CAMERA.cy}
    assert not any("principal point" in w for w in doc["quality"]["warnings"])
    capsys.readouterr()

    from dream.coarse import intrinsics

    def flagged(*args, **kwargs):
        estimate = fit_principal(*args, **kwargs)
        return replace(estimate, flagged=True, unresolved=False,
                       shift_px=np.array([3.0, -2.0]), xi=np.array([0.03, 0, 0, 0, 0, 0.0]))

    monkeypatch.setattr(intrinsics, "fit_principal", flagged)
    assert main(argv + [str(tmp_path / "f.json"), "--fixed-principal"]) == 0, \
        capsys.readouterr()[1]
    doc = json.loads((tmp_path / "f.json").read_text())
    principal = doc["start"]["principal"]
    assert principal["flagged"] and not principal["adopted"]
    assert principal["used"] == {"cx": CAMERA.cx, "cy": CAMERA.cy}
    assert doc["quality"]["verdict"] != "good"
    assert any("principal point" in w for w in doc["quality"]["warnings"])
    assert np.asarray(doc["covariance_xi"])[0, 0] >= 0.03 ** 2
    capsys.readouterr()

    assert main(argv + [str(tmp_path / "a.json")]) == 0, capsys.readouterr()[1]
    printed = capsys.readouterr()[0]
    doc = json.loads((tmp_path / "a.json").read_text())
    principal = doc["start"]["principal"]
    assert principal["adopted"] and "162.50, 117.50, fitted to the robot" in printed
    assert principal["used"] == {"cx": CAMERA.cx + 3.0, "cy": CAMERA.cy - 2.0}
    assert doc["quality"]["verdict"] == "check"
    assert any("--fixed-principal" in w for w in doc["quality"]["warnings"])
    floor_rad = PrincipalSettings().adopted_floor_rad
    assert np.sqrt(np.asarray(doc["covariance_xi"])[1, 1]) >= floor_rad
    from dream.result import adopted_intrinsics

    assert principal["used"].items() <= adopted_intrinsics(doc).items()


def test_the_keypoint_paths_crosscheck_checks_the_principal_point_on_the_outlines(
        panda, meshes, tmp_path, capsys, monkeypatch):
    """The keypoint path (labels, the default refinement): the silhouettes' cross-check
    records the principal point the outlines ask for at its optimum, nothing flagged; with
    the estimate flagged and `--fixed-principal`, the verdict names it and the written
    covariance holds its move."""
    image_dataset(panda, meshes, tmp_path)
    argv = ["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--out"]
    assert main(argv + [str(tmp_path / "r.json")]) == 0, capsys.readouterr()[1]
    doc = json.loads((tmp_path / "r.json").read_text())
    principal = doc["silhouette_check"]["principal"]
    assert not principal["flagged"] and principal["given"] == {"cx": CAMERA.cx, "cy": CAMERA.cy}
    assert not any("principal point" in w for w in doc["quality"]["warnings"])
    printed = capsys.readouterr()[0]
    assert "intrinsics on the outlines: the given distortion stands" in printed
    assert "; the given fx, fy stand" in printed
    assert "the given cx, cy stand" in printed

    from dream.coarse import crosscheck
    from dream.pnp import apply_increment

    turn = np.array([0.03, 0, 0, 0, 0, 0.0])

    def flagged(*args, **kwargs):       # the pose through the asked point 0.03 rad away
        estimate = fit_principal(*args, **kwargs)
        return replace(estimate, flagged=True, xi=turn,
                       T_cam_base=apply_increment(args[4], turn))

    monkeypatch.setattr(crosscheck, "fit_principal", flagged)
    assert main(argv + [str(tmp_path / "f.json"), "--fixed-principal"]) == 0, \
        capsys.readouterr()[1]
    flagged_doc = json.loads((tmp_path / "f.json").read_text())
    assert "principal" not in flagged_doc      # kept as given: a finding, not adopted
    assert flagged_doc["silhouette_check"]["principal"]["flagged"]
    assert flagged_doc["quality"]["verdict"] != "good"
    assert any("principal point" in w for w in flagged_doc["quality"]["warnings"])
    assert (np.asarray(flagged_doc["covariance_xi"])[0, 0]
            >= np.asarray(doc["covariance_xi"])[0, 0] + 0.03 ** 2 - 1e-12)
    assert "intrinsics the outlines ask for" in flagged_doc["uncertainty"]["method"]


def test_the_keypoint_paths_crosscheck_names_a_focal_length_the_outlines_ask_for(
        panda, meshes, tmp_path, capsys, monkeypatch):
    """Where the outlines at the cross-check's optimum ask for another focal length (and the
    overlap agrees) and `--fixed-focal` keeps the given one, the verdict names it, the pose
    written stays, and the covariance holds the move to the pose through the asked focal
    length."""
    image_dataset(panda, meshes, tmp_path)
    argv = ["calibrate", "--data", str(tmp_path / "data"), "--use-labels", "--out"]
    assert main(argv + [str(tmp_path / "r.json")]) == 0, capsys.readouterr()[1]
    doc = json.loads((tmp_path / "r.json").read_text())
    assert not doc["silhouette_check"]["focal"]["asked"]
    assert not any("focal length" in w for w in doc["quality"]["warnings"])

    from dream.coarse import crosscheck
    from dream.coarse.focal import fit_focal

    def asked(*args, **kwargs):
        estimate = fit_focal(*args, **kwargs)
        T = estimate.T_cam_base.copy()
        T[2, 3] += 0.03                         # the pose through it 3 cm along the axis
        # the scale's sensitivity is measured only where it is asked for: made up here
        return replace(estimate, adopted=True, scale=0.95, T_cam_base=T,
                       xi_per_log_scale=np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.5]))

    monkeypatch.setattr(crosscheck, "fit_focal", asked)
    assert main(argv + [str(tmp_path / "f.json"), "--fixed-focal"]) == 0, \
        capsys.readouterr()[1]
    asked_doc = json.loads((tmp_path / "f.json").read_text())
    assert "focal" not in asked_doc            # kept as given: a finding, not adopted
    focal = asked_doc["silhouette_check"]["focal"]
    assert focal["asked"] and not focal["adopted"] and focal["used"] == focal["given"]
    assert asked_doc["T_cam_base"] == doc["T_cam_base"]
    assert asked_doc["quality"]["verdict"] != "good"
    assert any("ask for a focal length x0.950" in w for w in asked_doc["quality"]["warnings"])
    assert (np.asarray(asked_doc["covariance_xi"])[5, 5]
            >= np.asarray(doc["covariance_xi"])[5, 5] + 0.02 ** 2)


def test_an_adopted_principal_point_s_1_sigma_turns_the_pose_about_the_camera_centre():
    """`adopted_covariance`: a 1-sigma in du alone turns the camera about its y axis by
    atan(sigma / fx), and about its centre: the camera's position in the base frame keeps no
    variance, its translation in camera axes does."""
    from dream.coarse.principal import adopted_covariance
    from dream.transforms import camera_position_covariance

    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 1.4]
    C = adopted_covariance(CAMERA, T, np.array([2.0, 0.0]))
    assert np.sqrt(C[1, 1]) == pytest.approx(np.arctan(2.0 / CAMERA.fx), rel=1e-3)
    assert C[0, 0] == pytest.approx(0.0, abs=1e-15) and np.linalg.matrix_rank(C) == 1
    assert np.sqrt(C[3, 3]) == pytest.approx(1.4 * np.arctan(2.0 / CAMERA.fx), rel=1e-2)
    position = camera_position_covariance(T, C)       # to first order in the turn: none
    assert np.sqrt(np.max(np.diag(position))) < 0.01 * np.sqrt(C[3, 3])
    with pytest.raises(ValueError, match="shape"):
        adopted_covariance(CAMERA, T, np.array([1.0, 2.0, 3.0]))


def test_an_unresolved_principal_point_leaves_its_turn_in_the_1_sigma_and_the_verdict():
    """A turn beyond the limit that the outlines do not resolve is neither adopted nor
    dropped: the move to the pose through the asked point, that pose's spread and the turn of
    a point as far off as asked enter the covariance, and the verdict names it; a turn within
    the limit adds nothing."""
    from dream.coarse.principal import PrincipalEstimate, adopted_covariance

    xi, spread = np.array([0.0, 0.05, 0.0, 0.01, 0.0, 0.0]), np.diag([1e-4] * 6)
    asked = PrincipalEstimate(np.array([12.0, -8.0]), np.array([6.0, 5.0]), 0.05, 3, False,
                              "within 3 sigma", CAMERA, np.eye(4), xi, spread=spread,
                              unresolved=True)
    turn = adopted_covariance(CAMERA, np.eye(4), np.array([12.0, 8.0]))
    np.testing.assert_allclose(asked.pose_covariance, np.outer(xi, xi) + spread + turn)
    assert np.sqrt(asked.pose_covariance[1, 1]) > np.arctan(12.0 / CAMERA.fx)
    level, warning = principal_finding(asked.to_dict())
    assert level == "check" and "do not resolve it" in warning and "2.9 deg" in warning
    standing = replace(asked, unresolved=False, angle_rad=0.01)
    assert not standing.pose_covariance.any() and principal_finding(standing.to_dict()) is None
