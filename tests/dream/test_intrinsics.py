"""The intrinsics the robot's outlines ask for at the search's winner, adopted in turn
(`dream.coarse.intrinsics`): on masks rendered through the camera and given a principal point
off, the search adopts it and comes back to the truth; the order of the adoptions and the
unresolved principal point's veto, on the fits' decisions alone."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import dream.coarse.intrinsics as intrinsics
from dream.coarse.calibration import DATA_MASKS, SearchMasks
from dream.coarse.distortion import DistortionEstimate, with_corner_shift
from dream.coarse.focal import FocalEstimate, FocalSettings, with_focal_scale
from dream.coarse.intrinsics import adopted_camera, with_asked_intrinsics
from dream.coarse.principal import PrincipalEstimate, PrincipalSettings, with_principal_shift
from dream.coarse.search import find_winner
from dream.metrics import pose_errors
from tests.dream.test_coarse import SMALL, rendered_masks
from tests.dream.test_edges import CAMERA
from tests.dream.test_principal import FRAMES, GIVEN_OFF_PX, turned


def test_a_principal_point_given_off_is_adopted_and_the_search_comes_back(panda, meshes):
    """Given cx, cy 12, -8 px off, the search's winner is turned degrees off; the principal
    point asked for is adopted, the search again through it lands within 0.5 deg and 1 cm of
    the truth, and the adopted camera carries it; kept as given, the pose stays turned."""
    T_true, joints, masks = rendered_masks(panda, meshes, frames=FRAMES)
    given = with_principal_shift(CAMERA, GIVEN_OFF_PX)
    frames = np.arange(len(joints))
    inputs = SearchMasks(meshes, frames, joints, masks, DATA_MASKS, (), frames)
    winner = find_winner(meshes, joints, masks, given,
                         {"guess": turned(T_true, GIVEN_OFF_PX, CAMERA)[None]}, SMALL)
    assert np.rad2deg(pose_errors(winner.best.T_cam_base, T_true)[1]) > 2.0
    lines: list[str] = []
    outcome, adopted = with_asked_intrinsics(given, inputs, winner, SMALL,
                                             progress=lines.append)
    assert adopted.principal.adopted and adopted.principal.flagged
    assert "principal point: adopted, searching again with it" in lines
    t_err, r_err = pose_errors(outcome.best.T_cam_base, T_true)
    assert t_err < 0.01 and np.rad2deg(r_err) < 0.5, (t_err, np.rad2deg(r_err))
    camera = adopted_camera(given, adopted)
    assert abs(camera.cx - CAMERA.cx) < 1.0 and abs(camera.cy - CAMERA.cy) < 1.0
    assert adopted.principal.to_dict()["used"] == {"cx": camera.cx, "cy": camera.cy}
    # the adopted point's error turns the pose: at least the floor in the covariance
    assert np.sqrt(adopted.principal.pose_covariance[1, 1]) >= \
        PrincipalSettings().adopted_floor_rad
    kept_outcome, kept = with_asked_intrinsics(given, inputs, winner, SMALL,
                                               principal=PrincipalSettings(adopt=False))
    assert kept.principal.flagged and not kept.principal.adopted
    assert adopted_camera(given, kept) == given
    assert np.rad2deg(pose_errors(kept_outcome.best.T_cam_base, T_true)[1]) > 2.0


@pytest.fixture
def fakes(monkeypatch):
    """The two fits answering from queues of (scale, asked) and (shift, flagged,
    unresolved), and the search again recording its source and camera."""
    calls = SimpleNamespace(focal=[], principal=[], searched=[], asks_focal=[],
                            asks_principal=[], distortion=[], asks_distortion=[])

    def fit_distortion(P, meshes, masks, camera, T, settings, distortion, held, region):
        calls.distortion.append(camera)
        shift, asked = calls.asks_distortion.pop(0) if calls.asks_distortion else (0.0, False)
        return DistortionEstimate(shift, 0.001, 0.0, float("nan"), 0.5, 0.6, 1, asked,
                                  f"{shift}", with_corner_shift(camera, shift), camera,
                                  np.eye(4), np.zeros((6, 1)), np.full((1, 1), 0.005 ** 2))

    def fit_focal(P, meshes, masks, camera, T, settings, focal, held, region):
        calls.focal.append(camera)
        scale, asked = calls.asks_focal.pop(0)
        return FocalEstimate(scale, 0.001, 0.5, 0.6, 1, asked, f"x{scale}",
                             with_focal_scale(camera, scale), camera, np.eye(4), np.zeros(6),
                             0.005)

    def fit_principal(P, meshes, masks, camera, T, settings, principal, held, region):
        calls.principal.append(camera)
        shift, flagged, unresolved = calls.asks_principal.pop(0)
        return PrincipalEstimate(np.asarray(shift, float), np.full(2, 0.5), 0.05, 1, flagged,
                                 "p", camera, np.eye(4), np.zeros(6), unresolved=unresolved)

    def searched_again(camera, inputs, winner, T_start, source, settings, progress=None):
        calls.searched.append((source, camera))
        return winner

    monkeypatch.setattr(intrinsics, "fit_distortion", fit_distortion)
    monkeypatch.setattr(intrinsics, "fit_focal", fit_focal)
    monkeypatch.setattr(intrinsics, "fit_principal", fit_principal)
    monkeypatch.setattr(intrinsics, "searched_again", searched_again)
    monkeypatch.setattr(intrinsics, "vertices_in_base", lambda meshes, joints: None)
    return calls


def _run(fakes, focal_asks, principal_asks, principal=None):
    """`with_asked_intrinsics` on the fakes' answers, from a winner the robot was found at."""
    fakes.asks_focal[:] = focal_asks
    fakes.asks_principal[:] = principal_asks
    best = SimpleNamespace(iou=0.9, T_cam_base=np.eye(4))
    winner = SimpleNamespace(best=best, checked=lambda: "checked")
    one = np.arange(1)
    inputs = SearchMasks(None, one, None, None, DATA_MASKS, (), one)
    return with_asked_intrinsics(CAMERA, inputs, winner, SMALL, FocalSettings(),
                                 principal or PrincipalSettings())


