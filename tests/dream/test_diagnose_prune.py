"""Pruning the accepted effects: once a later effect is accepted, the groups of the earlier
ones that only stood in for it no longer differ from zero and are dropped.

Wrist joint offsets, for example, can mimic a hand keypoint's bias: accepted first, the joint
offset keeps them beside the true one; once the bias is accepted they are redundant, and left
in they bias its estimate.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dream.diagnosis.fit import Model, Param, group_p_values
from dream.diagnosis.run import diagnose_sequence, problem_from
from dream.diagnosis.score import score_diagnosis
from dream.diagnosis.select import DiagnoseSettings, evaluate, first_implausible, prune_accepted
from dream.diagnosis.select.prune import redundant_effects
from dream.extension import ModelExtension
from dream.inject import InjectionSettings, make_injected_sequence
from dream.pipeline import observations_from_labels, robot_for, truth_poses

NOISE_PX = 1.5
SCALE_PX = 2 * NOISE_PX   # the Huber scale the diagnosis would take (2 robust sigmas)
# a joint offset and a hand keypoint bias of the size the identification benchmark draws
JOINT3_OFFSET_RAD = 0.045
HAND_BIAS_M = (0.0019, -0.0020, -0.0115)


def _sequence(truth: ModelExtension, seed: int, frames: int = 150):
    spec = InjectionSettings(num_frames=frames, pixel_noise_px=NOISE_PX, seed=seed)
    seq = make_injected_sequence(spec, truth)
    robot = robot_for(seq, None, seq.keypoint_names)
    return seq, robot


def _fitted(truth: ModelExtension, params: list[Param], seed: int):
    """The extrinsic and `params` fitted to a sequence hiding `truth`, cross-validated."""
    seq, robot = _sequence(truth, seed)
    problem = problem_from(seq, robot, observations_from_labels(seq, robot))
    settings = DiagnoseSettings()
    model = Model(problem, tuple(params), truth_poses(seq)[0])   # the camera is fixed
    return evaluate("test", model, problem.observed, SCALE_PX, settings), settings, problem


def _joint(name: str) -> Param:
    return Param("joint_offset", name, name, np.deg2rad(1.0))


def _lens() -> list[Param]:
    return [Param("lens_distortion", k, k, 0.05) for k in ("k1", "k2")]


def _bias(keypoint: str) -> list[Param]:
    return [Param("keypoint_bias", keypoint, f"{keypoint}.{a}", 0.01) for a in "xyz"]


@pytest.mark.parametrize("seed", [3, 4])
def test_groups_of_an_accepted_effect_that_a_later_one_explains_are_dropped(seed):
    truth = ModelExtension(joint_offset_rad={"panda_joint3": JOINT3_OFFSET_RAD},
                           keypoint_bias_m={"panda_hand": HAND_BIAS_M})
    params = [_joint(j) for j in ("panda_joint3", "panda_joint5", "panda_joint6")]
    current, settings, problem = _fitted(truth, params + _bias("panda_hand"), seed)
    pruned, dropped = prune_accepted(current, ["joint_offset", "keypoint_bias"],
                                     problem.observed, SCALE_PX, settings)
    assert sorted(dropped) == [("joint_offset", "panda_joint5"), ("joint_offset", "panda_joint6")]
    assert [p.group for p in pruned.fit.model.params] == ["panda_joint3"] + ["panda_hand"] * 3
    assert pruned.heldout_cost.shape == (problem.num_frames,)
    x = pruned.fit.x[6:]
    assert x[0] == pytest.approx(JOINT3_OFFSET_RAD, abs=3 * pruned.fit.sigma[6])
    np.testing.assert_allclose(x[1:], HAND_BIAS_M, atol=3 * pruned.fit.sigma[7:].max())


def test_an_effect_keeps_its_last_group():
    """Pruning never removes an effect (that is the held-out test's verdict): of two null joint
    offsets beside a lens one is dropped and the other kept, though it is zero too (and named
    as redundant); the lens's redundant k2 is dropped."""
    truth = ModelExtension(distortion=(0.05, 0.0, 0.0, 0.0))
    joints = [_joint("panda_joint5"), _joint("panda_joint6")]
    current, settings, problem = _fitted(truth, _lens() + joints, seed=5)
    effects = ["lens_distortion", "joint_offset"]
    pruned, dropped = prune_accepted(current, effects, problem.observed, SCALE_PX, settings)
    assert ("lens_distortion", "k2") in dropped and len(dropped) == 2
    (p_kept,) = group_p_values(pruned.fit, "joint_offset").values()
    assert p_kept > settings.group_alpha
    assert redundant_effects(pruned.fit, effects, settings.group_alpha) == ["joint_offset"]


def test_a_group_stays_while_a_group_that_enters_after_it_does():
    """k2 enters only after k1 (`AFTER_GROUP`): a strong k2 keeps a k1 that is itself zero."""
    truth = ModelExtension(distortion=(0.0, 0.4, 0.0, 0.0))
    current, settings, problem = _fitted(truth, _lens(), seed=5)
    assert group_p_values(current.fit, "lens_distortion")["k1"] > settings.group_alpha
    pruned, dropped = prune_accepted(current, ["lens_distortion"], problem.observed, SCALE_PX,
                                     settings)
    assert dropped == [] and pruned is current


def test_the_diagnosis_reports_the_dropped_groups_and_recovers_both_effects():
    truth = ModelExtension(joint_offset_rad={"panda_joint3": JOINT3_OFFSET_RAD},
                           keypoint_bias_m={"panda_hand": HAND_BIAS_M})
    seq, robot = _sequence(truth, seed=100110)
    doc, diagnosis, _ = diagnose_sequence(seq, robot, observations_from_labels(seq, robot))
    assert set(doc["verdict"]) == {"joint_offset", "keypoint_bias"}
    score = score_diagnosis(truth, seq.camera, tuple(f.name for f in seq.frames), doc)
    assert all(s.recovered for s in score["scores"]), [s.detail for s in score["scores"]]
    joints = {p.group for p in diagnosis.final.fit.model.params if p.effect == "joint_offset"}
    assert joints == {"panda_joint3"}
    (note,) = [n for n in doc["notes"] if "were dropped" in n]
    assert "joint_offset: panda_joint5" in note and "joint_offset: panda_joint6" in note
    (entry,) = [e for e in doc["effects"] if e["name"] == "joint_offset"]
    assert {"panda_joint5", "panda_joint6"} <= set(entry["identifiability"]["pruned_as_zero"])
    assert set(entry["params"]) == {"panda_joint3"}
    # the report's steps: the model after each acceptance, the last one pruned
    assert len(diagnosis.step_fits) == 2 and diagnosis.step_fits[-1] is diagnosis.final.fit


def test_a_drop_that_leaves_an_effect_implausible_is_not_taken():
    """With the joint-offset limit between joint 3's estimate beside the redundant wrist joints
    and its estimate without them, the drop that would cross it is refused and the result
    stays plausible."""
    truth = ModelExtension(joint_offset_rad={"panda_joint3": JOINT3_OFFSET_RAD},
                           keypoint_bias_m={"panda_hand": HAND_BIAS_M})
    params = [_joint(j) for j in ("panda_joint3", "panda_joint5", "panda_joint6")]
    current, settings, problem = _fitted(truth, params + _bias("panda_hand"), seed=5)
    effects = ["joint_offset", "keypoint_bias"]
    full, _ = prune_accepted(current, effects, problem.observed, SCALE_PX, settings)
    before, after = abs(current.fit.x[6]), abs(full.fit.x[6])
    assert after > before   # precondition: the drops move joint 3 outwards
    tight = dataclasses.replace(settings, plausible={**settings.plausible,
                                                     "joint_offset": (before + after) / 2})
    assert first_implausible(current.fit, tuple(effects), tight.plausible) is None
    pruned, dropped = prune_accepted(current, effects, problem.observed, SCALE_PX, tight)
    assert len(dropped) < 2
    assert first_implausible(pruned.fit, tuple(effects), tight.plausible) is None
