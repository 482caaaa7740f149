"""`PolishSettings`: every constant of the silhouette polish (`dream.polish`)."""

from __future__ import annotations

from dataclasses import dataclass

from dream.errors import InputError
from dream.settings_checks import check_fields
from dream.silhouette import DEFAULT_MAX_TRIANGLES


@dataclass(frozen=True)
class PolishSettings:
    """Every constant of the silhouette polish. Metres, radians, pixels.

    Attributes:
        max_search_frames: frames used by the pose search (evenly spaced among those given).
        max_eval_frames: frames whose IoU decides (`polish_calibration` loads at most this
            many masks; `polish` scores every frame it is given).
        search_width_px: masks and camera are shrunk to at most this width during the search.
        fine_rounds: rounds at the camera's own resolution that finish a search run at a
            smaller one (a camera wider than `search_width_px`): a search pixel of a 960 px
            camera is 3 of its pixels, about 3 mm at a metre and a half.
        max_triangles: triangle budget of the robot's meshes (`dream.silhouette`).
        contour_band_px: a vertex is a contour point when it projects this close to the
            rendered outline (search resolution).
        huber_scale_px: Huber scale of the contour residuals (search resolution).
        max_residual_px: residuals beyond this get no weight (search resolution).
        max_outside_residual_px: positive residuals (the model's outline outside the observed
            mask, where an occluder may hide the robot) beyond this get no weight (search
            resolution). With 5 px the single-frame ADD AUC of `--frames each --polish` is
            93.8 on the design set and 94.8 on the held-out set, against 91.3 on both with
            15 px, the same cut both sides (docs/benchmarks.md).
        outer_iterations: render -> select contour points -> LM rounds.
        inner_iterations: LM steps on one set of contour points.
        initial_damping: LM lambda, relative to diag(J^T W J).
        step_tolerance_px: stop when a round moves the contour points less (RMS, search
            resolution).
        max_points_per_frame: contour points used per frame and round (evenly spaced).
        min_contour_points: fewer contour points in the search frames end the search.
        min_iou_gain: the mean IoU must grow by more than this for the polish to be kept.
        max_rmse_factor, rmse_margin_px: the inlier keypoints' RMSE at the polished pose must
            not exceed max(factor x RMSE before, RMSE before + margin) ("rmse" guard).
        frame_median_margin_px: a single frame's polish (the "median" guard) is kept only when
            the median distance of its n inlier keypoints stays within this of their median at
            the keypoint pose divided by `fit_shrinkage(n)`. 3 px: the best of 2, 3 and 5 on a
            rendered design set (`dream synth --num 300 --seed 6000`) without the division;
            with it, 4 frames of that set are better and none worse.
        frame_restart_below_iou: a frame (`polish_frames`) whose polish is refused or ends
            below this IoU is polished again from each of its leave-one-keypoint-out poses.
        min_evidence_iou: an all-frames polish against the data's own masks is decided by
            them alone (no keypoint veto) only where its mean IoU over the frames that agree
            reaches this; a polish that ends below it has not found the robot, and the keypoint
            detections guard it as they guard predicted masks.
        mask_starts, rank_frames: with the data's own masks, where the keypoint fit kept
            less than half of the detections and the polish ended below
            `frame_restart_below_iou`, the all-frames polish also starts from the
            `mask_starts` single-frame keypoint poses whose silhouettes overlap the masks best
            (IoU over `rank_frames` evenly spaced frames) and keeps the highest IoU: a biased
            detector can pull the all-frames keypoint fit metres away, where one
            frame's own pose may still lie in the polish's basin.
        min_frame_iou, max_frame_iou_loss, max_frame_iou_drop: an all-frames polish leaves out
            a frame whose own optimum reaches less IoU, that loses more IoU at the common pose
            than at its own, or whose IoU at the common pose lies more below the median of
            the frames kept (`dream.polish.frames`). Set on rendered scenes (seeds 100-119,
            readings of 3 in 10 frames moved 0.1-0.4 rad on one or two joints): frames with
            true readings lost at most 0.017 IoU, and reached 0.79 or more alone unless a held
            object hid part of the arm.
        min_agreeing_frames, min_agreeing_share: frames are left out only while at least this
            many, and this share of them, remain. With the network's coarse mask head (IoU
            about 0.6 with the true masks) the check left 25 of 30 frames out of one rendered
            scene and the polish ended 74 mm off; with wrong readings in 30 % of the frames at
            most 40 % were left out.
        frame_alone_rounds: rounds of the search of one frame's own optimum.
        frame_check_rounds: at most this many frames left out one by one (each a new search).
        max_median_factor, median_margin_px: an all-frames polish is refused when the median
            distance of all keypoint detections (inliers of the keypoint fit or not) grows
            past max(factor x before, before + margin) ("all-median" guard; the edge
            alignment's rule).
    """

    max_search_frames: int = 10
    max_eval_frames: int = 40
    search_width_px: int = 320
    fine_rounds: int = 5
    max_triangles: int = DEFAULT_MAX_TRIANGLES
    contour_band_px: float = 2.0
    huber_scale_px: float = 1.0
    max_residual_px: float = 15.0
    max_outside_residual_px: float = 5.0
    outer_iterations: int = 20
    inner_iterations: int = 3
    initial_damping: float = 1e-4
    step_tolerance_px: float = 0.05
    max_points_per_frame: int = 1500
    min_contour_points: int = 20
    min_iou_gain: float = 0.002
    max_rmse_factor: float = 1.5
    rmse_margin_px: float = 1.0
    frame_median_margin_px: float = 3.0
    frame_restart_below_iou: float = 0.95
    min_evidence_iou: float = 0.7
    mask_starts: int = 3
    rank_frames: int = 4
    min_frame_iou: float = 0.7
    max_frame_iou_loss: float = 0.05
    max_frame_iou_drop: float = 0.15
    min_agreeing_frames: int = 3
    min_agreeing_share: float = 0.25
    frame_alone_rounds: int = 5
    frame_check_rounds: int = 10
    max_median_factor: float = 2.0
    median_margin_px: float = 3.0

    def __post_init__(self) -> None:
        check_fields(self, "polish",
                     positive_ints=("max_search_frames", "max_eval_frames", "search_width_px",
                                    "rank_frames", "fine_rounds",
                                    "max_triangles", "outer_iterations", "inner_iterations",
                                    "min_contour_points", "max_points_per_frame",
                                    "min_agreeing_frames", "frame_check_rounds",
                                    "frame_alone_rounds"),
                     positive=("contour_band_px", "huber_scale_px", "max_residual_px",
                               "max_outside_residual_px", "initial_damping", "step_tolerance_px",
                               "max_rmse_factor", "max_median_factor"),
                     non_negative=("mask_starts", "min_iou_gain", "rmse_margin_px",
                                   "frame_median_margin_px",
                                   "max_frame_iou_loss", "max_frame_iou_drop",
                                   "median_margin_px"))
        for name in ("frame_restart_below_iou", "min_frame_iou", "min_agreeing_share",
                     "min_evidence_iou"):
            if not 0 <= getattr(self, name) <= 1:
                raise InputError(f"{name} must lie in [0, 1], got {getattr(self, name)}")
        for name in ("max_rmse_factor", "max_median_factor"):
            if getattr(self, name) < 1:
                raise InputError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.max_residual_px <= self.huber_scale_px:
            raise InputError("max_residual_px must exceed huber_scale_px")
        if not self.huber_scale_px < self.max_outside_residual_px <= self.max_residual_px:
            raise InputError("max_outside_residual_px must exceed huber_scale_px and not exceed "
                             f"max_residual_px, got {self.max_outside_residual_px}")
