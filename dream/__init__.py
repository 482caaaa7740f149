"""dream: markerless camera-to-robot calibration (pure core).

`dream` imports nothing from `train`, `synth` or `export`. Units are metres, radians, seconds and
pixels. `T_cam_base` maps base-frame points into the camera frame (OpenCV camera frame).
"""

__version__ = "0.1.0"
