"""Training data: DREAM-layout folders -> augmented, preprocessed tensors with belief targets.

One sample: image -> augmentation (keypoints and mask carried along) -> preprocessing (resize or
letterbox to the network input, or for a zoomed sample the cut around its keypoints,
`train.augment`) -> targets built from the keypoints after both. Keypoints are
taken from each frame's `uv_labels` (image pixels, NaN where absent), reordered to the config's
keypoint names (a name a dataset lacks is absent in all its frames). Frames without an image or
without labels are skipped. A keypoint outside the image that the letterbox brings into the
input frame (onto the padding) is absent (NaN): no target and not scored, as for the fill of the
affine augmentation (`train.augment`).

Shuffling (`EpochShuffle`) draws epoch e's order from seed + e, so that a resumed run sees the
batches an uninterrupted run would.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler, get_worker_info

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.io import image_size, load_image, load_mask, read_sequence
from dream.io.images import (
    NPZ_SUFFIX,
    PNG_SIGNATURE,
    PNG_TAIL_BYTES,
    check_file_end,
    check_size,
)
from dream.preprocess import Preprocess
from dream.robot.identity import same_robot_name
from dream.sequence import Frame, Sequence
from dream.zoom import cut_input, warp_to_input
from train.augment import Augment, inside_image
from train.config import TrainConfig
from train.targets import belief_maps, map_size, mask_map

logger = logging.getLogger(__name__)

_SEED_MODULUS = 2 ** 32
_SEED_MODULUS_64 = 2 ** 64
_MAX_DENOMINATOR = 10 ** 9  # val_fraction as an exact fraction (0.05 -> 1/20)
_FIX_IMAGE = "replace it with a complete, readable PNG or JPEG image"


def read_folders(folders: SequenceOf[str]) -> list[Sequence]:
    """Read DREAM-layout (or any `dream.io` layout) folders; at least one is required."""
    if not folders:
        raise InputError("no dataset folders given", fix="set data.train=[DIR, ...] in the recipe "
                         "or with --set")
    missing = [folder for folder in folders if not Path(folder).exists()]
    if missing:
        raise InputError("the dataset folder does not exist", missing[0],
                         "check data.train / data.val (the recipe or --set)")
    return [read_sequence(folder) for folder in folders]


def resolve_from_data(config: TrainConfig, sequences: SequenceOf[Sequence]) -> TrainConfig:
    """Fill `data.keypoints`, `data.robot` and `model.num_keypoints` from the first training
    sequence where the config leaves them null."""
    first = sequences[0]
    keypoints = config.data.keypoints or first.keypoint_names
    if not keypoints:
        raise InputError("the training data names no keypoints", first.source,
                         "write keypoints with projected_location in the frame files")
    robot = config.data.robot or first.robot
    for seq in sequences:
        if not same_robot_name(seq.robot, robot):
            raise InputError(f"holds frames of robot {seq.robot!r}, and the model is for "
                             f"{robot!r}", seq.source, "train on frames of one robot (data.train"
                             ", data.robot)")
    named = {name for seq in sequences for name in seq.keypoint_names}
    missing = [name for name in keypoints if name not in named]
    if missing:
        raise InputError(f"data.keypoints names {', '.join(missing)}, which no training frame "
                         f"labels (they label {', '.join(sorted(named))})", first.source,
                         "name keypoints the data labels, or leave data.keypoints null")
    data = replace(config.data, keypoints=tuple(keypoints), robot=robot)
    model = replace(config.model, num_keypoints=config.model.num_keypoints or len(keypoints))
    return config.replace(data=data, model=model)


@dataclass(frozen=True)
class _Item:
    sequence: int
    frame: int


class KeypointDataset(Dataset):
    """Samples of one or more sequences.

    Args:
        sequences: the sequences (their frames with an image and labels are used).
        keypoint_names: belief-map order.
        preprocess: image -> network input.
        stride: output stride of the network (input px per map px).
        sigma: belief Gaussian sigma, map px.
        augment: random augmentation, or None (validation).
        use_masks: load robot masks where frames have them.
        frame_filter: one bool per usable frame (with an image and labels, in order): keep it.

    A sample is a dict of tensors: `image` (3, H, W) float32 normalised, `belief` (K, H/s, W/s),
    `uv_input` (K, 2) keypoints in input pixels after augmentation (NaN: absent), `mask`
    (1, H/s, W/s) robot fraction, `has_mask` () bool, `index` () int.
    """

    def __init__(self, sequences: SequenceOf[Sequence], keypoint_names: SequenceOf[str],
                 preprocess: Preprocess, stride: int, sigma: float,
                 augment: Augment | None = None, use_masks: bool = True,
                 frame_filter: SequenceOf[bool] | None = None):
        self.sequences = list(sequences)
        self.keypoint_names = tuple(keypoint_names)
        self.preprocess = preprocess
        self.stride = stride
        self.sigma = sigma
        self.augment = augment
        self.use_masks = use_masks
        map_size(preprocess.input_width, preprocess.input_height, stride)
        self._columns = [self._column_map(seq) for seq in self.sequences]
        items = []
        skipped = 0
        for s, seq in enumerate(self.sequences):
            for f, frame in enumerate(seq.frames):
                if frame.image_path is None or frame.uv_labels is None:
                    skipped += 1
                    continue
                items.append(_Item(s, f))
        if frame_filter is not None:
            if len(frame_filter) != len(items):
                raise InputError(f"frame filter has {len(frame_filter)} entries for "
                                 f"{len(items)} frames")
            items = [item for item, keep in zip(items, frame_filter, strict=True) if keep]
        if skipped:
            logger.warning("%d frames without an image or labels are skipped", skipped)
        self.items = items

    def _column_map(self, seq: Sequence) -> np.ndarray:
        """(K,) index into the sequence's keypoints for each name, -1 where it has none."""
        index = {name: i for i, name in enumerate(seq.keypoint_names)}
        columns = np.array([index.get(name, -1) for name in self.keypoint_names])
        if np.all(columns < 0):
            raise InputError(f"the data has none of the keypoints {', '.join(self.keypoint_names)}"
                             f" (it has {', '.join(seq.keypoint_names) or 'none'})", seq.source,
                             "train on data of the same robot or set data.keypoints")
        return columns

    def __len__(self) -> int:
        return len(self.items)

    def frame(self, index: int) -> tuple[Sequence, Frame]:
        item = self.items[index]
        seq = self.sequences[item.sequence]
        return seq, seq.frames[item.frame]

    def labels(self, index: int) -> np.ndarray:
        """(K, 2) image-pixel labels of a sample in belief-map order, NaN where absent."""
        item = self.items[index]
        seq = self.sequences[item.sequence]
        columns = self._columns[item.sequence]
        uv = np.full((len(columns), 2), np.nan)
        have = columns >= 0
        uv[have] = seq.frames[item.frame].uv_labels[columns[have]]
        return uv

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        seq, frame = self.frame(index)
        image = load_image(frame, seq.camera)
        uv = self.labels(index)
        mask = load_mask(frame, seq.camera) if self.use_masks and frame.mask_path else None
        pre = self.preprocess
        cut = None
        if self.augment is not None:
            image, uv, mask = self.augment(image, uv, mask)
            cut = self.augment.zoom(uv, image.shape[1], image.shape[0], pre)
        if cut is None:
            x, transform = pre.apply(image)
        else:
            x, transform = cut_input(pre, image, cut), cut
        uv_input = transform.image_to_input(uv)
        on_padding = (~inside_image(uv, image.shape[1], image.shape[0])
                      & inside_image(uv_input, pre.input_width, pre.input_height))
        uv_input[on_padding] = np.nan  # outside the image, on the letterbox padding
        belief = belief_maps(uv_input, pre.input_width, pre.input_height, self.stride, self.sigma)
        if mask is not None:
            in_input = pre.apply_mask(mask) if cut is None else \
                warp_to_input(mask.astype(np.float32), cut, 0.0)
            mask_target = mask_map(in_input, self.stride)
        else:
            mask_target = np.zeros((1,) + belief.shape[1:], np.float32)
        return {"image": torch.from_numpy(x), "belief": torch.from_numpy(belief),
                "uv_input": torch.from_numpy(uv_input.astype(np.float32)),
                "mask": torch.from_numpy(mask_target),
                "has_mask": torch.tensor(mask is not None), "index": torch.tensor(index)}


