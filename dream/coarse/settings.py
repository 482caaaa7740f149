"""`SearchSettings`: every constant of the detector-free start (`dream.coarse`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.errors import InputError
from dream.settings_checks import check_fields


@dataclass(frozen=True)
class SearchSettings:
    """Every constant of the coarse search for a camera pose from the robot's silhouettes. Set
    on rendered fixed-camera scenes (`benchmarks/coarse_start.py`, design seeds), never on a
    real recording. Pixels are those of the scale they are used at.

    Attributes:
        guess_sigma_m, guess_sigma_rad: default 1-sigma of a rough guess, per axis (camera
            centre in the base frame; rotation vector).
        guess_samples: hypotheses drawn around a guess (each also aimed at the robot).
        max_guess_distance, max_guess_sigma: a guess whose camera lies farther from the
            robot's centre than the first, or whose 1-sigma in metres exceeds the second, both
            in units of the robot's reach (its moving parts' largest distance from the base
            origin), is refused: its numbers are not metres
            (`dream.coarse.hypotheses.check_guess_scale`).
        shell_directions: directions of the automatic search's cameras around the robot.
        shell_distances: their distances from the robot's centre, in units of its size (the
            largest distance of a mesh point from the base origin over the frames).
        shell_rolls: rolls about the optical axis of each.
        min_elevation_sin: shell cameras lie at least this high (sine of the elevation).
        search_frames: frames whose masks the hypotheses and the local refinement compare
            (evenly spaced, with motion).
        finish_frames: frames whose masks the winner's finishing refinement (and the basin
            check's) compares: more frames average out what one frame's mask gets wrong (a
            shadow, a part the colour of the scene behind it).
        surface_points: points sampled on the robot's surface per frame for the coarse score.
        coarse_width_px: mask width of the coarse score of every hypothesis.
        batch: hypotheses scored at once.
        local_starts: the best-scoring distinct hypotheses refined locally.
        in_view_starts: how many more are refined of the hypotheses of a guess (or of keypoints,
            a mark) aimed at the part of the robot in view, distinct from those and each
            other: on the masks of a close-up, a view of part of the arm scores as well as one
            of the whole arm, and ranked with the others they would crowd them out.
        distinct_m, distinct_rad: hypotheses closer than both (camera centre, rotation) are one.
        local_widths_px: mask widths of the local refinement's scales, coarsest first.
        local_rounds: polish rounds per scale of the local refinement.
        round_iou_tolerance: a round of the silhouette polish in the search (local, finish,
            basin check, jackknife) whose IoU at its scale falls more than this below the best
            of the rounds before is undone, and ends that scale's polish (the IoU of a
            sub-pixel step moves by whole pixels; a polish dragged off the robot loses tenths).
        fine_starts: candidates refined at the finest local scale too.
        finish_width_px: the winner is refined at this mask width too (at most the camera's).
        rival_m, rival_rad: a rival is a refined candidate farther than either from the best.
        min_found_iou: below this mean IoU the robot was not found in the images.
        min_found_iou_held_kept: ... unless its IoU at the finish's scale with the pixels its
            silhouettes cover in most frames kept in them (`Scales.found_iou`) reaches this.
            Set on renders (panda, ur5, xarm7, their close-ups, PR2, TIAGo Pro, a person
            guiding the arm, a late joint log): the poses more than 5 cm off reached 0.13-0.39
            at full size, the right ones the found test refused 0.43-0.66 (two with a person
            in view 0.29 and 0.36, found with its pixels away from the robot left out).
        keypoint_side_ratio: the silhouettes' cross-check undoes a kept edge alignment where
            its optimum lies nearer the keypoint pose than this times its distance to the
            aligned pose (`dream.coarse.crosscheck.sides_with_keypoints`; set on rendered
            scenes, `benchmarks/edge_align.py` seeds 100-119: with the bundled detector the
            keypoint poses lay 0.86-8 times as far from the optimum as the kept alignments,
            and the two alignments that slid off exact labels along the camera's depth
            0.23 and 0.41 times as far).
        min_gap: the best candidate's IoU must exceed the best rival's by this.
        basin_starts: restarts from around the best pose (the basin check).
        basin_m, basin_rad: how far from the best pose the restarts start.
        basin_return_m, basin_return_rad: a restart that ends this close has returned.
        basin_reference_m: `basin_m` and `basin_return_m` hold for a camera this far from the
            robot's centre or farther; a nearer one scales both by its distance over this
            (`basin_lengths`), so that the restarts move the robot as far across the image
            (the rendered scenes' shell cameras start 1 m out; a camera 0.3 m from a small
            arm moved by 5 cm started 0 of 4 restarts inside the basin of a pose 0.6 mm off).
        min_basin_share: at least this share of the restarts must return.
        jackknife_groups: frame groups left out in turn from the winner's finish (its
            1-sigma, with each link left out in turn too); 0 runs no jackknife.
        jackknife_link_points: a link is left out in turn where at least this many of its
            vertex projections over the frames lie inside the image.
        jackknife_link_groups: at most this many link groups are left out in turn: more
            links in view are left out with their neighbours along the kinematic tree
            (`dream.coarse.checks.link_groups`; set above the built-in and example-robot-data
            arms' 7-11 links, which each stay a group of their own; on a two-armed robot
            with hands, 38-111 links in view, left out one by one the finish's own scatter,
            summed over every link, made the 1-sigma 5-30 times the error).
        seed: seed of the random hypotheses and surface samples.
        find_carried: carve what the arm carries that the model lacks at the winner
            (`dream.coarse.carried`): reported, and the verdict's carried finding.
        leave_out_carried: where something is carved, search again from the winner and its
            rival without the pixels of its carved hull (`dream.coarse.carried.CarriedRegion`;
            on the rendered scenes the three searches 2-4 cm off came 1.5-1.8 cm off, the
            others with something carved stayed within 1 cm).
        carried_margin_px: the carved hull's pixels are widened by this many pixels of the
            scale compared (0, 5 and 10 were no better on all four scenes of a held ball).
        frame_influence: where a carried region is left out, the finish is repeated without
            the frames whose pull on its pose exceeds this many times the median frame's
            (`dream.coarse.scales.outlying_frames`; set on rendered held-object scenes, where
            the frames that held the finish 15-17 mm off pulled 10-57 times as hard as the
            median frame); 0 never repeats it.
        max_outlying_share: at most this share of the frames is left out so.
        away_margin_px: a mask's connected part that comes no nearer than this (pixels per
            320 px of image width) to the robot's silhouette at the pose found lies away from
            the robot (`dream.coarse.away.away_from_robot`: something else that moves).
        max_away_share: where more of the moving pixels than this lie away from the robot,
            the verdict is at most `check` (`dream.coarse.verdict.away_finding`).
        min_edges_kept_share: the edge alignment's optimum cross-checks the masks' only where
            the outline's agreement with the image edges there is at least this share of what
            it was at the start (`dream.coarse.verdict.edges_lost`; set on rendered scenes:
            the alignments that ran off, 46 mm to 4.5 m, ended at 0.03-0.28 of their start,
            those that stayed within 4 cm at 0.64-1.12).
    """

    guess_sigma_m: float = 0.3
    guess_sigma_rad: float = float(np.deg2rad(20.0))
    guess_samples: int = 2000
    max_guess_distance: float = 20.0
    max_guess_sigma: float = 5.0
    shell_directions: int = 160
    shell_distances: tuple[float, ...] = (0.5, 0.75, 1.1, 1.6, 2.4, 3.5)
    shell_rolls: int = 12
    min_elevation_sin: float = -0.3
    search_frames: int = 8
    finish_frames: int = 30
    surface_points: int = 800
    coarse_width_px: int = 64
    batch: int = 256
    local_starts: int = 48
    in_view_starts: int = 8
    distinct_m: float = 0.1
    distinct_rad: float = float(np.deg2rad(8.0))
    local_widths_px: tuple[int, ...] = (80, 160)
    local_rounds: int = 12
    round_iou_tolerance: float = 0.01
    fine_starts: int = 4
    finish_width_px: int = 640
    rival_m: float = 0.05
    rival_rad: float = float(np.deg2rad(5.0))
    min_found_iou: float = 0.4
    min_found_iou_held_kept: float = 0.4
    keypoint_side_ratio: float = 0.5
    min_gap: float = 0.05
    basin_starts: int = 4
    basin_m: float = 0.05
    basin_rad: float = float(np.deg2rad(3.0))
    basin_return_m: float = 0.01
    basin_return_rad: float = float(np.deg2rad(0.5))
    basin_reference_m: float = 1.0
    min_basin_share: float = 0.75
    jackknife_groups: int = 5
    jackknife_link_points: int = 50
    jackknife_link_groups: int = 12
    seed: int = 0
    find_carried: bool = True
    leave_out_carried: bool = True
    carried_margin_px: int = 2
    frame_influence: float = 10.0
    max_outlying_share: float = 0.2
    away_margin_px: float = 3.0
    max_away_share: float = 0.05
    min_edges_kept_share: float = 0.5

    def __post_init__(self) -> None:
        check_fields(self, "coarse search",
                     positive_ints=("guess_samples", "shell_directions", "shell_rolls",
                                    "search_frames", "finish_frames", "surface_points",
                                    "coarse_width_px", "batch", "local_starts", "local_rounds",
                                    "fine_starts", "finish_width_px", "jackknife_link_points",
                                    "jackknife_link_groups"),
                     positive=("guess_sigma_m", "guess_sigma_rad", "distinct_m", "distinct_rad",
                               "rival_m", "rival_rad", "basin_m", "basin_rad",
                               "basin_return_m", "basin_return_rad", "basin_reference_m",
                               "max_guess_distance", "max_guess_sigma"),
                     non_negative=("min_gap", "basin_starts", "min_found_iou",
                                   "min_found_iou_held_kept", "carried_margin_px",
                                   "round_iou_tolerance", "frame_influence", "in_view_starts",
                                   "min_basin_share", "jackknife_groups", "max_outlying_share",
                                   "away_margin_px", "max_away_share", "keypoint_side_ratio",
                                   "min_edges_kept_share"))
        if not self.shell_distances or min(self.shell_distances) <= 0:
            raise InputError("coarse search: shell_distances must be positive")
        if not self.local_widths_px or min(self.local_widths_px) < 8:
            raise InputError("coarse search: local_widths_px must be at least 8 px")
        if not -1 <= self.min_elevation_sin <= 1:
            raise InputError("coarse search: min_elevation_sin must lie in [-1, 1]")
        for name in ("min_found_iou", "min_found_iou_held_kept", "min_basin_share",
                     "max_outlying_share", "max_away_share", "min_edges_kept_share"):
            if getattr(self, name) > 1:
                raise InputError(f"coarse search: {name} must not exceed 1")

    def robot_found(self, iou: float, found_iou: float | None = None) -> bool:
        """Whether silhouettes overlapping the masks by `iou` at the local scales' finest (and by
        `found_iou`, `Scales.found_iou`, where known) found the robot in the images.

        >>> s = SearchSettings()
        >>> s.robot_found(0.41), s.robot_found(0.30), s.robot_found(0.30, 0.66)
        (True, False, True)
        """
        return iou >= self.min_found_iou or (
            found_iou is not None and found_iou >= self.min_found_iou_held_kept)

    def fits_clearly_better(self, iou: float, other_iou: float) -> bool:
        """Whether a pose whose silhouettes overlap the masks by `iou` explains them clearly
        better than one at `other_iou`: by more than `min_gap`.

        >>> s = SearchSettings()
        >>> s.fits_clearly_better(0.79, 0.51), s.fits_clearly_better(0.79, 0.77)
        (True, False)
        """
        return iou - other_iou > self.min_gap

    def basin_lengths(self, distance_m: float) -> tuple[float, float]:
        """(start, return) distances of the basin check for a camera `distance_m` from the
        robot's centre: `basin_m` and `basin_return_m`, scaled down where the camera is
        nearer than `basin_reference_m`.

        >>> SearchSettings().basin_lengths(2.0)
        (0.05, 0.01)
        >>> [round(v, 4) for v in SearchSettings().basin_lengths(0.5)]
        [0.025, 0.005]
        """
        if not np.isfinite(distance_m) or distance_m <= 0:
            raise InputError(f"coarse search: a camera distance must be positive, got "
                             f"{distance_m}")
        scale = min(1.0, distance_m / self.basin_reference_m)
        return self.basin_m * scale, self.basin_return_m * scale
