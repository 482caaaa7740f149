"""The detector-free start of a fixed-camera calibration: the robot's masks of the recording
(the data's own, or motion masks), camera hypotheses from a guess or a shell around the robot,
and the coarse search (`dream.coarse.search`); `dream.coarse.result` makes of its winner a
stand-in keypoint result, so that the image refinements (`--refine`) and RESULT.json take it
from there.

With motion masks, the links that never move are left out of the model (they are in the
background model, so not in the masks), the pixels the robot covers in most frames at a
hypothesis are not compared (`dream.coarse.evidence.held_pixels`: a shoulder turning in place
stays in the background model), and the search uses the frames whose masks show motion, drawn
as the background model's are (`dream.edges.background.median_frames`). The hypotheses are
scored on a few frames (`search_frames`); the winner is finished on up to `finish_frames` (on
rendered scenes, one frame's mask error moves the optimum of 8 frames by 1-2 cm, of 30 by a few
millimetres). At the winner, in turn: the joint log's lag behind the images is read
(`dream.coarse.timing`; also where the found test fails, which a late log can fail at the
right pose), and where the robot was found what the arm carries that the URDF lacks is carved
(`dream.coarse.carried`) and its pixels left out (the finishes then also leave out the frames
that pull the pose far harder than the others, `dream.coarse.scales`), and the lens's radial
distortion, the principal point and the focal length the robot's outlines ask for are fitted
(`dream.coarse.intrinsics`;
only where the robot was found with the held pixels left out of its silhouettes, as the fits
score them); each that is adopted runs the search again from the winner, and the callers go
on with what it adopted.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.carried import CarriedRegion, carried_geometry, carried_region
from dream.coarse.distortion import DistortionEstimate, DistortionSettings
from dream.coarse.focal import FocalEstimate, FocalSettings
from dream.coarse.hypotheses import around, check_guess_scale, fibonacci_directions, shell
from dream.coarse.intrinsics import with_asked_intrinsics
from dream.coarse.mark import (
    Mark,
    MarkSettings,
    check_mark_offset,
    mark_points,
    mark_pose,
    mark_sigma,
    placed_by_mark,
    track_mark,
)
from dream.coarse.principal import PrincipalEstimate, PrincipalSettings
from dream.coarse.search import SearchOutcome, Winner, find_winner, searched_again
from dream.coarse.settings import SearchSettings
from dream.coarse.timing import LagEstimate, TimingSettings, with_timing
from dream.diagnosis.attached import AttachedSettings, CarvingOutcome
from dream.errors import InputError
from dream.pipeline import joints_in_robot_order
from dream.pnp import MIN_KEYPOINTS, PoseFit
from dream.polish.objective import evenly_spaced
from dream.robot import Robot
from dream.sequence import Sequence
from dream.silhouette import (
    RobotMeshes,
    load_robot_meshes,
    static_links,
    vertices_in_base,
    without_links,
)

log = logging.getLogger(__name__)

GUESS, SHELL, CARRIED, MARK, TIMING = "guess", "shell", "carried", "mark", "timing"
DATA_MASKS, MOTION_MASKS = "the data's masks", "motion masks"
MOTION_CANDIDATES = 3   # frames tried for motion masks per search frame (evenly spaced)


@dataclass(frozen=True)
class CameraGuess:
    """A rough camera pose and how rough (1-sigma per axis); `T_cam_base` None asks for the
    automatic search around the robot. `user_given`: the numbers were typed, so their scale is
    checked against the robot's reach (`check_guess_scale`) before any hypothesis is drawn."""

    T_cam_base: np.ndarray | None
    sigma_m: float
    sigma_rad: float
    description: str
    user_given: bool = False
    look_at_base_m: np.ndarray | None = None     # the point a typed guess looks at (3,)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.sigma_m) and self.sigma_m > 0 and np.isfinite(self.sigma_rad)
                and self.sigma_rad > 0):
            raise InputError(f"the guess's 1-sigma must be positive, got {self.sigma_m} m and "
                             f"{self.sigma_rad} rad", fix="give --guess-sigma M,DEG, e.g. "
                             "0.3,20")


