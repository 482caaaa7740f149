"""Images -> 2D keypoint observations through a belief-map network (no torch, no `export`).

The network is any object that satisfies `KeypointModel`: its keypoint names (URDF links, the
belief maps' order), its preprocessing (`dream.preprocess.Preprocess`, the code training uses),
its output stride and `run(batch) -> {"belief": (N, K, h, w), ...}`. The project's ONNX runner
(`export.runner.OnnxKeypointModel`) is one; `load_keypoint_model` finds a runner for a model
file through the `dream.model_loaders` entry points, so `dream` imports nothing from `export`.

    model = load_keypoint_model("model.onnx", threads=2)
    obs = detect_keypoints(sequence, robot, model)   # -> dream.calibration.Observations

Per batch of frames: `dream.io.load_image` -> `Preprocess.apply` -> `model.run` ->
`dream.peaks.find_peaks_batch`, then per frame `to_input(stride)` -> `to_image(transform)`. A
keypoint's confidence is its belief-map peak value; a keypoint not found (or found outside the
image) has NaN pixels and confidence 0. A model trained on zoomed inputs (its `zoom` settings,
`dream.zoom`) looks a second time at the box around each frame's keypoints; what that pass
finds replaces the first pass's.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from dream.calibration import Observations
from dream.camera import CameraIntrinsics
from dream.errors import InputError, RobotError
from dream.io import load_image
from dream.peaks import PeakSettings, find_peaks_batch
from dream.pipeline import check_option_agrees, joints_in_robot_order, robot_for
from dream.preprocess import InputTransform, Preprocess
from dream.robot import Robot
from dream.sequence import Sequence
from dream.zoom import ZoomSettings, cut_input, zoom_transform

log = logging.getLogger(__name__)

BELIEF_OUTPUT = "belief"  # (N, K, h, w) belief maps, one per keypoint
MASK_OUTPUT = "mask"      # (N, 1, h, w) robot-mask logits (optional)
MODEL_LOADER_GROUP = "dream.model_loaders"
DEFAULT_BATCH_SIZE = 8
PROGRESS_EVERY_FRAMES = 100  # callers report progress about this often (`dream calibrate`)
NOT_FOUND_CONFIDENCE = 0.0


@runtime_checkable
class KeypointModel(Protocol):
    """What `detect_keypoints` needs of a keypoint network.

    Attributes:
        keypoint_names: K URDF link names, in belief-map order.
        preprocess: how an RGB image becomes the network input.
        stride: input pixels per belief-map pixel (1, 2 or 4).

    A model may also have `zoom` (`dream.zoom.ZoomSettings` or None): it was trained on inputs
    cut around the keypoints, and detection runs it a second time on such a cut.
    """

    keypoint_names: tuple[str, ...]
    preprocess: Preprocess
    stride: int

    def run(self, batch: np.ndarray) -> Mapping[str, np.ndarray]:
        """(N, 3, H, W) float32 normalised input -> outputs by name, `BELIEF_OUTPUT` among
        them with shape (N, K, H / stride, W / stride)."""
        ...


@dataclass(frozen=True)
class DetectionSettings:
    """How `detect_keypoints` batches the frames and finds the peaks.

    Attributes:
        batch_size: images per network call.
        peak_params: the peak finder's constants (None: `PeakSettings()`).
    """

    batch_size: int = DEFAULT_BATCH_SIZE
    peak_params: PeakSettings | None = None

    def __post_init__(self) -> None:
        if isinstance(self.batch_size, bool) or int(self.batch_size) != self.batch_size or \
                self.batch_size < 1:
            raise InputError(f"batch size must be an integer >= 1, got {self.batch_size!r}",
                             fix="give a batch size of 1 or more images (--batch N)")
        object.__setattr__(self, "batch_size", int(self.batch_size))
        if self.peak_params is not None and not isinstance(self.peak_params, PeakSettings):
            raise InputError(f"peak_params must be a PeakSettings, got "
                             f"{type(self.peak_params).__name__}")


def _model_path(model: Any) -> Path | None:
    path = getattr(model, "path", None)
    return None if path is None else Path(path)


def load_keypoint_model(path: str | Path, threads: int | None = None) -> KeypointModel:
    """The runner of a model file, found by its suffix among the `dream.model_loaders` entry
    points (`onnx = "export.runner:OnnxKeypointModel"`); `threads` is passed on."""
    path = Path(path)
    kind = path.suffix.lower().lstrip(".")
    loaders = {e.name: e for e in entry_points(group=MODEL_LOADER_GROUP)}
    if kind not in loaders:
        known = ", ".join(f".{name}" for name in sorted(loaders)) or "none installed"
        raise InputError(f"no model loader for '{path.suffix or 'no suffix'}' files "
                         f"(loaders: {known})", path,
                         "give a .onnx file written by dream export (and install the project "
                         "with pip install -e .)")
    try:
        loader = loaders[kind].load()
    except ImportError as exc:
        raise InputError(f"the .{kind} model loader cannot be imported ({exc})", path,
                         "reinstall the project with pip install -e .") from None
    model = loader(path, threads=threads)
    if not isinstance(model, KeypointModel):
        raise InputError(f"the .{kind} loader returned {type(model).__name__}, not a keypoint "
                         "model", path)
    return model


def _keypoint_mismatch(model: KeypointModel, robot_name: str, reason: str) -> InputError:
    return InputError(f"the model's keypoints ({', '.join(model.keypoint_names)}) are not links "
                      f"of robot '{robot_name}' ({reason})", _model_path(model),
                      "use a model trained for this robot, or pass --robot with the robot "
                      "(name or URDF) the model was trained on")


def robot_for_model(robot: Robot, model: KeypointModel) -> Robot:
    """`robot` with the model's keypoints (its belief maps are those links' origins)."""
    names = tuple(model.keypoint_names)
    if names == robot.keypoint_names:
        return robot
    try:
        return robot.with_keypoints(names)
    except RobotError as exc:
        raise _keypoint_mismatch(model, robot.name, str(exc)) from None


def load_model_robot(sequence: Sequence, model: KeypointModel, robot: str | None = None,
                     option_keypoints: tuple[str, ...] | None = None) -> Robot:
    """The sequence's robot (or the named one: built-in name or URDF path) with the model's
    keypoints; a keypoint that is not a link of it is one `InputError`, and so are
    `option_keypoints` (--keypoints) that name other links than the model's."""
    if option_keypoints:
        check_option_agrees(tuple(option_keypoints), tuple(model.keypoint_names),
                            f"the model {_model_path(model) or ''}".rstrip())
    try:
        return robot_for(sequence, robot, tuple(model.keypoint_names))
    except RobotError as exc:
        raise _keypoint_mismatch(model, robot or sequence.robot, str(exc)) from None


