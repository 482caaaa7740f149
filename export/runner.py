"""Torch-free inference of an exported keypoint network with onnxruntime.

`OnnxKeypointModel` satisfies `dream.detection.KeypointModel` and is registered as the `.onnx`
loader of the `dream.model_loaders` entry points, which `dream calibrate --model` uses. It
imports numpy, onnxruntime and `dream` only (neither torch nor the `onnx` package: the base
install runs it).

The model file carries its own description as ONNX metadata (`ModelMetadata`, written by
`dream export`): robot, keypoint names, input size, preprocessing, output stride, project
version, config hash, belief sigma, the peak finder's defaults, the SHA-256 of the robot's
URDF and, for a model trained on zoomed inputs, its zoom settings (`dream.zoom`).
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
from onnxruntime.capi import onnxruntime_pybind11_state as ort_state

from dream.detection import BELIEF_OUTPUT, MASK_OUTPUT
from dream.errors import InputError
from dream.io.fields import one_line
from dream.peaks import PeakSettings
from dream.preprocess import RGB_CHANNELS, Preprocess
from dream.zoom import ZoomSettings

log = logging.getLogger(__name__)

METADATA_FORMAT = 1
INPUT_NAME = "image"
OUTPUT_NAMES = (BELIEF_OUTPUT, MASK_OUTPUT)
VALID_STRIDES = (1, 2, 4)
PROVIDER = "CPUExecutionProvider"
FIX = "export it with dream export"
_SHA256 = re.compile(r"[0-9a-f]{64}")

# metadata_props keys of an exported model
KEY_FORMAT = "dream.format"
KEY_ROBOT = "dream.robot"
KEY_KEYPOINTS = "dream.keypoint_names"
KEY_INPUT_WIDTH = "dream.input_width"
KEY_INPUT_HEIGHT = "dream.input_height"
KEY_PREPROCESS = "dream.preprocess"
KEY_STRIDE = "dream.output_stride"
KEY_VERSION = "dream.version"
KEY_CONFIG_HASH = "dream.config_sha256"
KEY_BELIEF_SIGMA = "dream.belief_sigma"
KEY_PEAK_PARAMS = "dream.peak_params"
KEY_URDF_HASH = "dream.urdf_sha256"   # optional: models exported before it lack it
KEY_ZOOM = "dream.zoom"               # optional: only a model trained on zoomed inputs has it
REQUIRED_KEYS = (KEY_FORMAT, KEY_ROBOT, KEY_KEYPOINTS, KEY_INPUT_WIDTH, KEY_INPUT_HEIGHT,
                 KEY_PREPROCESS, KEY_STRIDE, KEY_VERSION, KEY_CONFIG_HASH, KEY_BELIEF_SIGMA)

# onnxruntime's own exception types (they derive from Exception, not RuntimeError)
_ORT_ERROR_NAMES = ("Fail", "InvalidArgument", "NoSuchFile", "NoModel", "EngineError",
                    "RuntimeException", "InvalidProtobuf", "ModelLoaded", "NotImplemented",
                    "InvalidGraph", "EPFail")
ORT_ERRORS: tuple[type[BaseException], ...] = tuple(
    cls for cls in (getattr(ort_state, name, None)
                    for name in _ORT_ERROR_NAMES) if isinstance(cls, type)) + (RuntimeError,
                                                                               OSError)


@dataclass(frozen=True)
class ModelMetadata:
    """What an exported model says about itself (stored as string metadata_props).

    Attributes:
        robot: robot name the network was trained on.
        keypoint_names: URDF links of the K belief maps, in order.
        preprocess: image -> network input (its size is the model's input size, px).
        output_stride: input pixels per belief-map pixel.
        dream_version: `dream.__version__` at export.
        config_sha256: sha256 of the training config's canonical JSON.
        belief_sigma: Gaussian sigma of the training targets, map pixels.
        peak_params: the peak finder's constants of the training config, or None.
        urdf_sha256: sha256 of the robot's URDF file at export, or None (unknown).
        zoom: the zoomed second pass the network was trained for (`dream.zoom`), or None.
    """

    robot: str
    keypoint_names: tuple[str, ...]
    preprocess: Preprocess
    output_stride: int
    dream_version: str
    config_sha256: str
    belief_sigma: float
    peak_params: PeakSettings | None = None
    urdf_sha256: str | None = None
    zoom: ZoomSettings | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.robot, str) or not self.robot:
            raise InputError(f"robot must be a non-empty name, got {self.robot!r}")
        names = tuple(self.keypoint_names)
        if not names or not all(isinstance(n, str) and n for n in names) or \
                len(set(names)) != len(names):
            raise InputError(f"keypoint names must be distinct non-empty names, got {names!r}")
        object.__setattr__(self, "keypoint_names", names)
        if not isinstance(self.preprocess, Preprocess):
            raise InputError("preprocess must be a dream.preprocess.Preprocess")
        if isinstance(self.output_stride, bool) or self.output_stride not in VALID_STRIDES:
            raise InputError(f"output stride must be one of {VALID_STRIDES}, got "
                             f"{self.output_stride!r}")
        object.__setattr__(self, "output_stride", int(self.output_stride))
        if not isinstance(self.config_sha256, str) or not _SHA256.fullmatch(self.config_sha256):
            raise InputError(f"config hash must be 64 hex digits, got {self.config_sha256!r}")
        sigma = float(self.belief_sigma)
        if not np.isfinite(sigma) or sigma <= 0:
            raise InputError(f"belief sigma must be > 0 (map pixels), got {self.belief_sigma!r}")
        object.__setattr__(self, "belief_sigma", sigma)
        if self.peak_params is not None and not isinstance(self.peak_params, PeakSettings):
            raise InputError("peak_params must be a dream.peaks.PeakSettings or None")
        if self.urdf_sha256 is not None and (not isinstance(self.urdf_sha256, str)
                                             or not _SHA256.fullmatch(self.urdf_sha256)):
            raise InputError(f"URDF hash must be 64 hex digits, got {self.urdf_sha256!r}")
        if self.zoom is not None and not isinstance(self.zoom, ZoomSettings):
            raise InputError("zoom must be a dream.zoom.ZoomSettings or None")

    def to_props(self) -> dict[str, str]:
        """metadata_props: string keys -> string values (numbers as text, lists as JSON)."""
        props = {
            KEY_FORMAT: str(METADATA_FORMAT),
            KEY_ROBOT: self.robot,
            KEY_KEYPOINTS: json.dumps(list(self.keypoint_names)),
            KEY_INPUT_WIDTH: str(self.preprocess.input_width),
            KEY_INPUT_HEIGHT: str(self.preprocess.input_height),
            KEY_PREPROCESS: json.dumps(self.preprocess.to_dict(), sort_keys=True),
            KEY_STRIDE: str(self.output_stride),
            KEY_VERSION: self.dream_version,
            KEY_CONFIG_HASH: self.config_sha256,
            KEY_BELIEF_SIGMA: repr(self.belief_sigma),
        }
        if self.peak_params is not None:
            props[KEY_PEAK_PARAMS] = json.dumps(asdict(self.peak_params), sort_keys=True)
        if self.urdf_sha256 is not None:
            props[KEY_URDF_HASH] = self.urdf_sha256
        if self.zoom is not None:
            props[KEY_ZOOM] = json.dumps(self.zoom.to_dict(), sort_keys=True)
        return props

    @classmethod
    def from_props(cls, props: Mapping[str, str], path: str | Path | None = None
                   ) -> ModelMetadata:
        """Parse and validate metadata_props; any problem is one `InputError` naming `path`."""
        missing = [k for k in REQUIRED_KEYS if k not in props]
        if len(missing) == len(REQUIRED_KEYS):
            raise InputError("the ONNX model has no dream metadata (not written by dream "
                             "export)", path, FIX)
        if missing:
            raise InputError(f"the ONNX model's dream metadata lacks {', '.join(missing)}",
                             path, FIX)
        if props[KEY_FORMAT] != str(METADATA_FORMAT):
            raise InputError(f"metadata format {props[KEY_FORMAT]!r} is not supported "
                             f"(expected {METADATA_FORMAT})", path,
                             "export it again with this version's dream export")
        names = _field(props, KEY_KEYPOINTS, _json_list, path)
        preprocess = _field(props, KEY_PREPROCESS, _preprocess, path)
        peak_params = _field(props, KEY_PEAK_PARAMS, _peak_params, path) \
            if KEY_PEAK_PARAMS in props else None
        zoom = _field(props, KEY_ZOOM, _zoom, path) if KEY_ZOOM in props else None
        stride = _field(props, KEY_STRIDE, int, path)
        sigma = _field(props, KEY_BELIEF_SIGMA, float, path)
        size = (_field(props, KEY_INPUT_WIDTH, int, path),
                _field(props, KEY_INPUT_HEIGHT, int, path))
        try:
            meta = cls(props[KEY_ROBOT], tuple(names), preprocess, stride, props[KEY_VERSION],
                       props[KEY_CONFIG_HASH], sigma, peak_params, props.get(KEY_URDF_HASH),
                       zoom)
        except InputError as exc:
            raise InputError(f"corrupt dream metadata: {exc.problem}", path, FIX) from None
        if size != (preprocess.input_width, preprocess.input_height):
            raise InputError(f"corrupt dream metadata: input size {size} differs from the "
                             f"preprocessing's {preprocess.input_width}x"
                             f"{preprocess.input_height}", path, FIX)
        return meta


def _json_list(text: str) -> list:
    value = json.loads(text)
    if not isinstance(value, list):
        raise InputError(f"expected a JSON list, got {text[:40]!r}")
    return value


def _preprocess(text: str) -> Preprocess:
    doc = json.loads(text)
    if not isinstance(doc, dict):
        raise InputError(f"expected a JSON object, got {text[:40]!r}")
    return Preprocess.from_dict(doc)


def _peak_params(text: str) -> PeakSettings:
    doc = json.loads(text)
    if not isinstance(doc, dict):
        raise InputError(f"expected a JSON object, got {text[:40]!r}")
    return PeakSettings(**doc)


def _zoom(text: str) -> ZoomSettings:
    return ZoomSettings.from_dict(json.loads(text))


def _field(props: Mapping[str, str], key: str, parse: Callable[[str], Any],
           path: str | Path | None) -> Any:
    """`parse(props[key])`; a failure is one InputError naming the key, the file and the fix."""
    try:
        return parse(props[key])
    except InputError as exc:
        raise InputError(f"corrupt dream metadata {key}: {exc.problem}", path, FIX) from None
    except (ValueError, TypeError) as exc:
        raise InputError(f"corrupt dream metadata {key}: {one_line(exc)}", path, FIX) from None


def _check_threads(threads: int | None) -> int | None:
    if threads is None:
        return None
    if isinstance(threads, bool) or int(threads) != threads or threads < 1:
        raise InputError(f"threads must be an integer >= 1, got {threads!r}",
                         fix="pass --threads N with N >= 1, or leave it out")
    return int(threads)


class OnnxKeypointModel:
    """An exported keypoint network run by onnxruntime on the CPU (`dream.detection.KeypointModel`).

    Args:
        path: a .onnx file written by `dream export`.
        threads: onnxruntime intra-op threads (None: onnxruntime's default, every core).

    Raises:
        InputError: the file is missing, not an ONNX model, or lacks valid dream metadata, or
            its graph does not match the metadata: input (N, 3, H, W), outputs belief (N, K,
            H/s, W/s) and mask (N, 1, H/s, W/s) for the metadata's K keypoint names, input size
            and output stride s (one line naming the file and the fix). Output dimensions the
            graph leaves symbolic are checked on each `run`, with the same error.
    """

    def __init__(self, path: str | Path, threads: int | None = None):
        self.path = Path(path)
        self.threads = _check_threads(threads)
        if not self.path.is_file():
            from dream.models import BUNDLED_MODEL

            raise InputError("model file not found", self.path,
                             f"give the path of an exported model (the bundled Panda model is "
                             f"{BUNDLED_MODEL}), or {FIX}")
        options = ort.SessionOptions()
        if self.threads is not None:
            options.intra_op_num_threads = self.threads
        options.log_severity_level = 3  # errors only: they are raised as InputError below
        try:
            self._session = ort.InferenceSession(str(self.path), options, providers=[PROVIDER])
        except ORT_ERRORS as exc:
            raise InputError(f"not a readable ONNX model ({one_line(exc)})", self.path,
                             FIX) from None
        props = self._session.get_modelmeta().custom_metadata_map
        self.metadata = ModelMetadata.from_props(props, self.path)
        self._check_graph()
        log.debug("loaded %s: %s, %d keypoints, input %dx%d, stride %d", self.path,
                  self.robot, len(self.keypoint_names), self.preprocess.input_width,
                  self.preprocess.input_height, self.stride)

    def _check_graph(self) -> None:
        inputs = self._session.get_inputs()
        pre = self.preprocess
        expected = [RGB_CHANNELS, pre.input_height, pre.input_width]
        if len(inputs) != 1 or inputs[0].name != INPUT_NAME or len(inputs[0].shape) != 4 or \
                list(inputs[0].shape[1:]) != expected:
            got = [(i.name, i.shape) for i in inputs]
            raise InputError(f"the model's input {got} is not '{INPUT_NAME}' (N, {expected[0]}, "
                             f"{expected[1]}, {expected[2]}) as its metadata says", self.path, FIX)
        outputs = self._session.get_outputs()
        names = [o.name for o in outputs]
        if BELIEF_OUTPUT not in names or any(n not in OUTPUT_NAMES for n in names) or \
                len(set(names)) != len(names):
            raise InputError(f"the model's outputs {names} are not {list(OUTPUT_NAMES)}",
                             self.path, FIX)
        self.output_names = tuple(names)
        stride = self.stride
        if pre.input_height % stride or pre.input_width % stride:
            raise InputError(f"the metadata's input size {pre.input_width}x{pre.input_height} is "
                             f"not a multiple of its output stride {stride}", self.path, FIX)
        for output in outputs:
            shape = output.shape
            expected = self._expected_shape(output.name)
            if len(shape) != len(expected) or any(
                    isinstance(got, int) and isinstance(want, int) and got != want
                    for got, want in zip(shape[1:], expected[1:], strict=True)):
                raise self._shape_error(output.name, shape)
        # dimensions left symbolic in the graph are checked on every run (`_check_outputs`)

    def _expected_shape(self, name: str, batch: int | str = "N") -> tuple[int | str, ...]:
        """(batch, K, H/s, W/s) for the belief maps, (batch, 1, H/s, W/s) for the mask."""
        pre, stride = self.preprocess, self.stride
        channels = len(self.keypoint_names) if name == BELIEF_OUTPUT else 1
        return (batch, channels, pre.input_height // stride, pre.input_width // stride)

    def _shape_error(self, name: str, shape, batch: int | str = "N") -> InputError:
        what = f"{len(self.keypoint_names)} keypoints" if name == BELIEF_OUTPUT else "one map"
        expected = ", ".join(map(str, self._expected_shape(name, batch)))
        return InputError(f"the model's '{name}' output has shape ({', '.join(map(str, shape))}),"
                          f" not ({expected}) as its metadata says ({what}, input "
                          f"{self.preprocess.input_width}x{self.preprocess.input_height}, output "
                          f"stride {self.stride})", self.path, FIX)

    def _check_outputs(self, outputs: Mapping[str, np.ndarray], batch: int) -> None:
        for name, value in outputs.items():
            if np.shape(value) != self._expected_shape(name, batch):
                raise self._shape_error(name, np.shape(value), batch)

    # ----- dream.detection.KeypointModel ----------------------------------------------------------

    @property
    def keypoint_names(self) -> tuple[str, ...]:
        return self.metadata.keypoint_names

    @property
    def preprocess(self) -> Preprocess:
        return self.metadata.preprocess

    @property
    def stride(self) -> int:
        return self.metadata.output_stride

    @property
    def robot(self) -> str:
        return self.metadata.robot

    @property
    def peak_params(self) -> PeakSettings | None:
        return self.metadata.peak_params

    @property
    def zoom(self) -> ZoomSettings | None:
        """The zoomed second pass the network was trained for, or None (one pass)."""
        return self.metadata.zoom

    @property
    def urdf_sha256(self) -> str | None:
        """sha256 of the URDF the model was trained on, when its metadata carries it."""
        return self.metadata.urdf_sha256

    def run(self, batch: np.ndarray) -> dict[str, np.ndarray]:
        """(N, 3, H, W) float32 normalised input (`Preprocess.apply`) -> {"belief": (N, K,
        H/s, W/s), "mask": (N, 1, H/s, W/s) logits when the model has a mask head}."""
        x = np.asarray(batch)
        pre = self.preprocess
        shape = (RGB_CHANNELS, pre.input_height, pre.input_width)
        if x.ndim != 4 or x.shape[1:] != shape or x.shape[0] < 1:
            raise InputError(f"network input has shape {x.shape}, expected (N, "
                             f"{', '.join(map(str, shape))})", self.path,
                             "preprocess images with the model's Preprocess.apply")
        if not np.issubdtype(x.dtype, np.floating):
            raise InputError(f"network input has dtype {x.dtype}, expected float32", self.path,
                             "preprocess images with the model's Preprocess.apply")
        x = np.ascontiguousarray(x, dtype=np.float32)
        try:
            outputs = self._session.run(list(self.output_names), {INPUT_NAME: x})
        except ORT_ERRORS as exc:
            raise InputError(f"onnxruntime failed ({one_line(exc)})", self.path, FIX) from None
        result = dict(zip(self.output_names, outputs, strict=True))
        self._check_outputs(result, len(x))
        return result

    def __repr__(self) -> str:
        return (f"OnnxKeypointModel({str(self.path)!r}, robot={self.robot!r}, "
                f"keypoints={len(self.keypoint_names)}, stride={self.stride})")