@dataclass(frozen=True)
class SearchMasks:
    """What the search compares: the meshes (without links the masks do not show), the chosen
    frames' indices, joints (n, J) and masks (n, H, W), the masks' source, links left out, and
    the positions among the chosen of the frames the hypotheses are scored on (`search`; the
    finishing refinement compares them all), and what the carving at the first winner found
    the arm carrying (`carried`; None where it did not run; `dream.coarse.carried`) and the
    pixels of it left out of the search (`region`; None where none are), and with motion
    masks how they were made (`motion`: the hysteresis on or off, a block-compressed recording's
    being off, and how many of the frames had their exposure matched; None with the data's
    masks), and the joint log's lag read at the winner (`timing`; `dream.coarse.timing`:
    where adopted, `joints` are the readings shifted by it), and the principal point and the
    focal-length scale the outlines ask for (`principal`, `focal`; None where not fitted;
    `dream.coarse.intrinsics`: where either is adopted, the search's pose is the one through
    `dream.coarse.intrinsics.adopted_camera`), and so the lens's radial distortion
    (`distortion`; `dream.coarse.distortion`)."""

    meshes: RobotMeshes
    frames: np.ndarray
    joints: np.ndarray
    masks: np.ndarray
    source: str
    left_out: tuple[str, ...]
    search: np.ndarray
    carried: CarvingOutcome | None = None
    region: CarriedRegion | None = None
    motion: dict | None = None
    focal: FocalEstimate | None = None
    timing: LagEstimate | None = None
    principal: PrincipalEstimate | None = None
    distortion: DistortionEstimate | None = None

    @property
    def held(self) -> bool:
        """Whether the masks are motion masks, which miss what the robot covers in most
        frames (`dream.coarse.evidence.held_pixels`)."""
        return self.source == MOTION_MASKS


def search_masks(sequence: Sequence, robot: Robot, settings: SearchSettings) -> SearchMasks:
    """The data's masks, or without them motion masks of the frames that show motion (module
    doc): up to `search_frames` frames for the hypotheses and, with them, up to `finish_frames`
    for the finish (each evenly spaced).

    Raises:
        InputError: a camera that moves, frames without images, an arm that hardly moves.
    """
    from dream.edges.background import median_frames
    from dream.edges.motion import (
        MotionSettings,
        check_motion,
        frame_gain,
        motion_masks,
        sequence_motion_model,
    )
    from dream.io import load_image, load_mask

    camera = sequence.fixed_camera("search for one camera pose from the robot's silhouettes")
    joints = joints_in_robot_order(sequence, robot)
    meshes = load_robot_meshes(robot)
    with_mask = np.flatnonzero([f.mask_path is not None for f in sequence.frames])
    if len(with_mask):
        frames, search = _frame_sets(with_mask, with_mask, settings)
        masks = np.stack([load_mask(sequence.frames[i], camera) for i in frames])
        return SearchMasks(meshes, frames, joints[frames], masks, DATA_MASKS, (), search)
    background, motion = sequence_motion_model(sequence, MotionSettings())
    everything = median_frames(joints)       # as the background model's frames
    for_search = evenly_spaced(everything, MOTION_CANDIDATES * settings.search_frames)
    tried = np.union1d(for_search, evenly_spaced(everything, settings.finish_frames))
    masks, matched = [], 0
    for i in tried:
        image = load_image(sequence.frames[int(i)], camera)
        gain = frame_gain(image, background, motion)
        masks.append(motion_masks(image[None], background, motion, [gain])[0])
        matched += gain != 1.0
    masks = np.stack(masks)
    coverage = masks.reshape(len(masks), -1).mean(axis=1)
    check_motion(coverage[np.isin(tried, for_search)], motion, str(sequence.source))
    moving = tried[coverage >= motion.min_area_fraction]
    frames, search = _frame_sets(moving[np.isin(moving, for_search)], moving, settings)
    static = static_links(meshes, joints, motion.static_link_m)
    if set(static) >= set(meshes.links):
        raise InputError("the arm does not move in these frames, so motion masks cannot show "
                         "it", sequence.source, "record the arm moving, or give robot masks")
    if static:
        meshes = without_links(meshes, static)
    made = {"hysteresis": motion.weak_threshold < motion.threshold,
            "frames_exposure_matched": int(matched), "frames_made": len(tried)}
    return SearchMasks(meshes, frames, joints[frames], masks[np.searchsorted(tried, frames)],
                       MOTION_MASKS, static, search, motion=made)


def _frame_sets(for_search: np.ndarray, for_finish: np.ndarray, settings: SearchSettings
                ) -> tuple[np.ndarray, np.ndarray]:
    """(the frames, sorted; the positions among them of the search's): up to `search_frames`
    of `for_search` and up to `finish_frames` of `for_finish`, each evenly spaced.

    >>> [a.tolist() for a in _frame_sets(np.arange(0, 9, 2), np.arange(9),
    ...                                  SearchSettings(search_frames=2, finish_frames=3))]
    [[0, 4, 8], [0, 2]]
    """
    search = evenly_spaced(for_search, settings.search_frames)
    frames = np.union1d(search, evenly_spaced(for_finish, settings.finish_frames))
    return frames, np.searchsorted(frames, search)


