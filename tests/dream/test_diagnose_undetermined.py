"""Parameters the data cannot determine: held at zero, and counted in the others' sigma.

A camera that moved sideways looks, in the keypoints, much like one that turned. The diagnosis
keeps one of the two and holds the other at zero; the one kept then absorbs the other's true
value, and its stated sigma must say so (`dream.diagnosis.fit.undetermined_covariance`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dream.diagnosis.fit import Model, candidate_params, fit_model, undetermined_covariance
from dream.diagnosis.run import diagnose_sequence, problem_from
from dream.extension import ModelExtension
from dream.inject import InjectionSettings, make_injected_sequence, random_effect
from dream.pipeline import observations_from_labels, robot_for, truth_poses
from dream.robot import load_robot

FRAMES = 60
NOISE_PX = (1.0, 2.0)
HUBER_PX = 1e6        # every residual weighted alike: the plain least-squares response
HELD_VALUE_M = 1e-3   # small enough for the response to be linear


def _case(effect: str | None, seed: int):
    rng = np.random.default_rng(seed)
    spec = InjectionSettings(num_frames=FRAMES, pixel_noise_px=float(rng.uniform(*NOISE_PX)),
                             seed=seed)
    truth = random_effect(effect, rng, load_robot(spec.robot), spec) if effect \
        else ModelExtension()
    seq = make_injected_sequence(spec, truth)
    return seq, robot_for(seq, None, seq.keypoint_names), truth


def test_the_covariance_is_the_estimates_response_to_the_held_parameter():
    """Data made with the held parameter (a sideways move) at a small value moves the fit of
    the others by B times that value: the covariance equals the response's outer product scaled
    to the parameter's typical magnitude."""
    seq, robot, _ = _case(None, 3)
    problem = problem_from(seq, robot, observations_from_labels(seq, robot))
    move = candidate_params("camera_moved", problem)
    held, kept = move[3], tuple(move[:3]) + tuple(move[4:])     # move.tx held
    T0, change = truth_poses(seq)[0], problem.num_frames // 2
    full = Model(problem, kept + (held,), T0, change)
    x_held = np.zeros(full.size)
    x_held[-1] = HELD_VALUE_M
    mask = problem.observed
    fits = []
    for x in (np.zeros(full.size), x_held):
        data = dataclasses.replace(problem, uv=full.predict(x))
        fits.append(fit_model(Model(data, kept, T0, change), mask, HUBER_PX))
    response = (fits[1].x - fits[0].x) / HELD_VALUE_M
    expected = np.outer(response, response) * held.typical ** 2
    got = undetermined_covariance(fits[0], (held,), mask, HUBER_PX)
    np.testing.assert_allclose(got, expected, atol=0.02 * np.abs(expected).max())
    assert np.abs(expected).max() > 0
    assert not undetermined_covariance(fits[0], (), mask, HUBER_PX).any()


def test_a_sideways_move_reported_as_a_turn_states_a_sigma_that_covers_the_truth():
    """A camera move of 6 mm and no turn: the diagnosis holds move.tx at zero and reports a turn
    about y. Its stated sigma includes what move.tx may be, so the true turn (none) is within
    3 sigmas; the fit's own sigma, which takes move.tx as known to be zero, puts it 8 sigmas
    away."""
    seq, robot, truth = _case("camera_moved", 11)
    doc, diagnosis, _ = diagnose_sequence(seq, robot, observations_from_labels(seq, robot))
    assert doc["verdict"] == ["camera_moved"]
    entry = next(e for e in doc["effects"] if e["name"] == "camera_moved")
    assert entry["identifiability"]["in_sigma"] == ["move.tx"]
    true_turn = np.asarray(truth.effect_params("camera_moved")["rotation_rad"])
    turn = np.asarray(entry["params"]["rotation_rad"])
    stated = np.array([entry["sigma"][c] for c in ("rx", "ry", "rz")])
    assert np.all(np.abs(turn - true_turn) <= 3 * stated)
    fit = diagnosis.final.fit
    own = np.array([fit.sigma[6 + i] for i, p in enumerate(fit.model.params)
                    if p.name in ("move.rx", "move.ry", "move.rz")])
    assert np.max(np.abs(turn - true_turn) / own) > 3