def _reseed_worker(worker_id: int) -> None:
    """DataLoader `worker_init_fn`: a different augmentation stream in every worker."""
    info = get_worker_info()
    if info is not None and getattr(info.dataset, "augment", None) is not None:
        info.dataset.augment.reseed(info.seed % _SEED_MODULUS)


def held_out(n: int, fraction: float) -> np.ndarray:
    """(n,) bool: the frames `make_datasets` holds out for validation, `fraction` of them spread
    evenly: frame i when floor((i + 1) f) > floor(i f), in exact arithmetic on the decimal value
    of f (so f = 1/k holds out every k-th frame, frames k-1, 2k-1, ...). floor(n f) frames, so
    with f < 1 at least one frame is left for training."""
    if not 0 <= fraction < 1:
        raise InputError(f"config data.val_fraction: must be in [0, 1), got {fraction}",
                         fix="correct the recipe YAML or the --set override")
    f = Fraction(str(fraction)).limit_denominator(_MAX_DENOMINATOR)
    floors = (np.arange(n + 1, dtype=np.int64) * f.numerator) // f.denominator
    return floors[1:] > floors[:-1]


def make_datasets(config: TrainConfig, train_sequences: SequenceOf[Sequence],
                  val_sequences: SequenceOf[Sequence] = ()
                  ) -> tuple[KeypointDataset, KeypointDataset]:
    """Training and validation datasets of a resolved config. Without validation sequences,
    `data.val_fraction` of the training frames is held out (`held_out`)."""
    data = config.data
    common = dict(keypoint_names=data.keypoints, preprocess=config.input,
                  stride=config.model.output_stride, sigma=data.belief_sigma,
                  use_masks=data.use_masks and config.model.mask_head)
    augment = Augment(config.augment, seed=config.trainer.seed) if config.augment.enabled \
        else None
    if val_sequences:
        train = KeypointDataset(train_sequences, augment=augment, **common)
        val = KeypointDataset(val_sequences, **common)
    else:
        held = held_out(len(KeypointDataset(train_sequences, **common)), data.val_fraction)
        train = KeypointDataset(train_sequences, augment=augment, frame_filter=~held, **common)
        val = KeypointDataset(train_sequences, frame_filter=held, **common)
    if len(train) == 0:
        sources = ", ".join(str(s.source) for s in train_sequences)
        raise InputError(f"no training frames with an image and keypoint labels in {sources}",
                         fix="point data.train at DREAM folders with images and labels")
    logger.info("%d training and %d validation frames", len(train), len(val))
    return train, val