def hypotheses_for(guess: CameraGuess, inputs: SearchMasks, settings: SearchSettings
                   ) -> tuple[dict[str, np.ndarray], tuple[str, ...]]:
    """The hypotheses of a guess (`around` it) or of the automatic search (a `shell` around
    the robot's moving geometry, sized by it), and the sources scored only aimed at the
    robot."""
    out: dict[str, np.ndarray] = {}
    aimed_only: tuple[str, ...] = ()
    rng = np.random.default_rng(settings.seed)
    if guess.T_cam_base is not None:
        if guess.user_given:
            P = vertices_in_base(inputs.meshes, inputs.joints).reshape(-1, 3)
            # the reach: the moving parts' farthest distance from the base origin, the arm's
            # size even where only its wrist moves
            check_guess_scale(guess.T_cam_base, guess.sigma_m, P.mean(axis=0),
                              float(np.max(np.linalg.norm(P, axis=1))),
                              settings.max_guess_distance, settings.max_guess_sigma,
                              guess.description, guess.look_at_base_m)
        out[GUESS] = around(guess.T_cam_base, guess.sigma_m, guess.sigma_rad,
                            settings.guess_samples, rng)
    else:
        P = vertices_in_base(inputs.meshes, inputs.joints).reshape(-1, 3)
        centre = P.mean(axis=0)
        size = float(np.max(np.linalg.norm(P - centre, axis=1)))
        out[SHELL] = shell(centre, size, fibonacci_directions(settings.shell_directions,
                                                               settings.min_elevation_sin),
                           settings.shell_distances, settings.shell_rolls)
        aimed_only = (SHELL,)
    return out, aimed_only


def coarse_start(sequence: Sequence, robot: Robot, guess: CameraGuess,
                 settings: SearchSettings | None = None,
                 progress: Callable[[str], None] | None = None,
                 extra: dict[str, np.ndarray] | None = None,
                 focal: FocalSettings | None = None, timing: TimingSettings | None = None,
                 principal: PrincipalSettings | None = None,
                 distortion: DistortionSettings | None = None
                 ) -> tuple[SearchOutcome, SearchMasks]:
    """The coarse search of a fixed-camera `sequence` (module doc); `extra`: more hypotheses
    by source (the keypoint pose of a detector), scored beside the guess's; `timing`: whether
    and how the lag is fitted, first; `principal`, `focal`, `distortion`: whether and how the
    intrinsics the outlines ask for are fitted and adopted (`dream.coarse.intrinsics`)."""
    settings = settings or SearchSettings()
    inputs = search_masks(sequence, robot, settings)
    if progress is not None:
        progress(f"{inputs.source} of {len(inputs.frames)} frames"
                 + (f" (left out, never moving: {', '.join(inputs.left_out)})"
                    if inputs.left_out else ""))
    hypotheses, aimed_only = hypotheses_for(guess, inputs, settings)
    hypotheses.update(extra or {})
    winner = find_winner(inputs.meshes, inputs.joints, inputs.masks, sequence.camera,
                         hypotheses, settings, aimed_only=aimed_only,
                         held=inputs.held, progress=progress,
                         search_frames=inputs.search)
    def again(moved: SearchMasks, last: Winner) -> Winner:
        return searched_again(sequence.camera, moved, last, last.best.T_cam_base, TIMING,
                              settings, progress)
    first = (winner, inputs)      # kept where the robot stays unfound even with a lag
    winner, inputs = with_timing(sequence, joints_in_robot_order(sequence, robot), inputs,
                                 winner, settings, timing or TimingSettings(), again,
                                 inputs.held, progress)
    if not settings.robot_found(winner.best.iou, winner.best.found_iou):
        return first[0].checked(), first[1]
    if settings.find_carried:
        winner, inputs = with_carried(sequence.camera, inputs, winner, settings, progress)
    return with_asked_intrinsics(sequence.camera, inputs, winner, settings, focal, principal,
                                 progress, distortion)


