"""`dream train` on bad input and the training data's edge cases: one clear error and no run
folder left behind, garbage checkpoints, letterbox padding, the held-out fraction, runs without
validation and the data order of a resumed run. Skipped without the training extras."""

from __future__ import annotations

import logging
import shutil
import warnings
from dataclasses import replace
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("lightning")
pytest.importorskip("albumentations")

from lightning.pytorch.callbacks import Callback  # noqa: E402

from dream.cli import main  # noqa: E402
from dream.errors import InputError  # noqa: E402
from dream.io import read_sequence  # noqa: E402
from dream.preprocess import Preprocess  # noqa: E402
from tests.trainkit import StopAtEpoch, make_drawn_dataset  # noqa: E402
from train.checkpoint import checkpoint_payload, load_checkpoint, read_checkpoint  # noqa: E402
from train.config import TrainConfig, load_config  # noqa: E402
from train.data import (  # noqa: E402
    KeypointDataset,
    epoch_order,
    held_out,
    make_datasets,
    resolve_from_data,
)
from train.metrics import keypoint_errors  # noqa: E402
from train.run import run_training  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "configs" / "train" / "tiny.yaml"
NUM_FRAMES = 32
QUICK = ("trainer.num_threads=1", "model.base_width=8", "trainer.max_epochs=1")


@pytest.fixture(scope="module")
def drawn(tmp_path_factory) -> Path:
    return make_drawn_dataset(tmp_path_factory.mktemp("drawn") / "data", NUM_FRAMES)


def tiny(data: Path, *overrides: str):
    return load_config(TINY, [f"data.train=[{data}]", *QUICK, *overrides])


def _copy(drawn: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(drawn, tmp_path / "data"))


def _error_line(code: int, err: str) -> str:
    """The one error line of a failed command (INFO progress lines may precede it)."""
    assert code == 2, err
    assert "Traceback" not in err, err
    errors = [line for line in err.splitlines() if "error:" in line]
    assert len(errors) == 1, err
    return errors[0]


def _train_cli(data: Path, out: Path, *extra: str) -> list[str]:
    sets = [arg for o in QUICK for arg in ("--set", o)]
    return ["train", "--config", str(TINY), "--set", f"data.train=[{data}]", *sets,
            "--out", str(out), *extra]


# ---------------------------------------------------------------- the run folder

