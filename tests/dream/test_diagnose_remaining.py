"""The diagnosis says how much misfit remains and whether it looks like detector error."""

from __future__ import annotations

import dataclasses
import doctest

import numpy as np

import dream.diagnosis.remaining
from dream.diagnosis.run import diagnose_sequence
from dream.inject import InjectionSettings, make_injected_sequence
from dream.pipeline import observations_from_labels, robot_for

NOISY_KEYPOINT = 5   # panda_link7
DETECTOR_NOISE_PX = 8.0


def _diagnose(seq):
    robot = robot_for(seq, None, seq.keypoint_names)
    doc, _, _ = diagnose_sequence(seq, robot, observations_from_labels(seq, robot))
    return doc


def test_misfit_on_one_keypoint_reads_as_detector_error():
    seq = make_injected_sequence(InjectionSettings(num_frames=80, pixel_noise_px=1.0, seed=7))
    clean = _diagnose(seq)
    assert clean["remaining"]["confined_to"] == []
    assert 0.5 < clean["remaining"]["unexplained_share"] <= 1.2
    rng = np.random.default_rng(0)
    frames = []
    for f in seq.frames:
        uv = f.uv_labels.copy()
        uv[NOISY_KEYPOINT] += rng.normal(0.0, DETECTOR_NOISE_PX, 2)
        frames.append(dataclasses.replace(f, uv_labels=uv))
    noisy = _diagnose(dataclasses.replace(seq, frames=tuple(frames)))
    name = seq.keypoint_names[NOISY_KEYPOINT]
    assert noisy["remaining"]["confined_to"] == [name]
    assert f"detector error on {name}" in noisy["remaining"]["looks_like"]


def test_docstring_example():
    assert doctest.testmod(dream.diagnosis.remaining).failed == 0
