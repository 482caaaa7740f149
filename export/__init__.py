"""ONNX export and torch-free onnxruntime inference (issue 5)."""
