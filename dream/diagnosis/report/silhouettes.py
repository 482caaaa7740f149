"""Silhouette panels of the report: a frame's observed robot mask against the rendered one,
before and after the extension (`silhouettes.png`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from dream.diagnosis.report.plots import PANEL_IN, empty_panel, plt
from dream.errors import InputError
from dream.silhouette import silhouette_iou

MAX_SILHOUETTE_PANELS = 6      # frames shown in silhouettes.png
OVERLAY_ALPHA = 0.55           # opacity of the mask colours over the image
IMAGE_DIM = 0.6                # the photo is dimmed to this brightness under the overlay
BOTH_RGB = (40, 220, 40)       # observed and rendered robot
OBSERVED_ONLY_RGB = (255, 60, 40)
RENDERED_ONLY_RGB = (40, 120, 255)


@dataclass(frozen=True, eq=False)
class SilhouettePanel:
    """One frame's observed robot mask against the rendered one, before and after extension.

    Attributes:
        frame: frame name.
        image: (H, W, 3) uint8 RGB photo.
        observed_mask: (H, W) bool, the robot seen in the photo.
        rendered_before: (H, W) bool, the robot rendered by the nominal model.
        rendered_after: (H, W) bool rendered by the extended model, or None.
        iou_before, iou_after: IoU of the observed mask with each rendering (iou_after None
            when there is no `rendered_after`; computed when None and it is given).
    """

    frame: str
    image: np.ndarray
    observed_mask: np.ndarray
    rendered_before: np.ndarray
    rendered_after: np.ndarray | None
    iou_before: float
    iou_after: float | None = None

    def __post_init__(self) -> None:
        image = np.asarray(self.image)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise InputError(f"silhouette panel '{self.frame}': image must be (H, W, 3) uint8, "
                             f"got {image.shape} {image.dtype}", fix="give an RGB uint8 image")
        hw = image.shape[:2]
        for name in ("observed_mask", "rendered_before", "rendered_after"):
            mask = getattr(self, name)
            if mask is None and name == "rendered_after":
                continue
            mask = np.asarray(mask)
            if mask.shape != hw:
                raise InputError(f"silhouette panel '{self.frame}': {name} has shape "
                                 f"{mask.shape}, expected {hw} (the image's)",
                                 fix="render the masks at the image's size")
            object.__setattr__(self, name, mask.astype(bool))
        if self.rendered_after is not None and self.iou_after is None:
            object.__setattr__(self, "iou_after",
                               silhouette_iou(self.observed_mask, self.rendered_after))
        if self.rendered_after is None and self.iou_after is not None:
            raise InputError(f"silhouette panel '{self.frame}': iou_after given without "
                             f"rendered_after", fix="give both or neither")
        for name in ("iou_before", "iou_after"):
            value = getattr(self, name)
            if value is None and name == "iou_after":
                continue
            if not isinstance(value, (int, float, np.floating)) or not 0.0 <= value <= 1.0:
                raise InputError(f"silhouette panel '{self.frame}': {name} = {value!r} is not "
                                 f"in [0, 1]", fix="give the intersection over union")
            object.__setattr__(self, name, float(value))
        object.__setattr__(self, "image", image)


def silhouette_overlay(image: np.ndarray, observed: np.ndarray,
                       rendered: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: the dimmed photo with both masks coloured: BOTH_RGB where they agree,
    OBSERVED_ONLY_RGB where only the photo has robot, RENDERED_ONLY_RGB where only the model."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"image must be (H, W, 3), got {image.shape}")
    observed = np.asarray(observed, dtype=bool)
    rendered = np.asarray(rendered, dtype=bool)
    if observed.shape != image.shape[:2] or rendered.shape != image.shape[:2]:
        raise InputError(f"masks {observed.shape} and {rendered.shape} do not match the image "
                         f"{image.shape[:2]}")
    out = image.astype(float) * IMAGE_DIM
    for mask, rgb in ((observed & rendered, BOTH_RGB), (observed & ~rendered, OBSERVED_ONLY_RGB),
                      (~observed & rendered, RENDERED_ONLY_RGB)):
        out[mask] = (1 - OVERLAY_ALPHA) * out[mask] + OVERLAY_ALPHA * np.array(rgb, float)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def plot_silhouettes(panels: Sequence[SilhouettePanel]) -> Figure:
    """One row per frame (at most MAX_SILHOUETTE_PANELS): the overlay before, and after when
    some panel has an extended rendering; IoU in the titles."""
    panels = list(panels)[:MAX_SILHOUETTE_PANELS]
    cols = 2 if any(p.rendered_after is not None for p in panels) else 1
    rows = max(1, len(panels))
    h, w = panels[0].image.shape[:2] if panels else (3, 4)
    fig, axes = plt.subplots(rows, cols, squeeze=False,
                             figsize=(PANEL_IN * cols, PANEL_IN * rows * h / w + 0.6))
    for i, p in enumerate(panels):
        views = [("nominal", p.rendered_before, p.iou_before),
                 ("extended", p.rendered_after, p.iou_after)][:cols]
        for ax, (name, rendered, iou) in zip(axes[i], views, strict=True):
            if rendered is None:
                empty_panel(ax, "no extended rendering")
                continue
            ax.imshow(silhouette_overlay(p.image, p.observed_mask, rendered))
            ax.set_title(f"{p.frame} {name}: IoU {iou:.3f}", fontsize=9)
            ax.axis("off")
    if not panels:
        empty_panel(axes[0, 0], "no silhouettes")
    fig.suptitle("green: both, red: photo only, blue: model only", fontsize=9)
    fig.tight_layout()
    return fig
