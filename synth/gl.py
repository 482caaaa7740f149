"""MuJoCo, imported after choosing its offscreen OpenGL backend (EGL unless `MUJOCO_GL` is set).

MuJoCo reads `MUJOCO_GL` when it is first imported, so every `synth` module imports it from
here: `from synth.gl import mujoco`.
"""

from __future__ import annotations

import os

DEFAULT_MUJOCO_GL = "egl"  # headless; Mesa's software EGL works without a GPU
os.environ.setdefault("MUJOCO_GL", DEFAULT_MUJOCO_GL)

import mujoco  # noqa: E402  (after MUJOCO_GL)

__all__ = ["mujoco"]