def test_a_distortion_asked_for_goes_first_and_the_rest_is_fitted_through_it(fakes):
    """The lens's radial distortion is adopted before anything else (left out, it bends the
    outlines in ways a principal point and a focal length partly make up for): the search
    runs again through it, and the focal length and the principal point are fitted through
    the camera with it; the adopted camera carries it."""
    fakes.asks_distortion[:] = [(-0.15, True)]
    outcome, inputs = _run(fakes, [(1.0, False)], [((0.0, 0.0), False, False)])
    assert outcome == "checked" and [s for s, _ in fakes.searched] == ["distortion"]
    with_lens = with_corner_shift(CAMERA, -0.15)
    assert fakes.searched[0][1] == with_lens
    assert fakes.focal == [with_lens] and fakes.principal == [with_lens]
    assert inputs.distortion.adopted
    assert adopted_camera(CAMERA, inputs).distortion == with_lens.distortion
    fakes.searched.clear()
    fakes.asks_distortion[:] = [(-0.15, False)]                   # asked, not adopted
    _, kept = _run(fakes, [(1.0, False)], [((0.0, 0.0), False, False)])
    assert not fakes.searched and adopted_camera(CAMERA, kept) == CAMERA


def test_an_unresolved_principal_point_vetoes_the_focal_length(fakes):
    outcome, inputs = _run(fakes, [(0.95, True)], [((20.0, -10.0), False, True)])
    assert outcome == "checked" and not fakes.searched
    assert not inputs.focal.adopted and "unresolved" in inputs.focal.reason
    # the principal point was fitted through the focal length asked for
    assert fakes.principal[0].fx == pytest.approx(0.95 * CAMERA.fx)


def test_a_flagged_principal_point_goes_first_and_alone(fakes):
    """Asked for beside a focal length, the principal point is adopted alone, on the given
    focal length; the focal length fitted again through it is adopted in a second search."""
    _, inputs = _run(fakes, [(0.95, True), (0.97, True)], [((12.0, -8.0), True, False)])
    assert [source for source, _ in fakes.searched] == ["principal", "focal"]
    first = fakes.searched[0][1]
    assert (first.fx, first.cx, first.cy) == (CAMERA.fx, CAMERA.cx + 12, CAMERA.cy - 8)
    assert fakes.focal[1] == first          # the focal length fitted again through it
    camera = adopted_camera(CAMERA, inputs)
    assert camera.fx == pytest.approx(0.97 * CAMERA.fx) and camera.cx == CAMERA.cx + 12
    assert inputs.principal.adopted and inputs.focal.adopted
    assert len(fakes.principal) == 1        # nothing adopted twice


def test_a_focal_length_goes_where_the_principal_point_stands(fakes):
    """The focal length asked for is adopted; the principal point fitted again at the new
    winner through it is adopted in turn where it is a finding there."""
    _, inputs = _run(fakes, [(0.95, True)], [((0.5, 0.2), False, False),
                                              ((12.0, -8.0), True, False)])
    assert [source for source, _ in fakes.searched] == ["focal", "principal"]
    assert fakes.principal[1].fx == pytest.approx(0.95 * CAMERA.fx)
    camera = adopted_camera(CAMERA, inputs)
    assert camera.fx == pytest.approx(0.95 * CAMERA.fx) and camera.cx == CAMERA.cx + 12


def test_a_principal_point_kept_as_given_leaves_the_focal_length_to_its_rule(fakes):
    _, inputs = _run(fakes, [(0.95, True)], [((12.0, -8.0), True, False),
                                              ((0.3, 0.1), False, False)],
                     principal=PrincipalSettings(adopt=False))
    assert [source for source, _ in fakes.searched] == ["focal"]
    assert inputs.focal.adopted and not inputs.principal.adopted
    assert adopted_camera(CAMERA, inputs) == replace(CAMERA, fx=0.95 * CAMERA.fx,
                                                     fy=0.95 * CAMERA.fy)
