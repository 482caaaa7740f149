"""The zoomed second pass: its cut, its warp, detection through it and its metadata."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from dream.camera import CameraIntrinsics
from dream.detection import detect_keypoints
from dream.errors import InputError
from dream.peaks import PeakSettings
from dream.preprocess import IMAGENET_MEAN, IMAGENET_STD, Preprocess
from dream.sequence import Frame, Sequence
from dream.zoom import ZoomSettings, warp_to_input, zoom_transform

WIDTH, HEIGHT = 640, 480
PRE = Preprocess(128, 96)                 # the whole image shrinks 5 times
DOTS = np.array([[300.3, 200.6], [352.8, 241.2]])   # panda_link0 red, panda_link2 green
DOT_SIGMA_PX = 2.0
MAP_SIGMA = 1.0                           # the fake network's belief sigma, map pixels


def _blob(uv: np.ndarray, sigma: float, width: int, height: int) -> np.ndarray:
    v, u = np.mgrid[0:height, 0:width].astype(float)
    return np.exp(-((u - uv[0]) ** 2 + (v - uv[1]) ** 2) / (2 * sigma ** 2))


def test_cut_centres_the_keypoints_box_and_caps_the_magnification():
    uv = np.array([[100.0, 100.0], [164.0, 148.0], [np.nan, np.nan]])
    t = zoom_transform(PRE, WIDTH, HEIGHT, uv, ZoomSettings(margin=0.0, max_zoom=10.0))
    assert t.scale_u == t.scale_v == pytest.approx(2.0)      # 128 / 64 and 96 / 48
    assert t.image_to_input(np.array([132.0, 124.0])) == pytest.approx([63.5, 47.5])
    capped = zoom_transform(PRE, WIDTH, HEIGHT, uv, ZoomSettings(margin=0.0, max_zoom=3.0))
    assert capped.scale_u == pytest.approx(0.2 * 3.0)
    wide = zoom_transform(PRE, WIDTH, HEIGHT, uv, ZoomSettings(margin=0.5, max_zoom=10.0))
    assert wide.scale_u == pytest.approx(1.0)                 # the box twice as wide


def test_no_cut_without_two_keypoints_or_without_a_gain():
    settings = ZoomSettings()
    assert zoom_transform(PRE, WIDTH, HEIGHT, np.array([[5.0, 5.0], [np.nan, 1.0]]),
                          settings) is None
    corners = np.array([[0.0, 0.0], [WIDTH - 1.0, HEIGHT - 1.0]])
    assert zoom_transform(PRE, WIDTH, HEIGHT, corners, settings) is None
    with pytest.raises(InputError, match="expected"):
        zoom_transform(PRE, WIDTH, HEIGHT, np.zeros(4), settings)


def test_warp_puts_an_image_point_where_the_transform_says():
    uv = np.array([123.3, 77.8])
    image = (_blob(uv, DOT_SIGMA_PX, WIDTH, HEIGHT) * 255).astype(np.float32)
    t = zoom_transform(PRE, WIDTH, HEIGHT, np.array([[100.0, 60.0], [150.0, 95.0]]),
                       ZoomSettings(margin=0.1))
    warped = warp_to_input(image, t, 0.0)
    assert warped.shape == (PRE.input_height, PRE.input_width)
    v, u = np.mgrid[0:warped.shape[0], 0:warped.shape[1]]
    centroid = np.array([(u * warped).sum(), (v * warped).sum()]) / warped.sum()
    assert centroid == pytest.approx(t.image_to_input(uv), abs=0.05)
    with pytest.raises(InputError, match="not the transform"):
        warp_to_input(image[:10], t, 0.0)


def test_settings_are_checked_and_round_trip():
    assert ZoomSettings.from_dict(ZoomSettings(0.3, 2.5).to_dict()) == ZoomSettings(0.3, 2.5)
    for bad in ({"margin": -0.1}, {"max_zoom": 1.0}, {"max_zoom": float("nan")}):
        with pytest.raises(InputError):
            ZoomSettings(**bad)
    with pytest.raises(InputError, match="margin and max_zoom"):
        ZoomSettings.from_dict({"margin": 0.2, "zoom": 3})


class DotModel:
    """A fake network that 'sees' a red dot (keypoint 0) and a green one (keypoint 1): its
    belief maps are those channels pooled to the map and blurred."""

    keypoint_names = ("panda_link0", "panda_link2")
    preprocess = PRE
    stride = 2

    def __init__(self, zoom: ZoomSettings | None):
        self.zoom = zoom
        self.inputs: list[np.ndarray] = []

    def run(self, batch: np.ndarray) -> dict[str, np.ndarray]:
        self.inputs.append(batch)
        mean = np.asarray(IMAGENET_MEAN, np.float32)[None, :, None, None]
        std = np.asarray(IMAGENET_STD, np.float32)[None, :, None, None]
        rgb = batch * std + mean
        n, _, h, w = batch.shape
        s = self.stride
        pooled = rgb[:, :2].reshape(n, 2, h // s, s, w // s, s).mean(axis=(3, 5))
        belief = np.stack([[cv2.GaussianBlur(m, (0, 0), MAP_SIGMA) for m in maps]
                           for maps in pooled])
        return {"belief": (belief / max(belief.max(), 1e-6)).astype(np.float32)}


def _dot_sequence(tmp_path) -> Sequence:
    image = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    for channel, uv in enumerate(DOTS):
        image[..., channel] = np.maximum(image[..., channel], (_blob(
            uv, DOT_SIGMA_PX, WIDTH, HEIGHT) * 255).astype(np.uint8))
    path = tmp_path / "000000.rgb.png"
    cv2.imwrite(str(path), image[..., ::-1])
    camera = CameraIntrinsics(500.0, 500.0, WIDTH / 2 - 0.5, HEIGHT / 2 - 0.5, WIDTH, HEIGHT)
    return Sequence("panda", camera, tuple(f"panda_joint{i}" for i in range(1, 8)),
                    DotModel.keypoint_names, (Frame("000000", np.zeros(7), image_path=path),))


def test_detection_maps_the_zoomed_peaks_back_to_the_image(tmp_path):
    import dream

    seq, robot = _dot_sequence(tmp_path), dream.load_robot("panda")
    errors = {}
    for zoom in (None, ZoomSettings(margin=0.5)):
        model = DotModel(zoom)
        obs = detect_keypoints(seq, robot, model, peak_params=PeakSettings())
        errors[zoom is not None] = np.linalg.norm(obs.uv[0] - DOTS, axis=-1).max()
        assert len(model.inputs) == (1 if zoom is None else 2)
    # one pass sees dots of 0.4 input pixels; the cut magnifies them about 2 times more
    assert errors[True] < 0.25 < errors[False]


def test_an_exported_model_carries_the_zoom_it_was_trained_for():
    pytest.importorskip("onnxruntime")
    from export.runner import KEY_ZOOM, ModelMetadata

    meta = ModelMetadata(robot="panda", keypoint_names=("panda_link0", "panda_hand"),
                         preprocess=Preprocess(64, 48), output_stride=2, dream_version="0",
                         config_sha256="0" * 64, belief_sigma=2.0)
    assert KEY_ZOOM not in meta.to_props() and ModelMetadata.from_props(
        meta.to_props()).zoom is None
    props = replace(meta, zoom=ZoomSettings(0.3, 3.0)).to_props()
    assert ModelMetadata.from_props(props).zoom == ZoomSettings(0.3, 3.0)
    with pytest.raises(InputError, match="corrupt dream metadata dream.zoom: max zoom"):
        ModelMetadata.from_props({**props, KEY_ZOOM: '{"margin": 0.3, "max_zoom": 0.5}'},
                                 Path("m.onnx"))
    pytest.importorskip("torch")
    from export.onnx_export import metadata_for
    from train.config import TrainConfig

    config = TrainConfig()
    config = replace(config, data=replace(config.data, robot="panda",
                                          keypoints=("panda_link0", "panda_hand")))
    assert metadata_for(config).zoom is None
    zoomed = replace(config, augment=replace(config.augment, zoom_p=0.5, zoom_margin=0.3))
    assert metadata_for(zoomed).zoom == ZoomSettings(0.3, zoomed.augment.zoom_max)
