"""Training from an exported model (`trainer.init_from=MODEL.onnx`, `train.onnx_init`): the
batch norms the export folded are split again so that the network computes the exported
function, and a model of another recipe, robot or keypoint set is refused."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("lightning")
pytest.importorskip("albumentations")
onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

from dream.errors import InputError  # noqa: E402
from export.onnx_export import export_model  # noqa: E402
from export.runner import OnnxKeypointModel  # noqa: E402
from tests.trainkit import make_drawn_dataset  # noqa: E402
from train.checkpoint import load_checkpoint  # noqa: E402
from train.config import load_config  # noqa: E402
from train.model import build_model  # noqa: E402
from train.onnx_init import conv_bn_pairs, init_from_onnx  # noqa: E402
from train.run import run_training  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.filterwarnings("ignore:.*LeafSpec.*")]

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "configs" / "train" / "tiny.yaml"
# a few epochs: enough for batch-norm statistics far from their initial 0 and 1
SHORT = ("trainer.max_epochs=3", "trainer.num_threads=1")
ATOL = 1e-4


@pytest.fixture(scope="module")
def drawn(tmp_path_factory) -> Path:
    return make_drawn_dataset(tmp_path_factory.mktemp("drawn") / "data", 24)


@pytest.fixture(scope="module")
def trained(drawn, tmp_path_factory):
    """(checkpoint, exported ONNX file) of a briefly trained tiny network."""
    config = load_config(TINY, [f"data.train=[{drawn}]", *SHORT])
    ckpt = run_training(config, tmp_path_factory.mktemp("run")).last_checkpoint
    return ckpt, export_model(ckpt, tmp_path_factory.mktemp("model") / "model.onnx").path


def _images(seed: int, count: int = 6) -> torch.Tensor:
    return torch.from_numpy(np.random.default_rng(seed).standard_normal(
        (count, 3, 96, 128)).astype(np.float32))


def test_every_batch_norm_is_paired_with_the_convolution_before_it(trained):
    net, _ = load_checkpoint(trained[0])
    pairs = conv_bn_pairs(net, _images(0, 1))
    bns = [n for n, m in net.named_modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert sorted(pairs.values()) == sorted(bns)
    assert pairs["encoder.stages.0.0.conv1"] == "encoder.stages.0.0.bn1"
    assert pairs["encoder.stem.0.0"] == "encoder.stem.0.1"


def test_a_network_started_from_the_onnx_file_computes_the_exported_function(trained):
    original, config = load_checkpoint(trained[0])
    fresh = build_model(config.model, load_weights=False)
    batches = [_images(1), _images(2)]
    fresh.train()
    init_from_onnx(fresh, trained[1], config, batches)
    assert all(m.training for m in fresh.modules())   # left in the mode it was given
    fresh.eval()
    with torch.no_grad():
        for x in (_images(3), batches[0]):
            want, got = original(x), fresh(x)
            np.testing.assert_allclose(got.belief.numpy(), want.belief.numpy(), atol=ATOL)
            np.testing.assert_allclose(got.mask.numpy(), want.mask.numpy(), atol=ATOL)
        # training mode normalises by the batch's own statistics: on the images that chose the
        # split (one batch of them), those are the split's, so training starts from the same
        # function rather than from another network
        single = [batches[0]]
        init_from_onnx(fresh, trained[1], config, single)
        onnx_out = OnnxKeypointModel(trained[1], threads=1).run(batches[0].numpy())
        got = fresh.train()(batches[0])
        np.testing.assert_allclose(got.belief.numpy(), onnx_out["belief"], atol=1e-3)
    # the original's batch norms are not the split's: the same function, other parameters
    bn = "encoder.stem.0.1"
    assert not torch.allclose(dict(fresh.named_modules())[bn].running_var,
                              dict(original.named_modules())[bn].running_var)


def test_training_starts_from_the_onnx_file(trained, drawn, tmp_path):
    original, _ = load_checkpoint(trained[0])
    config = load_config(TINY, [f"data.train=[{drawn}]", "trainer.max_epochs=1",
                                "trainer.num_threads=1", "optim.lr=1.0e-9",
                                f"trainer.init_from={trained[1]}"])
    result = run_training(config, tmp_path / "run")
    tuned, saved = load_checkpoint(result.last_checkpoint)
    assert saved.trainer.init_from == str(trained[1])
    x = _images(4)
    with torch.no_grad():   # a learning rate of 1e-9: only the running statistics moved
        np.testing.assert_allclose(tuned(x).belief.numpy(), original(x).belief.numpy(),
                                   atol=0.05)


@pytest.mark.parametrize("change", ["keypoints", "width", "input"])
def test_an_onnx_file_of_another_recipe_is_refused_before_training(trained, drawn, tmp_path,
                                                                   change):
    overrides = {"keypoints": "data.keypoints=[panda_link0,panda_link2,panda_link3]",
                 "width": "model.decoder_width=16", "input": "input.input_width=160"}[change]
    config = load_config(TINY, [f"data.train=[{drawn}]", *SHORT, overrides,
                                f"trainer.init_from={trained[1]}"])
    out = tmp_path / "new" / "run"
    with pytest.raises(InputError) as info:
        run_training(config, out)
    message = str(info.value)
    assert message.startswith(f"{trained[1]}: cannot start from this model") and "\n" not in \
        message
    assert not (tmp_path / "new").exists()


def test_a_file_that_is_no_model_is_one_error_naming_it(trained, drawn, tmp_path):
    _, config = load_checkpoint(trained[0])
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    net = build_model(config.model, load_weights=False)
    with pytest.raises(InputError, match="cannot read the ONNX model") as info:
        init_from_onnx(net, bad, config, [_images(0)])
    assert str(info.value).startswith(str(bad))
    with pytest.raises(InputError, match="not found"):
        init_from_onnx(net, tmp_path / "missing.onnx", replace(config), [_images(0)])
