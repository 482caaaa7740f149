"""Models that ship with the package: `BUNDLED_MODEL`, the Panda keypoint network (ONNX; its
model card, panda_cpu.md, lies beside it)."""

from pathlib import Path

BUNDLED_MODEL = Path(__file__).resolve().parent / "panda_cpu.onnx"
