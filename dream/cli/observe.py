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
            threads: int | None = None, batch: int | None = None, loaded_model: Any = None,
            keypoints: tuple[str, ...] | None = None):
    """Robot, observations and the loaded network (None with the labels). `keypoints` (the
    links of --keypoints) are used where neither the model nor the labels name keypoints; where
    they do, naming other links is an `InputError`."""
    if model is not None:
        return detect(seq, robot, model, out, threads=threads, batch=batch,
                      loaded_model=loaded_model, keypoints=keypoints)
    from dream.pipeline import check_option_agrees, observations_from_labels, robot_for
    from dream.plausibility import check_robot_readings

    labelled = tuple(seq.keypoint_names) if use_labels else ()
    if labelled and keypoints:
        check_option_agrees(keypoints, labelled, f"the labels of {seq.source}")
    robot_model = robot_for(seq, robot, labelled or None, keypoints_from=seq.source,
                            option_keypoints=keypoints)
    check_robot_readings(seq, robot_model)
    return robot_model, observations_from_labels(seq, robot_model), None


def detect(seq, robot: str | None, model: str, out: TextIO, *, threads: int | None = None,
           batch: int | None = None, loaded_model: Any = None,
           keypoints: tuple[str, ...] | None = None):
    """Robot, observations and the loaded network of `--model` (`loaded_model`: that network
    already loaded), with a progress line on stderr every `PROGRESS_EVERY_FRAMES` frames;
    `keypoints` (--keypoints) must name the model's. A model trained on another robot (another
    built-in, or a URDF of other content: `dream.robot.identity`) is a warning."""
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
    robot_model = load_model_robot(seq, network, robot, keypoints)
    check_robot_readings(seq, robot_model)
    trained_on = getattr(network, "robot", None)
    if trained_on:
        from dream.robot.identity import TrainedRobot, robot_difference

        difference = robot_difference(
            TrainedRobot(trained_on, getattr(network, "urdf_sha256", None)), robot_model)
        if difference is not None:
            log.warning("%s", difference)
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