def check_images(sequence: Sequence) -> None:
    """Every frame must have an image for detection."""
    missing = [f.name for f in sequence.frames if f.image_path is None]
    if missing:
        raise InputError(f"{len(missing)} of {len(sequence)} frames have no image (first: "
                         f"{missing[0]}); a keypoint network needs images", sequence.source,
                         "use --use-labels to calibrate from the 2D labels")


def prepare_batch(images: SequenceOf[np.ndarray], preprocess: Preprocess
                  ) -> tuple[np.ndarray, tuple[InputTransform, ...]]:
    """(H, W, 3) uint8 RGB images -> ((N, 3, h, w) float32 network input, their transforms),
    through `Preprocess.apply`, exactly as training feeds the network."""
    pairs = [preprocess.apply(image) for image in images]
    batch = np.stack([x for x, _ in pairs]).astype(np.float32, copy=False)
    return batch, tuple(t for _, t in pairs)


def _belief_of(outputs: Mapping[str, np.ndarray], n: int, k: int,
               model: KeypointModel) -> np.ndarray:
    if BELIEF_OUTPUT not in outputs:
        raise InputError(f"the model has no '{BELIEF_OUTPUT}' output (it has "
                         f"{', '.join(outputs) or 'none'})", _model_path(model),
                         "export it with dream export")
    belief = np.asarray(outputs[BELIEF_OUTPUT])
    if belief.ndim != 4 or belief.shape[:2] != (n, k):
        raise InputError(f"the model's belief maps have shape {belief.shape}, expected "
                         f"({n}, {k}, h, w)", _model_path(model), "export it with dream export")
    return belief


def detect_keypoints(sequence: Sequence, robot: Robot, model: KeypointModel,
                     batch_size: int = DEFAULT_BATCH_SIZE, peak_params: PeakSettings | None = None,
                     progress: Callable[[int, int], None] | None = None) -> Observations:
    """2D keypoints of every frame of `sequence` found by `model`, as `Observations`.

    Args:
        sequence: frames with images (a frame without one is an `InputError`).
        robot: the sequence's robot; its keypoints are replaced by the model's.
        model: a `KeypointModel` (e.g. `load_keypoint_model("model.onnx")`).
        batch_size: images per `model.run` call.
        peak_params: the peak finder's constants (default: the model's own, `peak_params` of
            an exported model's metadata, else `PeakSettings()`).
        progress: called as `progress(frames_done, frames_total)` after every batch.

    Returns:
        `Observations` with uv in image pixels (NaN where not found), confidence the belief
        peak value (0 where not found) and P_base from the robot's forward kinematics.
    """
    settings = DetectionSettings(batch_size, peak_params)
    params = settings.peak_params or getattr(model, "peak_params", None) or PeakSettings()
    robot = robot_for_model(robot, model)
    check_images(sequence)
    P_base = robot.forward_kinematics(joints_in_robot_order(sequence, robot))
    F, K = len(sequence), robot.num_keypoints
    uv = np.full((F, K, 2), np.nan)
    confidence = np.full((F, K), NOT_FOUND_CONFIDENCE)
    camera = sequence.camera
    zoom = getattr(model, "zoom", None)
    for start in range(0, F, settings.batch_size):
        frames = sequence.frames[start:start + settings.batch_size]
        images = [load_image(f, camera) for f in frames]
        batch, transforms = prepare_batch(images, model.preprocess)
        found = _found_in(model, batch, transforms, params, camera)
        if zoom is not None:
            found = _zoomed(model, images, found, zoom, params, camera)
        for i, (uv_i, confidence_i) in enumerate(found):
            uv[start + i], confidence[start + i] = uv_i, confidence_i
        if progress is not None:
            progress(start + len(frames), F)
    found = np.isfinite(uv[..., 0])
    log.info("detected %d of %d keypoints in %d frames", int(found.sum()), F * K, F)
    return Observations(P_base, uv, confidence, tuple(f.name for f in sequence.frames),
                        robot.keypoint_names)