def _check_image_file(path: Path, camera: CameraIntrinsics | None) -> None:
    """Header (readable, its size the camera's) and end (not truncated) of one image file."""
    check_size(*image_size(path), camera, path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(len(PNG_SIGNATURE))
            fh.seek(0, os.SEEK_END)
            fh.seek(max(fh.tell() - PNG_TAIL_BYTES, 0))
            tail = fh.read()
    except OSError as exc:
        raise InputError(f"cannot read the image ({exc.strerror or type(exc).__name__})", path,
                         _FIX_IMAGE) from None
    check_file_end(head, tail, path)


def check_image_files(*datasets: KeypointDataset) -> None:
    """Check, before a run starts, every image and mask file its datasets will load: each
    opens, its header gives the camera's size and it is not truncated (a PNG ends with its IEND
    chunk, a JPEG with its end marker). Two small reads a file (the header and the last KiB),
    no decoding: corruption inside the compressed data shows only when the frame is loaded. An
    .npz image stack: its first and last images used are loaded."""
    checked: set[Path] = set()
    stacks: dict[Path, list[tuple[Frame, Sequence]]] = {}
    for dataset in datasets:
        for index in range(len(dataset)):
            seq, frame = dataset.frame(index)
            paths = [frame.image_path]
            if dataset.use_masks and frame.mask_path is not None:
                paths.append(frame.mask_path)
            for path in paths:
                if path in checked:
                    continue
                if path.suffix.lower() == NPZ_SUFFIX:
                    stacks.setdefault(path, []).append((frame, seq))
                    continue
                checked.add(path)
                _check_image_file(path, seq.camera)
    for frames in stacks.values():
        by_index = sorted(frames, key=lambda fs: fs[0].image_index or 0)
        for frame, seq in {id(f): (f, s) for f, s in (by_index[0], by_index[-1])}.values():
            load_image(frame, seq.camera)


class EpochShuffle(Sampler[int]):
    """A random order of `n` samples drawn afresh each epoch from `seed + epoch` (Lightning
    calls `set_epoch` before each epoch, as for a `DistributedSampler`): epoch e has the same
    order whether or not the run was interrupted and resumed before it."""

    def __init__(self, n: int, seed: int):
        self.n = n
        self.seed = seed
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.n

    def __iter__(self) -> Iterator[int]:
        return iter(epoch_order(self.n, self.seed, self.epoch).tolist())


def epoch_order(n: int, seed: int, epoch: int) -> np.ndarray:
    """The order of `n` samples in epoch `epoch` of a run seeded with `seed`."""
    generator = torch.Generator().manual_seed((seed + epoch) % _SEED_MODULUS_64)
    return torch.randperm(n, generator=generator).numpy()


def make_loader(dataset: KeypointDataset, config: TrainConfig, shuffle: bool) -> DataLoader:
    """The loader of a dataset; `shuffle`: a fresh order each epoch (`EpochShuffle`, seeded by
    `trainer.seed`)."""
    workers = config.data.num_workers
    sampler = EpochShuffle(len(dataset), config.trainer.seed) if shuffle else None
    return DataLoader(dataset, batch_size=config.data.batch_size, sampler=sampler,
                      num_workers=workers, persistent_workers=workers > 0,
                      worker_init_fn=_reseed_worker, drop_last=False)
