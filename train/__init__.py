"""Keypoint belief-map network and its Lightning training (`dream train`).

Modules, one concept each: `config` (frozen dataclasses, YAML recipes, `--set` overrides),
`model` (pure nn.Modules, `build_model`), `targets` (Gaussian belief maps, numpy), `augment`
(albumentations with keypoints), `data` (DREAM folders -> tensors), `metrics` (keypoint errors
through `dream.peaks`), `module` (the LightningModule), `schedule` (the learning-rate schedule
and its revisions), `checkpoint` (`load_checkpoint`: the network and its config from one file),
`budget` (the precision and step budget that fit the machine), `run` (one training run into a
folder), `cli` (`dream train`). Importing `train` or `train.cli` imports no torch.
"""