def _found_in(model: KeypointModel, batch: np.ndarray,
              transforms: SequenceOf[InputTransform], params: PeakSettings,
              camera: CameraIntrinsics) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per image of `batch`: (K, 2) image pixels (NaN: not found) and (K,) confidences."""
    K, stride = len(model.keypoint_names), int(model.stride)
    belief = _belief_of(model.run(batch), len(batch), K, model)
    found = []
    for in_map, transform in zip(find_peaks_batch(belief, params), transforms, strict=True):
        peaks = in_map.to_input(stride).to_image(transform)
        ok = peaks.found & (peaks.confidence > 0) & camera.in_image(peaks.uv_image)
        found.append((np.where(ok[:, None], peaks.uv_image, np.nan),
                      np.where(ok, peaks.confidence, NOT_FOUND_CONFIDENCE)))
    return found


def _zoomed(model: KeypointModel, images: SequenceOf[np.ndarray],
            found: list[tuple[np.ndarray, np.ndarray]], zoom: ZoomSettings,
            params: PeakSettings, camera: CameraIntrinsics) -> list[tuple[np.ndarray, np.ndarray]]:
    """The second pass: each image cut around its first-pass keypoints; a keypoint the cut does
    not find keeps the first pass's pixel and confidence."""
    pre = model.preprocess
    cuts = [zoom_transform(pre, camera.width, camera.height, uv, zoom) for uv, _ in found]
    todo = [i for i, t in enumerate(cuts) if t is not None]
    if not todo:
        return found
    batch = np.stack([cut_input(pre, images[i], cuts[i]) for i in todo]).astype(np.float32,
                                                                                 copy=False)
    second = _found_in(model, batch, [cuts[i] for i in todo], params, camera)
    out = list(found)
    for i, (uv, confidence) in zip(todo, second, strict=True):
        hit = np.isfinite(uv[:, 0])
        out[i] = (np.where(hit[:, None], uv, found[i][0]),
                  np.where(hit, confidence, found[i][1]))
    return out


def predict_masks(sequence: Sequence, model: KeypointModel, indices: SequenceOf[int],
                  batch_size: int = DEFAULT_BATCH_SIZE) -> np.ndarray:
    """Robot masks of frames `indices` from the network's mask head, in image pixels.

    The (N, 1, h, w) mask logits are sampled bilinearly at every image pixel's place in the
    belief map (the inverse of the preprocessing, as for the keypoints); logit > 0 is robot.

    Returns:
        (n, H, W) bool.
    Raises:
        InputError: the model has no mask head.
    """
    import cv2

    camera = sequence.camera
    stride = int(model.stride)
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height,
                                                                      dtype=float))
    out = np.zeros((len(indices), camera.height, camera.width), bool)
    for start in range(0, len(indices), batch_size):
        chunk = list(indices[start:start + batch_size])
        frames = [sequence.frames[i] for i in chunk]
        batch, transforms = prepare_batch([load_image(f, camera) for f in frames],
                                          model.preprocess)
        outputs = model.run(batch)
        if outputs.get(MASK_OUTPUT) is None:
            raise InputError("the model has no robot-mask head", _model_path(model),
                             "give data with masks, or a model trained with model.mask_head")
        logits = np.asarray(outputs[MASK_OUTPUT], dtype=np.float32)
        for n, transform in enumerate(transforms):
            uv_input = transform.image_to_input(np.stack([u, v], -1))
            map_uv = (uv_input + 0.5) / stride - 0.5
            sampled = cv2.remap(logits[n, 0], map_uv[..., 0].astype(np.float32),
                                map_uv[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
            out[start + n] = sampled > 0
    return out
