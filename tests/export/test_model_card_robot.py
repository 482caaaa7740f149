"""The SHA-256 of the robot's URDF on an exported model's card: written by `dream export` where
the URDF can be read, optional when read (models exported without it still load)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

pytest.importorskip("onnxruntime")

from dream import BUNDLED_MODEL  # noqa: E402
from dream.errors import InputError  # noqa: E402
from dream.preprocess import Preprocess  # noqa: E402
from dream.robot import load_robot  # noqa: E402
from dream.robot.identity import urdf_sha256  # noqa: E402
from export.runner import KEY_URDF_HASH, ModelMetadata, OnnxKeypointModel  # noqa: E402

CONFIG_HASH = "0" * 64


def _metadata(**changes) -> ModelMetadata:
    meta = ModelMetadata(robot="panda", keypoint_names=("panda_link0", "panda_hand"),
                         preprocess=Preprocess(64, 48), output_stride=2, dream_version="0",
                         config_sha256=CONFIG_HASH, belief_sigma=2.0)
    return replace(meta, **changes)


def test_urdf_hash_round_trips_and_is_optional():
    digest = urdf_sha256(load_robot("panda").urdf_path)
    props = _metadata(urdf_sha256=digest).to_props()
    assert props[KEY_URDF_HASH] == digest
    assert ModelMetadata.from_props(props).urdf_sha256 == digest
    older = _metadata().to_props()
    assert KEY_URDF_HASH not in older and ModelMetadata.from_props(older).urdf_sha256 is None
    with pytest.raises(InputError, match="corrupt dream metadata: URDF hash"):
        ModelMetadata.from_props({**older, KEY_URDF_HASH: "not-a-hash"}, Path("m.onnx"))


def test_bundled_model_without_a_hash_still_loads():
    model = OnnxKeypointModel(BUNDLED_MODEL, threads=1)
    assert model.robot == "panda" and model.urdf_sha256 is None


def test_export_metadata_carries_the_urdf_hash(tmp_path):
    pytest.importorskip("torch")
    from export.onnx_export import metadata_for
    from train.config import TrainConfig

    config = TrainConfig()
    config = replace(config, data=replace(config.data, robot="panda",
                                          keypoints=("panda_link0", "panda_hand")))
    assert metadata_for(config).urdf_sha256 == urdf_sha256(load_robot("panda").urdf_path)
    gone = replace(config, data=replace(config.data, robot=str(tmp_path / "gone.urdf")))
    assert metadata_for(gone).urdf_sha256 is None
