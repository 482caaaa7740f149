"""The 2D keypoint observations of `dream calibrate` and `dream diagnose`: from the data's
labels (`--use-labels`) or from a keypoint network (`--model MODEL.onnx`, onnxruntime, no
torch)."""

from __future__ import annotations

import logging
import sys
from typing import Any, TextIO

from dream.cli.options import check_positive

log = logging.getLogger("dream")


def observe(seq, robot: str | None, model: str | None, use_labels: bool, out: TextIO, *,
            threads: int | None = None, batch: int | None = None, loaded_model: Any = None):
    """Robot, observations and the loaded network (None with the labels)."""
    if model is not None:
        return detect(seq, robot, model, out, threads=threads, batch=batch,
                      loaded_model=loaded_model)
    from dream.pipeline import observations_from_labels, robot_for
    from dream.plausibility import check_robot_readings

    keypoints = seq.keypoint_names if use_labels else None
    robot_model = robot_for(seq, robot, keypoints, keypoints_from=seq.source)
    check_robot_readings(seq, robot_model)
    return robot_model, observations_from_labels(seq, robot_model), None


def detect(seq, robot: str | None, model: str, out: TextIO, *, threads: int | None = None,
           batch: int | None = None, loaded_model: Any = None):
    """Robot, observations and the loaded network of `--model` (`loaded_model`: that network
    already loaded), with a progress line on stderr every `PROGRESS_EVERY_FRAMES` frames."""
    from dream.detection import (
        DEFAULT_BATCH_SIZE,
        PROGRESS_EVERY_FRAMES,
        check_images,
        detect_keypoints,
        load_keypoint_model,
        load_model_robot,
    )
    from dream.plausibility import check_robot_readings

    check_positive(batch, "--batch", "give --batch 1 or more images per network call "
                   f"(default {DEFAULT_BATCH_SIZE})")
    batch = DEFAULT_BATCH_SIZE if batch is None else batch
    check_images(seq)
    network = loaded_model
    if network is None:
        network = load_keypoint_model(model, threads=threads)
    robot_model = load_model_robot(seq, network, robot)
    check_robot_readings(seq, robot_model)
    trained_on = getattr(network, "robot", None)
    if trained_on is not None and trained_on != robot_model.name:
        log.warning("the model was trained on robot '%s', the data is of '%s'", trained_on,
                    robot_model.name)
    every = PROGRESS_EVERY_FRAMES

    def progress(done: int, total: int) -> None:  # a line each time `every` is crossed
        if done == total or done // every > (done - batch) // every:
            print(f"detected keypoints in {done}/{total} frames", file=sys.stderr)

    obs = detect_keypoints(seq, robot_model, network, batch_size=batch,
                           peak_params=getattr(network, "peak_params", None),
                           progress=progress if len(seq) > every else None)
    print(f"{model}: found {int(obs.found.sum())} of {obs.found.size} keypoints in "
          f"{len(seq)} frames", file=out)
    return robot_model, obs, network
