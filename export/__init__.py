"""ONNX export and torch-free onnxruntime inference.

- `export.onnx_export` (torch, onnx): `export_onnx(checkpoint, out)`, the `dream export` command.
- `export.runner` (onnxruntime, numpy only): `OnnxKeypointModel(path, threads=None)`, the
  `.onnx` loader of the `dream.model_loaders` entry points that `dream calibrate --model` uses.

This package file imports nothing, so that loading the runner never loads torch.
"""
