"""The embedded default scene of `dream demo`: a rendered fixed-camera Panda sequence.

A fixed camera on the training recipe's shell looks at the arm in `DEMO_FRAMES` random joint
configurations; lights, colours, backgrounds and a few distractors are randomised as in
`configs/synth/default.yaml` (the bundled model's training distribution) but from one fixed
seed, so the scene and its ground truth are the same on every machine.
"""

from __future__ import annotations

from pathlib import Path

from synth.config import config_from_dict
from synth.generate import SynthJob, generate

DEMO_ROBOT = "panda"
DEMO_FRAMES = 30
DEMO_SEED = 7
DEMO_SCENE = {  # overrides of the default recipe (metres, radians, pixels)
    "camera": {"radius_m": [1.3, 1.6], "elevation_rad": [0.3, 0.6]},
    "intrinsics": {"width": 320, "height": 240, "fx": 260.0, "fy": 260.0, "cx": 159.5,
                   "cy": 119.5},
    "joints": {"range_fraction": 0.7},
    "distractors": {"count": [0, 2], "occluder_prob": 0.0},
    "sequence": {"mode": "fixed_camera"},
}


def render_demo_scene(out_dir: str | Path, seed: int = DEMO_SEED,
                      num_frames: int = DEMO_FRAMES, held_object: bool = False) -> Path:
    """Render the demo scene into `out_dir` (overwritten); returns the folder. `held_object`:
    the arm holds an object (`distractors.held_prob` 1) throughout the sequence."""
    scene = {**DEMO_SCENE, "distractors": {**DEMO_SCENE["distractors"],
                                           "held_prob": 1.0 if held_object else 0.0}}
    job = SynthJob(robot=DEMO_ROBOT, out_dir=Path(out_dir), num_frames=num_frames,
                   config=config_from_dict(scene), seed=seed)
    generate(job, overwrite=True, on_progress=lambda done: None)
    return Path(out_dir)
