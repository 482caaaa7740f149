"""`EdgeSettings`: every constant of the edge alignment (`dream.edges`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dream.edges.exposure import ExposureSettings
from dream.errors import InputError
from dream.settings_checks import check_fields
from dream.silhouette import DEFAULT_MAX_TRIANGLES


@dataclass(frozen=True)
class EdgeSettings:
    """Every constant of the edge alignment. Pixels are those of the scale they are used at;
    grey levels lie in [0, 1]. Set on rendered fixed-camera scenes (`benchmarks/edge_align.py`,
    design seeds), never on a real recording.

    Attributes:
        scale_widths_px: image widths of the coarse-to-fine scales, coarsest first (capped at
            the image's own width; equal widths collapse).
        search_range_px: the edge search runs this far either side of the model's outline,
            along its normal, at every scale.
        blur_sigma_px: Gaussian blur of the grey image before its gradient, at every scale.
        min_edge_strength: an edge is a local maximum of the intensity gradient along the
            normal (grey levels per pixel) at least this strong.
        max_edge_angle_rad: and its gradient points within this angle of the normal.
        side_probe_px: with a background model, an edge must have the background just outside
            it and something else just inside, probed this far along the normal.
        motion_threshold: a pixel differs from the background by at least this (grey level).
        background_frames: frames whose per-pixel median is the background model (evenly
            spaced; where the arm rests in one pose in most frames, each pose counts once:
            `dream.edges.background.background_indices`).
        min_background_frames: fewer frames give no background model (as the motion masks'
            `MotionSettings.min_background_frames`).
        huber_scale_px: Huber scale of the edge residuals.
        max_residual_px: residuals beyond this get no weight.
        contour_band_px: a mesh vertex is an outline point when it projects this close to the
            rendered outline.
        max_points_per_frame: outline points per frame and round (evenly spaced).
        max_search_frames: frames the alignment uses (evenly spaced among those given).
        rounds_per_scale: render -> select outline -> search edges -> LM rounds per scale.
        inner_iterations: LM steps on one set of matched edges.
        initial_damping: LM lambda, relative to diag(J^T W J).
        step_tolerance_px: a scale ends when a round moves the outline points less (RMS).
        min_outline_points: fewer matched outline points end the alignment.
        agree_px: an outline point agrees with the image when its edge lies this close
            (full resolution; the keep rule and the per-link report).
        min_agreement_gain: the share of agreeing outline points must grow by more than this
            for the aligned pose to be kept.
        mismatch_ratio: a link whose outline agrees less than this fraction of the whole
            outline's agreement at the kept pose is named as not matching its model (a tool, a
            gripper, a held object).
        static_link_m: with a background model, links whose vertices move less than this
            between the frames are in the background model too and are left out.
        max_keypoint_factor, keypoint_margin_px: the median distance of all keypoint
            detections at the aligned pose must not exceed max(factor x median before,
            median before + margin).
        min_static_share: `--frames each`: a background model is used only where, in the
            median frame, at least this share of the pixels lie within `motion_threshold` of
            it (rendered fixed-camera scenes 0.94-0.96; frames of 20 different cameras 0.17).
        frame_median_margin_px: `--frames each`: a frame's aligned pose is kept only when the
            median distance of its inlier keypoints stays within their median at its keypoint
            pose / `fit_shrinkage(n)` + this (the single-frame polish's margin).
        link_weight_scale: each link's points are weighted by min(1, this x the median edge
            offset of all points / that of the link's points) (`dream.edges.refine.
            link_weights`): a link that does not match its model (a tool, a gripper) pulls
            less; 0 turns the link weights off. On the design seeds (no keypoint guard) the
            median error went 1.96 mm without, 1.75 / 1.71 / 1.82 mm with 1.5 / 2 / 3.
        max_triangles: triangle budget of the robot's meshes (`dream.silhouette`).
        exposure: with a background model, each grey frame's exposure is matched to the
            model's before they are compared, and the model's frames to their first median
            before the median is taken again (`dream.edges.exposure`); None: as read.
    """

    scale_widths_px: tuple[int, ...] = (80, 160, 320)
    search_range_px: float = 6.0
    blur_sigma_px: float = 1.0
    min_edge_strength: float = 0.02
    max_edge_angle_rad: float = 0.5
    side_probe_px: float = 2.0
    motion_threshold: float = 0.05
    background_frames: int = 60
    min_background_frames: int = 5
    huber_scale_px: float = 1.0
    max_residual_px: float = 6.0
    contour_band_px: float = 1.0
    max_points_per_frame: int = 800
    max_search_frames: int = 20
    rounds_per_scale: int = 8
    inner_iterations: int = 3
    initial_damping: float = 1e-4
    step_tolerance_px: float = 0.05
    min_outline_points: int = 20
    agree_px: float = 1.0
    min_agreement_gain: float = 0.0
    mismatch_ratio: float = 0.5
    static_link_m: float = 0.005
    min_static_share: float = 0.5
    frame_median_margin_px: float = 3.0
    max_keypoint_factor: float = 2.0
    keypoint_margin_px: float = 3.0
    link_weight_scale: float = 2.0
    max_triangles: int = DEFAULT_MAX_TRIANGLES
    exposure: ExposureSettings | None = field(default_factory=ExposureSettings)

    def __post_init__(self) -> None:
        widths = tuple(int(w) for w in self.scale_widths_px)
        if not widths or any(w < 1 for w in widths) or list(widths) != sorted(widths):
            raise InputError(f"scale_widths_px must be positive widths, coarsest first, got "
                             f"{self.scale_widths_px}")
        object.__setattr__(self, "scale_widths_px", widths)
        check_fields(self, "edge",
                     positive_ints=("background_frames", "min_background_frames",
                                    "max_points_per_frame", "max_search_frames",
                                    "rounds_per_scale", "inner_iterations", "min_outline_points",
                                    "max_triangles"),
                     positive=("search_range_px", "blur_sigma_px", "min_edge_strength",
                               "side_probe_px", "motion_threshold", "huber_scale_px",
                               "max_residual_px", "contour_band_px", "initial_damping",
                               "step_tolerance_px", "agree_px", "max_keypoint_factor",
                               "static_link_m"),
                     non_negative=("min_agreement_gain", "keypoint_margin_px", "mismatch_ratio",
                                   "frame_median_margin_px", "link_weight_scale"))
        if not 0 <= self.min_static_share <= 1:
            raise InputError(f"min_static_share must lie in [0, 1], got {self.min_static_share}")
        if not 0 < self.max_edge_angle_rad < np.pi / 2:
            raise InputError(f"max_edge_angle_rad must lie in (0, pi/2), got "
                             f"{self.max_edge_angle_rad}")
        if self.max_residual_px <= self.huber_scale_px:
            raise InputError("max_residual_px must exceed huber_scale_px")
        if self.max_keypoint_factor < 1:
            raise InputError(f"max_keypoint_factor must be >= 1, got {self.max_keypoint_factor}")
