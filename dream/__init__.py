"""dream: markerless camera-to-robot calibration.

Point a fixed camera at a robot arm, log images and joint angles, and get the camera's pose in
the robot base frame (`T_cam_base`, with its uncertainty) without a checkerboard::

    import dream

    sequence = dream.read_sequence("demo/scene")            # any supported layout
    robot = dream.load_robot(sequence)                       # the robot the data names
    model = dream.load_keypoint_model(dream.BUNDLED_MODEL)   # ONNX, runs on onnxruntime
    observations = dream.detect(sequence, robot, model)      # keypoints of every frame
    result = dream.calibrate(sequence, observations)         # one T_cam_base from all frames

The API (each name's own help says more):

- read_sequence(path): a recording in any supported layout (docs/data_format.md), its
  cameras and timestamps checked.
- load_robot(sequence | name | urdf_path): URDF kinematics and keypoints.
- load_keypoint_model(path), BUNDLED_MODEL: a keypoint network (ONNX).
- detect(sequence, robot, model), labels(sequence, robot): 2D keypoints as Observations.
- calibrate(sequence, observations, mode="all" | "each"): a CalibrationResult.
- refine_edges(sequence, robot, result, observations): align the outline with the images'
  edges (no masks needed).
- polish_result(sequence, robot, result, observations): align the silhouette with the masks.
- evaluate(sequence, robot, result, observations): errors against the ground truth.
- result_document(result, observations, robot, sequence, refined), read_result(path): RESULT.json.
- diagnose(sequence, robot, observations, report_dir=None): the sim-to-real diagnosis.
- DreamError, InputError, CalibrationError, RobotError: what the library raises.

Units are metres, radians, seconds and pixels (the top-left pixel's centre at (0, 0));
`T_cam_base` maps base-frame points into the OpenCV camera frame. `dream` imports nothing from
`train`, `synth` or `export`; its submodules load on first use, so `import dream` is cheap.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_API = {
    "BUNDLED_MODEL": "dream.models",
    "load_robot": "dream.api",
    "detect": "dream.api",
    "labels": "dream.api",
    "calibrate": "dream.api",
    "polish_result": "dream.api",
    "refine_edges": "dream.api",
    "evaluate": "dream.api",
    "diagnose": "dream.api",
    "result_document": "dream.api",
    "read_sequence": "dream.api",
    "load_keypoint_model": "dream.detection",
    "read_result": "dream.result",
    "Sequence": "dream.sequence",
    "Robot": "dream.robot",
    "Observations": "dream.calibration",
    "CalibrationResult": "dream.calibration",
    "SolverSettings": "dream.pnp",
    "DreamError": "dream.errors",
    "InputError": "dream.errors",
    "CalibrationError": "dream.errors",
    "RobotError": "dream.errors",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    """The public API, imported on first use (PEP 562)."""
    if name not in _API:
        raise AttributeError(f"module 'dream' has no attribute {name!r}")
    value = getattr(importlib.import_module(_API[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