def with_carried(camera: CameraIntrinsics, inputs: SearchMasks, winner: Winner,
                 settings: SearchSettings, progress: Callable[[str], None] | None = None
                 ) -> tuple[Winner, SearchMasks]:
    """The carving at the winner (`dream.coarse.carried`) in the inputs; where it finds
    something and `settings.leave_out_carried`, the search again from the winner and its rival
    without the carved hull's pixels (`CarriedRegion`), its checks still to run (the first
    winner's never run); otherwise the first winner."""
    say = progress or (lambda line: None)
    attached = AttachedSettings()
    carving = carried_geometry(inputs.meshes, inputs.joints, inputs.masks, camera,
                               winner.best.T_cam_base, attached)
    inputs = replace(inputs, carried=carving)
    if carving.finding is None:
        say(f"nothing carried found: {carving.reason}")
        return winner, inputs
    link, points = carving.finding.geometry.link, carving.finding.points_link
    say(f"something the URDF lacks moves with {link} (about "
        f"{' x '.join(f'{100 * s:.0f}' for s in carving.finding.geometry.size_m)} cm, "
        f"{carving.finding.points} carved points)"
        + (": searching again without its pixels" if settings.leave_out_carried else ""))
    if not settings.leave_out_carried:
        return winner, inputs
    region = carried_region(inputs.meshes.robot, inputs.joints, link, points, attached.voxel_m,
                            settings.carried_margin_px)
    inputs = replace(inputs, region=region)
    return (searched_again(camera, inputs, winner, winner.best.T_cam_base, CARRIED, settings,
                           progress), inputs)


@dataclass(frozen=True)
class MarkStart:
    """The mark's start: the mark, the guess around its pose, its PnP fit, the frames it is
    known in (clicked and tracked, indices into the sequence), how many were clicked, the mark
    in the base frame at the clicked frames (to check the clicks at the pose found), and the
    hypotheses it adds. Known in fewer frames than a pose needs, it has no fit: the guess asks
    for the automatic search, and each orientation of the search's shell, placed where the
    mark's frames put it (`dream.coarse.mark.placed_by_mark`), joins its hypotheses."""

    mark: Mark
    guess: CameraGuess
    fit: PoseFit | None
    frames: np.ndarray
    clicked: int
    P_clicked_base: np.ndarray
    hypotheses: dict[str, np.ndarray]

    @property
    def placed(self) -> int:
        """How many cameras the mark placed for the search (0 where it has a pose)."""
        return sum(map(len, self.hypotheses.values()))


def mark_start(sequence: Sequence, robot: Robot, mark: Mark,
               settings: SearchSettings | None = None,
               mark_settings: MarkSettings | None = None) -> MarkStart:
    """The mark tracked through the fixed camera's images and its PnP over time
    (`dream.coarse.mark`), as a guess searched around within the PnP's own 1-sigma; known in
    fewer than `MIN_KEYPOINTS` frames, the automatic search with cameras placed by the mark
    (`MarkStart`)."""
    import cv2

    from dream.io import load_image

    settings = settings or SearchSettings()
    mark_settings = mark_settings or MarkSettings()
    camera = sequence.fixed_camera("find one camera pose from a tracked mark")
    joints = joints_in_robot_order(sequence, robot)

    def gray(i: int) -> np.ndarray | None:
        frame = sequence.frames[i]
        if frame.image_path is None:
            return None
        return cv2.cvtColor(load_image(frame, camera), cv2.COLOR_RGB2GRAY)

    check_mark_offset(robot, joints, mark.link, mark.offset_link_m,
                      mark_settings.max_offset_reach)
    P_base = mark_points(robot, joints, mark.link, mark.offset_link_m)
    frames, uv = track_mark(gray, mark.frames, mark.uv, P_base, mark_settings)
    known = (f"{len(mark.frames)} clicked, {len(frames) - len(mark.frames)} tracked frames")
    if len(frames) < MIN_KEYPOINTS:
        placed = placed_by_mark(shell_orientations(settings), P_base[frames], uv, camera)
        guess = CameraGuess(None, settings.guess_sigma_m, settings.guess_sigma_rad,
                            f"the automatic search, with its orientations placed by the mark "
                            f"on {mark.link} ({known}: too few for a pose of its own)")
        return MarkStart(mark, guess, None, frames, len(mark.frames), P_base[mark.frames],
                         {MARK: placed})
    fit = mark_pose(P_base[frames], uv, camera)
    sigma_m, sigma_rad = mark_sigma(fit, mark_settings, settings.guess_sigma_m,
                                    settings.guess_sigma_rad)
    guess = CameraGuess(fit.T_cam_base, sigma_m, sigma_rad,
                        f"around the pose of the mark on {mark.link} ({known})")
    return MarkStart(mark, guess, fit, frames, len(mark.frames), P_base[mark.frames], {})


def shell_orientations(settings: SearchSettings) -> np.ndarray:
    """(n, 3, 3) the automatic search's camera orientations: looking at the robot from each
    of its shell's directions, with each of its rolls (`shell`)."""
    directions = fibonacci_directions(settings.shell_directions, settings.min_elevation_sin)
    return shell(np.zeros(3), 1.0, directions, (1.0,), settings.shell_rolls)[:, :3, :3]