def test_a_run_folder_that_is_a_file_is_refused(drawn, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    line = _error_line(main(_train_cli(drawn, afile)), capsys.readouterr().err)
    assert f"{afile}: the run folder is a file" in line and "Fix:" in line
    line = _error_line(main(_train_cli(drawn, afile / "run")), capsys.readouterr().err)
    assert f"{afile / 'run'}: the run folder cannot be created: {afile} is a file" in line
    assert afile.read_text() == "not a folder"
    data = _copy(drawn, tmp_path)                      # --out naming the data folder itself
    before = sorted(p.name for p in data.iterdir())
    line = _error_line(main(_train_cli(drawn, data)), capsys.readouterr().err)
    assert "holds other files and no run" in line
    assert sorted(p.name for p in data.iterdir()) == before


@pytest.mark.parametrize(("seed", "ok"), [(-1, False), (0, True), (2 ** 32 - 1, True),
                                          (2 ** 32, False)])
def test_the_seed_must_be_one_numpy_takes(seed, ok):
    if ok:
        assert load_config(TINY, [f"trainer.seed={seed}"]).trainer.seed == seed
        return
    with pytest.raises(InputError, match=r"trainer\.seed: must be an integer in \[0, 4294967295\]"):
        load_config(TINY, [f"trainer.seed={seed}"])


# ---------------------------------------------------------------- checkpoints

def _garbage_checkpoints(tmp_path: Path) -> list[Path]:
    """A sound torch file of ours, then damaged and foreign ones."""
    good = tmp_path / "good.ckpt"
    torch.save({"dream": checkpoint_payload(TrainConfig()),
                "state_dict": {"model.w": torch.arange(5000.0)}}, good)
    data = good.read_bytes()
    rng = np.random.default_rng(0)
    files = {"empty.ckpt": b"", "random.ckpt": rng.bytes(3000), "text.onnx": b"hello\n" * 50,
             "head.ckpt": data[:len(data) // 3], "tail.ckpt": data[len(data) // 2:],
             "nearly.ckpt": data[:-30]}
    flipped = bytearray(data)
    for i in rng.integers(0, len(data), 40):
        flipped[i] ^= 0xFF
    files["flipped.ckpt"] = bytes(flipped)
    paths = []
    for name, content in files.items():
        (tmp_path / name).write_bytes(content)
        paths.append(tmp_path / name)
    torch.save([1, 2, 3], tmp_path / "list.ckpt")
    torch.save({"dream": [1], "state_dict": {}}, tmp_path / "payload.ckpt")
    return [*paths, tmp_path / "list.ckpt", tmp_path / "payload.ckpt"]


def test_a_garbage_checkpoint_is_one_input_error_naming_it(tmp_path):
    for path in _garbage_checkpoints(tmp_path):
        for read in (read_checkpoint, load_checkpoint):
            with pytest.raises(InputError) as info:
                read(path)
            assert info.value.path == path and "\n" not in str(info.value), str(info.value)
            assert info.value.fix


def test_train_and_export_refuse_a_garbage_checkpoint(drawn, tmp_path, capsys):
    garbage = tmp_path / "garb.ckpt"
    garbage.write_bytes(np.random.default_rng(1).bytes(4096))
    out = tmp_path / "new" / "run"
    line = _error_line(main(_train_cli(drawn, out, "--resume", str(garbage))),
                       capsys.readouterr().err)
    assert f"{garbage}: cannot read the checkpoint" in line
    assert not (tmp_path / "new").exists()
    onnx_out = tmp_path / "model.onnx"
    line = _error_line(main(["export", "--checkpoint", str(garbage), "--out", str(onnx_out)]),
                       capsys.readouterr().err)
    assert f"{garbage}: cannot read the checkpoint" in line
    assert not onnx_out.exists()


# ------------------------------------------------ no run folder after an input error

def _truncate_an_image(data: Path) -> Path:
    image = sorted(data.glob("*.rgb.png"))[5]
    image.write_bytes(image.read_bytes()[:-200])
    return image


def _remove_the_images(data: Path) -> Path:
    for image in data.glob("*.rgb.png"):
        image.unlink()
    return data


@pytest.mark.parametrize(("overrides", "words"), [
    (("data.robot=ur5",), "and the model is for 'ur5'"),
    (("data.keypoints=[panda_link0,panda_linkXX]",), "names panda_linkXX, which no training"),
    (("data.train=[/no/such/folder]",), "does not exist. Fix: check data.train"),
])
def test_the_data_must_be_of_the_models_robot_and_label_its_keypoints(drawn, tmp_path,
                                                                      overrides, words):
    """A recipe or --set that names another robot, a keypoint the frames do not label, or a
    folder that is not there, is refused before training (the model was exported as that
    robot's, or with an untrained belief map; the fix named --data, an option train lacks)."""
    seq = read_sequence(drawn)
    assert seq.robot == "panda" and "panda_link0" in seq.keypoint_names
    out = tmp_path / "run"
    with pytest.raises(InputError, match=words):
        run_training(tiny(drawn, *overrides), out)
    assert not out.exists()


@pytest.mark.parametrize("damage", ["truncated image", "no images", "missing checkpoint",
                                    "garbage init_from"])
def test_an_input_error_found_before_training_creates_no_run_folder(drawn, tmp_path, damage):
    data = _copy(drawn, tmp_path)
    overrides, resume, named = [], None, data
    if damage == "truncated image":
        named = _truncate_an_image(data)
    elif damage == "no images":
        _remove_the_images(data)
    elif damage == "missing checkpoint":
        resume = named = tmp_path / "missing.ckpt"
    else:
        named = tmp_path / "garb.ckpt"
        named.write_bytes(b"\x80\x04garbage")
        overrides = [f"trainer.init_from={named}"]
    out = tmp_path / "new" / "run"
    with pytest.raises(InputError) as info:
        run_training(tiny(data, *overrides), out, resume=resume)
    assert str(named) in str(info.value) and "\n" not in str(info.value)
    assert not (tmp_path / "new").exists()


def _corrupt_inside(image: Path) -> None:
    """Damage the compressed data in the middle of a PNG: its header and end stay intact."""
    data = bytearray(image.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 64] = bytes(64)
    image.write_bytes(bytes(data))


@pytest.mark.parametrize("workers", [0, 1])
def test_an_image_corrupt_inside_removes_the_run_folder_it_created(drawn, tmp_path, workers):
    data = _copy(drawn, tmp_path)
    image = sorted(data.glob("*.rgb.png"))[9]
    _corrupt_inside(image)
    config = tiny(data, f"data.num_workers={workers}")
    out = tmp_path / "new" / "run"
    with pytest.raises(InputError) as info:  # found when the frame is loaded, in epoch 0
        run_training(config, out)
    assert str(info.value).startswith(f"{image}: ") and "\n" not in str(info.value)
    assert not (tmp_path / "new").exists()
    # a folder that was there before the run is left, with what it held
    kept = tmp_path / "kept"
    kept.mkdir()
    (kept / "notes.txt").write_text("mine")
    with pytest.raises(InputError):
        run_training(config, kept)
    assert (kept / "notes.txt").read_text() == "mine"


# ---------------------------------------------------------------- letterbox padding

def test_keypoints_outside_the_image_on_the_letterbox_padding_are_absent(drawn):
    """A 128x96 image letterboxed into 128x128 has 16 padding rows above and below: a keypoint
    just above the image lands on them and must get no target and no score; one far above
    stays outside the input frame, with its coordinates."""
    seq = read_sequence(drawn)
    uv = seq.frames[0].uv_labels.copy()
    uv[0] = [60.0, -5.0]    # outside the image, on the padding (input v = 11)
    uv[1] = [60.0, -40.0]   # outside the image and the input frame (input v = -24)
    uv[2] = [70.0, 50.0]    # inside
    seq = replace(seq, frames=(replace(seq.frames[0], uv_labels=uv),))
    pre = Preprocess(128, 128, mode="letterbox")
    dataset = KeypointDataset([seq], seq.keypoint_names, pre, 2, 1.5)
    t = pre.transform_for(128, 96)
    assert t.offset_v == 16 and 0 < t.image_to_input(uv[0])[1] < 16
    sample = dataset[0]
    uv_input, belief = sample["uv_input"].numpy(), sample["belief"].numpy()
    assert np.isnan(uv_input[0]).all() and belief[0].max() == 0.0
    np.testing.assert_allclose(uv_input[1], t.image_to_input(uv[1]), atol=1e-4)
    np.testing.assert_allclose(uv_input[2], t.image_to_input(uv[2]), atol=1e-4)
    assert belief[2].max() > 0.9
    scored = keypoint_errors(belief[None], uv_input[None], 2, 128, 128).scored[0]
    assert not scored[0] and not scored[1] and scored[2]


# ---------------------------------------------------------------- zoomed samples

def test_a_zoomed_sample_cuts_image_mask_and_labels_alike(drawn):
    """`augment.zoom_p` 1, nothing else: every sample is cut around its keypoints, magnified
    over the whole image's letterbox, every keypoint in the image stays in the input, and the
    robot mask (discs around the keypoints) is warped with the image: it covers each keypoint's
    target."""
    from train.augment import Augment, inside_image
    from train.config import AugmentConfig

    off = {name: 0.0 for name in AugmentConfig.__dataclass_fields__ if name.endswith("_p")}
    seq = read_sequence(drawn)
    pre = Preprocess(128, 96)
    dataset = KeypointDataset([seq], seq.keypoint_names, pre, 2, 1.5,
                              augment=Augment(AugmentConfig(**{**off, "zoom_p": 1.0}), seed=4))
    whole = pre.transform_for(seq.camera.width, seq.camera.height)
    gains = []
    for index in range(8):
        sample = dataset[index]
        labels = dataset.labels(index)
        inside = inside_image(labels, seq.camera.width, seq.camera.height)
        uv_input = sample["uv_input"].numpy()[inside]
        assert ((uv_input >= -0.5) & (uv_input <= [127.5, 95.5])).all()
        gains.append(np.ptp(uv_input, axis=0).max()
                     / np.ptp(whole.image_to_input(labels[inside]), axis=0).max())
        rows, cols = np.round((uv_input + 0.5) / 2 - 0.5).astype(int).T[::-1]
        assert (sample["mask"].numpy()[0, rows, cols] > 0.5).all()
        assert (sample["belief"].numpy()[inside].max(axis=(1, 2)) > 0.9).all()
    assert min(gains) > 0.99 and max(gains) > 1.2, gains


# ---------------------------------------------------------------- held-out frames

def test_held_out_frames_are_the_exact_fraction_spread_evenly():
    for k in range(2, 41):  # 1/k: every k-th frame, as before (0.05: frames 19, 39, ...)
        for n in (0, 1, k - 1, k, 37, 1000):
            np.testing.assert_array_equal(held_out(n, 1 / k), np.arange(n) % k == k - 1,
                                          err_msg=f"1/{k}, {n} frames")
    np.testing.assert_array_equal(np.flatnonzero(held_out(100, 0.05)), [19, 39, 59, 79, 99])
    for f in (0.0, 0.3, 0.4, 0.5, 0.6, 0.7, 0.95, 0.999):
        held = held_out(1000, f)
        prefix = np.concatenate([[0], np.cumsum(held)])
        exact = [int(Fraction(str(f)) * m) for m in range(1001)]  # floor(m f) in any prefix
        np.testing.assert_array_equal(prefix, exact, err_msg=str(f))
    assert held_out(40, 0.4).sum() == 16 and held_out(40, 0.6).sum() == 24
    with pytest.raises(InputError, match="val_fraction"):
        held_out(10, 1.0)


@pytest.mark.parametrize(("fraction", "val"), [(0.125, 4), (0.4, 12), (0.5, 16), (0.6, 19),
                                               (0.7, 22)])
def test_val_fraction_holds_out_that_share_of_the_frames(drawn, fraction, val):
    seqs = [read_sequence(drawn)]
    config = resolve_from_data(tiny(drawn, f"data.val_fraction={fraction}"), seqs)
    train, held = make_datasets(config, seqs)
    assert (len(train), len(held)) == (NUM_FRAMES - val, val)


# ---------------------------------------------------------------- runs without validation, order

class RecordOrder(Callback):
    """The sample indices of every training batch, by epoch."""

    def __init__(self):
        self.by_epoch: dict[int, list[int]] = {}

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self.by_epoch.setdefault(trainer.current_epoch, []).extend(batch["index"].tolist())


def test_epoch_order_is_a_permutation_fixed_by_seed_and_epoch():
    orders = [epoch_order(50, 7, e) for e in range(4)]
    for order in orders:
        np.testing.assert_array_equal(np.sort(order), np.arange(50))
    assert len({tuple(o) for o in orders}) == 4
    np.testing.assert_array_equal(epoch_order(50, 7, 2), orders[2])
    assert not np.array_equal(epoch_order(50, 8, 0), orders[0])


def test_a_resumed_run_sees_the_batches_of_an_uninterrupted_one(drawn, tmp_path, recwarn,
                                                                  caplog):
    config = tiny(drawn, "trainer.max_epochs=3", "data.val_fraction=0")
    whole = RecordOrder()
    with caplog.at_level(logging.INFO, logger="train"):
        run_training(config, tmp_path / "whole", callbacks=[whole])
    # no validation data: one line of ours, no Lightning warning about it
    assert not [w for w in recwarn if "val_dataloader" in str(w.message)]
    assert any("no validation data" in r.getMessage() for r in caplog.records)
    killed = RecordOrder()
    with pytest.raises(KeyError):
        run_training(config, tmp_path / "killed", callbacks=[killed, StopAtEpoch(2)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_training(config, tmp_path / "killed", callbacks=[killed])
    assert sorted(killed.by_epoch) == [0, 1, 2]
    for epoch in range(3):
        assert killed.by_epoch[epoch] == whole.by_epoch[epoch], epoch
    assert whole.by_epoch[2] != whole.by_epoch[0]
