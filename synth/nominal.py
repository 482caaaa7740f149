"""The nominal camera of a recipe: the one `_camera_settings.json` names and frames start from."""

from __future__ import annotations

import numpy as np

from dream.camera import CameraIntrinsics
from synth.config import SynthConfig
from synth.randomize import sample_intrinsics, sequence_rng


def nominal_camera(config: SynthConfig, seed: int | None = None) -> CameraIntrinsics:
    """The camera of `_camera_settings.json`: the fixed one; in the sequence modes the one
    camera of the sequence of `seed` (its field of view is drawn once); else the middle field
    of view."""
    c = config.intrinsics
    if c.fixed:
        return sample_intrinsics(np.random.default_rng(0), config)
    if config.sequence.mode != "random" and seed is not None:
        return sample_intrinsics(sequence_rng(seed), config)   # sample_scene's first draw
    f = (c.width / 2) / np.tan(np.mean(c.hfov_rad) / 2)
    return CameraIntrinsics(f, f, (c.width - 1) / 2, (c.height - 1) / 2, c.width, c.height,
                            c.distortion)
