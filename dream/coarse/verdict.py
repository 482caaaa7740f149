"""The verdict on a pose found without keypoints (pure): did the search find the robot, does
the chosen pose explain the images clearly better than every other pose it reached, does a
refinement started near it come back, and do the image cues agree.

Each finding is (level, one sentence with what to do), as in `dream.quality`:

- **found**: the mean IoU of the chosen pose's silhouettes with the masks is below
  `min_found_iou`, and with the pixels they cover in most frames kept in them
  (`dream.coarse.scales.Scales.found_iou`) below `min_found_iou_held_kept`: the robot was not
  found (`unreliable`).
- **gap**: a candidate farther than `rival_m` / `rival_rad` explains the masks within
  `min_gap` of the chosen one's IoU: the images cannot tell the two apart (`unreliable`).
- **basin**: fewer than `min_basin_share` of the restarts around the chosen pose return to it
  (started and counted at `SearchSettings.basin_lengths` of the camera's distance): it is a
  ridge, not a clear optimum (`check`).
- **mark**: at the pose written, the mark's clicks lie farther than `max_click_residual_px`
  (median) from where the mark projects: a click, the mark's link or offset, or the pose is
  wrong (`check`).
- **crosscheck** (a pose found another way: the keypoint fit and its edge alignment): the
  local silhouette search from it (`dream.coarse.crosscheck`) ends more than `rival_m` /
  `rival_rad` away (`unreliable`), or more than a centimetre or a degree (the cues finding,
  `check`); its silhouettes overlap the masks below `min_found_iou` (the images cannot confirm
  it: `check`); the basin finding as above.
- **cues**: the written pose (the edge alignment's) and the masks' optimum differ by more than
  a centimetre or a degree: one cue is pulled by something the model lacks (`check`); where
  the masks refute the other cue's optimum (`cue_refuted`: it ran off), or the edge alignment
  lost the image edges on its way (`edges_lost`), it says so instead, and the disagreement
  stays out of the 1-sigma (`check`).
- **carried**: the carving at the pose found names something a link carries that the URDF
  lacks (`dream.coarse.carried`): the search leaves its pixels out, but it hides part of the
  arm and its carving is only as good as the pose it was carved at (`check`; on the rendered
  benchmark scenes every search that landed more than 1 cm off had one).
- **away**: more than `max_away_share` of the moving pixels lie in parts of the masks that
  come nowhere near the robot at the pose found (`dream.coarse.away`: another arm at work, a
  person): the found test reads the IoU without them, and the verdict is at most `check`.
- **focal**: the robot's outlines and their overlap ask for another focal length than the
  given one (`dream.coarse.focal`): the pose was found with it, and the user's intrinsics need
  correcting (`check`); both ask for more than its `max_change` off: the intrinsics or the
  pose are wrong (`unreliable`). In the silhouettes' cross-check of a pose found another way,
  the same ask is a `check` whose move enters the 1-sigma (`crosscheck_focal_finding`).
- **principal**: the robot's outlines ask for a principal point that turns the camera by more
  than the check's limit (`dream.coarse.principal`): adopted, the pose was found with it and
  the user's intrinsics need correcting (`check`); kept as given, or unresolved (within the
  outlines' noise, or beside something carried), the pose rests on the given cx, cy and its
  rotation may be off by that much (`check`; the turn enters the 1-sigma); the same at the
  silhouettes' cross-check's optimum.

    >>> from dream.coarse.settings import SearchSettings
    >>> s = SearchSettings()
    >>> [f[0] for f in search_findings(0.8, 0.78, 0.3, 4, 4, s)]
    ['unreliable']
    >>> search_findings(0.8, 0.5, 0.3, 4, 4, s)
    []
"""

from __future__ import annotations

import numpy as np

from dream.coarse.settings import SearchSettings
from dream.quality import (
    CHECK,
    POSITION_SIGMA_CHECK_M,
    ROTATION_SIGMA_CHECK_RAD,
    UNRELIABLE,
    Finding,
)


def search_findings(best_iou: float, rival_iou: float | None, rival_distance_m: float | None,
                    basin_returned: int, basin_starts: int,
                    settings: SearchSettings, basin_m: float | None = None,
                    found_iou: float | None = None,
                    basin_ious: list[float] | None = None,
                    found_held_kept_iou: float | None = None) -> list[Finding]:
    """The found, gap and basin findings (module doc); `basin_m`: how far the restarts
    started (default `settings.basin_m`; `SearchOutcome.basin_m`); `found_iou`: the IoU the
    found test reads (default `best_iou`; without the pixels away from the robot: the away
    finding); `basin_ious`: the IoU where each restart ended (`SearchOutcome.basin_ious`),
    which tells a narrow basin (the restarts that did not come back ended where the masks fit
    clearly worse) from a flat one; `found_held_kept_iou`: the winner's `found_iou` the found
    test also reads (`SearchSettings.robot_found`; None: not known).

    >>> s = SearchSettings()
    >>> search_findings(0.79, None, None, 0, 4, s, basin_ious=[0.39, 0.33, 0.33, 0.35])[0][1]
    ... # doctest: +ELLIPSIS
    'only 0 of 4 ... return to it, ending where the masks fit clearly worse ...'
    """
    out: list[Finding] = []
    found_iou = best_iou if found_iou is None else found_iou
    if not settings.robot_found(found_iou, found_held_kept_iou):
        kept = "" if found_held_kept_iou is None else (
            f", {found_held_kept_iou:.2f} with the pixels they cover in most frames kept "
            f"(below {settings.min_found_iou_held_kept})")
        out.append((UNRELIABLE, f"the robot's silhouettes at the pose found overlap the masks by "
                    f"IoU {found_iou:.2f} only (below {settings.min_found_iou}){kept}: the "
                    "robot was not found in the images, much else moves with it (a person "
                    "guiding it?), or the joint readings are not those of the images (a joint's "
                    "sign, the columns' order, images and readings paired a frame apart); check "
                    "the overlays, give a camera guess closer to the truth "
                    "(--camera-guess, --look-at) or a keypoint model, or record the arm "
                    "driven with nothing else moving in view"))
    if rival_iou is not None and best_iou - rival_iou < settings.min_gap:
        out.append((UNRELIABLE, f"another camera pose {rival_distance_m * 100:.0f} cm away "
                    f"explains the masks nearly as well (IoU {rival_iou:.3f} against "
                    f"{best_iou:.3f}): the images cannot tell them apart; record the arm "
                    "moving through more of the view, or give a closer camera guess"))
    if basin_starts and basin_returned < settings.min_basin_share * basin_starts:
        worse = [] if basin_ious is None else \
            [iou for iou in basin_ious if settings.fits_clearly_better(best_iou, iou)]
        how = ("the images constrain it weakly" if len(worse) < basin_starts - basin_returned
               else f"ending where the masks fit clearly worse (IoU {min(worse):.2f}-"
                    f"{max(worse):.2f} against {best_iou:.2f}): its basin is narrow")
        out.append((CHECK, f"only {basin_returned} of {basin_starts} refinements started "
                    f"{(settings.basin_m if basin_m is None else basin_m) * 100:.1f} cm / "
                    f"{np.rad2deg(settings.basin_rad):.0f} "
                    f"deg from the pose found return to it, {how}; check the overlays"))
    return out


def cues_agree(distance_m: float, angle_rad: float) -> bool:
    """Whether two image cues' poses `distance_m` and `angle_rad` apart agree: within what a
    `good` result's 1-sigma may be (`dream.quality`)."""
    return distance_m <= POSITION_SIGMA_CHECK_M and angle_rad <= ROTATION_SIGMA_CHECK_RAD


def cues_finding(distance_m: float, angle_rad: float,
                 written_by: str = "the edge alignment") -> Finding | None:
    """The cues finding (module doc): the pose written (`written_by`: the edge alignment's,
    the silhouette polish's, the keypoint fit's) against the masks' optimum.

    >>> cues_finding(0.002, 0.001) is None
    True
    >>> cues_finding(0.03, 0.001)[0]
    'check'
    """
    if cues_agree(distance_m, angle_rad):
        return None
    return CHECK, (f"{written_by} and the robot's masks disagree by {distance_m * 1e3:.1f} "
                   f"mm and {np.rad2deg(angle_rad):.2f} deg: something the model lacks (a tool, "
                   "a cable, a shadow) pulls one of them; the 1-sigma includes the disagreement; "
                   "check the overlays, or leave the suspect links out (--exclude-links)")


def cue_refuted(challenge: dict | None, settings: SearchSettings) -> bool:
    """Whether the masks refute the other cue's optimum (RESULT.json's `start.challenge`,
    `dream.coarse.challenge`): finished on them, its silhouettes fail the found test
    (`min_found_iou`) where those of the pose written (`iou_between`: the winner's, or where
    the challenge won, the winner's of the search run again) pass it. It ran off rather than
    disagreeing: its distance is no measure of the pose's error (on a rendered TIAGo Pro scene
    the edge alignment ended 3.2 m away at IoU 0.09 against the winner's 0.44, 13 mm off the
    truth; on a rendered UR10 close-up it ended 34 mm from a first winner at IoU 0.33, and the
    search run again from it found the pose 1.9 mm off at 0.73, 290 mm from the alignment's
    end).

    >>> s = SearchSettings()
    >>> cue_refuted({"iou_between": 0.44, "iou_challenger": 0.09}, s), cue_refuted(None, s)
    (True, False)
    >>> cue_refuted({"iou_between": 0.39, "iou_challenger": 0.09}, s)
    False
    >>> cue_refuted({"iou_winner": 0.32, "iou_between": 0.73, "iou_challenger": 0.33}, s)
    True
    """
    return challenge is not None and \
        challenge["iou_challenger"] < settings.min_found_iou <= challenge["iou_between"]


def refuted_finding(challenge: dict) -> Finding:
    """The cues finding where the masks refute the other cue's optimum (`cue_refuted`): the
    images' edges do not hold the pose (`check`)."""
    return CHECK, (f"{challenge['source']} ran off: it ended {challenge['distance_m'] * 1e3:.0f} "
                   f"mm and {np.rad2deg(challenge['angle_rad']):.1f} deg from where it started, "
                   f"where the robot's silhouettes overlap the masks by IoU "
                   f"{challenge['iou_challenger']:.2f} against {challenge['iou_between']:.2f} at "
                   "the pose written: the images' edges do not hold the robot (thin or dark "
                   "links, a busy background?), so the pose and its 1-sigma rest on the masks "
                   "alone; check the overlays")


def edges_lost(edges: dict | None, settings: SearchSettings) -> bool:
    """Whether the edge alignment that cross-checks the masks' optimum (RESULT.json's `edges`,
    `cross_check` true) lost the image edges on its way: the outline's agreement with them at
    its end is below `min_edges_kept_share` of what it was at the start. Its end is then no
    optimum of the edges, and its distance no measure of the pose's error (on a rendered
    close-up of a Kinova arm with a hand the URDF lacks, the alignment went from 36 % to 7 %
    and ended 46 mm from a pose 0.7 mm off; where an alignment moved a pose that the masks had
    left 42 mm off towards the truth, its agreement rose).

    >>> s = SearchSettings()
    >>> edges_lost({"cross_check": True, "agreement_before": 0.36, "agreement_after": 0.07}, s)
    True
    >>> edges_lost({"cross_check": True, "agreement_before": 0.58, "agreement_after": 0.46}, s)
    False
    >>> edges_lost({"ran": False, "kept": False}, s), edges_lost(None, s)
    (False, False)
    """
    if not edges or not edges.get("cross_check"):
        return False
    before, after = edges.get("agreement_before"), edges.get("agreement_after")
    return before is not None and after is not None and \
        after < settings.min_edges_kept_share * before


def lost_finding(edges: dict) -> Finding:
    """The cues finding where the edge alignment lost the image edges (`edges_lost`): the pose
    and its 1-sigma rest on the masks alone (`check`)."""
    return CHECK, (f"the edge alignment lost the image edges on its way to "
                   f"{edges['camera_position_change_m'] * 1e3:.0f} mm and "
                   f"{np.rad2deg(edges['rotation_change_rad']):.1f} deg from the pose found "
                   f"(the outline on them {edges['agreement_before']:.0%} -> "
                   f"{edges['agreement_after']:.0%}): something the model lacks, thin or dark "
                   "links or a busy background lead it astray, so the pose and its 1-sigma "
                   "rest on the masks alone; check the overlays")


def cue_ran_off(doc: dict, settings: SearchSettings) -> bool:
    """Whether the other cue ran off (RESULT.json's `start.challenge` and `edges`): the masks
    refute its optimum (`cue_refuted`) or the edge alignment lost the image edges on its way
    (`edges_lost`). Its distance then stays out of the 1-sigma and the cues finding."""
    return cue_refuted(doc["start"].get("challenge"), settings) \
        or edges_lost(doc.get("edges"), settings)


def ran_off_finding(doc: dict, settings: SearchSettings) -> Finding | None:
    """The cues finding where the other cue ran off (`cue_ran_off`), None where it did not."""
    if not cue_ran_off(doc, settings):
        return None
    challenge = doc["start"].get("challenge")
    return refuted_finding(challenge) if cue_refuted(challenge, settings) \
        else lost_finding(doc["edges"])


def away_finding(share: float, settings: SearchSettings) -> Finding | None:
    """The away finding (module doc) of the share of moving pixels away from the robot.

    >>> s = SearchSettings()
    >>> away_finding(0.01, s) is None, away_finding(0.3, s)[0]
    (True, 'check')
    """
    if share <= settings.max_away_share:
        return None
    return CHECK, (f"{100 * share:.0f} % of the moving pixels lie away from the robot at the pose "
                   "found (another arm at work, a person, something moved in view?): they were "
                   "not counted as robot; if the robot itself is among them the pose is wrong; "
                   "check the overlays, or record with nothing else moving")


def carried_finding(link: str, size_m) -> Finding:
    """The carried finding (module doc) of something carved at `link`, about `size_m` (3,).

    >>> carried_finding("panda_hand", (0.2, 0.1, 0.1))[0]
    'check'
    """
    size = " x ".join(f"{100 * s:.0f}" for s in size_m)
    return CHECK, (f"something the URDF lacks moves with {link} (about {size} cm, carved from "
                   "the masks): the search left its pixels out, but it hides part of the arm, "
                   "so the pose may be off by a centimetre or more; check the overlays, or "
                   "record without it (where nothing is there, the joint readings up to that link "
                   "may be offset)")


def focal_finding(focal: dict | None) -> Finding | None:
    """The focal finding (module doc) of RESULT.json's `start.focal`
    (`dream.coarse.focal.FocalEstimate.to_dict`).

    >>> focal_finding({"adopted": True, "scale": 1.04, "given": {"fx": 100.0, "fy": 100.0},
    ...                "used": {"fx": 104.0, "fy": 104.0}, "reason": "r"})[0]
    'check'
    >>> focal_finding({"adopted": False, "scale": 1.01, "reason": "the outlines agree"}) is None
    True
    """
    if focal is None:
        return None
    if focal["adopted"]:
        given, used = focal["given"], focal["used"]
        return CHECK, (f"the robot's outlines ask for a focal length x{focal['scale']:.3f} the "
                       f"given one, and their overlap agrees: the pose was found with fx, fy "
                       f"{used['fx']:.1f}, {used['fy']:.1f} (given {given['fx']:.1f}, "
                       f"{given['fy']:.1f}), and with the given ones it lies centimetres off; "
                       "correct the camera's intrinsics (an image resized or cropped after "
                       "calibrating? lens distortion left uncorrected?), or pass --fixed-focal "
                       "to keep them")
    if focal["reason"].startswith("beyond"):
        return UNRELIABLE, (f"the robot's outlines and their overlap ask for a focal length "
                            f"x{focal['scale']:.2f} the given one: the intrinsics (the image "
                            "size they belong to, their units) or the pose found are wrong; "
                            "check both")
    return None


def crosscheck_focal_finding(focal: dict | None) -> Finding | None:
    """The focal finding of the silhouettes' cross-check (RESULT.json's
    `silhouette_check.focal`, where nothing is adopted and `asked` says the outlines and the
    overlap ask for the scale): as `focal_finding`, but the pose written was not found again
    with it.

    >>> crosscheck_focal_finding({"asked": True, "adopted": False, "scale": 0.95,
    ...                           "reason": "r", "given": {"fx": 100.0, "fy": 100.0}})[0]
    'check'
    """
    if focal is None or not focal["asked"]:
        return focal_finding(focal)         # beyond its range: unreliable; else None
    given = focal["given"]
    return CHECK, (f"the robot's outlines ask for a focal length x{focal['scale']:.3f} the "
                   f"given one (fx, fy {given['fx'] * focal['scale']:.1f}, "
                   f"{given['fy'] * focal['scale']:.1f} instead of {given['fx']:.1f}, "
                   f"{given['fy']:.1f}), and their overlap agrees: with the given ones the "
                   "pose written may lie centimetres off along the camera's axis (in the "
                   "1-sigma); correct the camera's intrinsics (an image resized or cropped "
                   "after calibrating? a depth stream's intrinsics for the colour images?)")


def adopted_principal_finding(principal: dict) -> Finding:
    """The finding of an adopted principal point (RESULT.json's `principal` of the keypoint
    path, `start.principal` of the search: the record with `used`).

    >>> adopted_principal_finding({"shift_px": [12.0, -8.0], "angle_rad": 0.06,
    ...                            "given": {"cx": 160.0, "cy": 120.0},
    ...                            "used": {"cx": 172.0, "cy": 112.0}})[0]
    'check'
    """
    du, dv = principal["shift_px"]
    given, used = principal["given"], principal["used"]
    return CHECK, (f"the robot's outlines ask for a principal point {du:+.1f}, {dv:+.1f} px "
                   f"from the given one, turning the camera by "
                   f"{np.rad2deg(principal['angle_rad']):.1f} deg: the pose was found with cx, "
                   f"cy {used['cx']:.1f}, {used['cy']:.1f} (given {given['cx']:.1f}, "
                   f"{given['cy']:.1f}), and with the given ones it lies degrees off; give the "
                   "camera's calibrated cx, cy (not the image centre, and for this image "
                   "size), or pass --fixed-principal to keep them")


def principal_finding(principal: dict | None) -> Finding | None:
    """The principal finding (module doc) of RESULT.json's `start.principal`
    (`dream.coarse.principal.PrincipalEstimate.to_dict`).

    >>> principal_finding({"flagged": True, "shift_px": [12.0, -8.0], "angle_rad": 0.06,
    ...                    "given": {"cx": 160.0, "cy": 120.0}})[0]
    'check'
    >>> principal_finding({"flagged": False, "unresolved": True, "shift_px": [9.0, 2.0],
    ...                    "angle_rad": 0.04, "given": {"cx": 160.0, "cy": 120.0}})[1][:60]
    "the robot's outlines ask for a principal point +9.0, +2.0 px"
    >>> principal_finding({"flagged": False}) is None
    True
    """
    if principal is None:
        return None
    if principal.get("adopted"):
        return adopted_principal_finding(principal)
    if not (principal["flagged"] or principal.get("unresolved")):
        return None
    du, dv = principal["shift_px"]
    given = principal["given"]
    how = ("" if principal["flagged"] else ", but do not resolve it (within their noise, "
           "beside something the arm carries, or not confirmed by the overlap): nothing was "
           "adopted")
    return CHECK, (f"the robot's outlines ask for a principal point {du:+.1f}, {dv:+.1f} px "
                   f"from the given cx, cy {given['cx']:.1f}, {given['cy']:.1f}{how}; the pose "
                   f"rests on the given one, and its rotation may be off by up to "
                   f"{np.rad2deg(principal['angle_rad']):.1f} deg (in the 1-sigma); give the "
                   "camera's calibrated cx, cy (not the image centre, and for this image "
                   "size)")


def mark_finding(click_residuals_px: np.ndarray, max_px: float) -> Finding | None:
    """The mark finding (module doc) of the clicks' pixel distances at the pose written.

    >>> mark_finding(np.array([1.0, 2.0, 3.0]), 10.0) is None
    True
    >>> mark_finding(np.array([12.0, 30.0, 3.0]), 10.0)[0]
    'check'
    """
    median = float(np.median(click_residuals_px))
    if median <= max_px:
        return None
    return CHECK, (f"the mark projects {median:.0f} px (median) from where it was clicked at the "
                   "pose found: a click, --mark-link / --mark-offset or the pose is wrong; check "
                   "the overlays and the marks")


def crosscheck_findings(iou_written: float, iou_silhouettes: float, distance_m: float,
                        angle_rad: float, basin_returned: int, basin_starts: int,
                        evidence: str, settings: SearchSettings,
                        basin_m: float | None = None, away=None,
                        written_by: str = "the edge alignment") -> list[Finding]:
    """The crosscheck findings (module doc) of the silhouettes' optimum near a written pose
    (`basin_m` as in `search_findings`; `away`: RESULT.json's `silhouette_check.away`, whose
    IoU of the optimum without the away pixels the found tests read for `iou_silhouettes`, and
    whose share the away finding; `written_by`: what found the pose written, in words).

    >>> s = SearchSettings()
    >>> [f[0] for f in crosscheck_findings(0.6, 0.7, 0.12, 0.02, 4, 4, "motion masks", s)]
    ['unreliable']
    >>> crosscheck_findings(0.7, 0.7, 0.004, 0.002, 4, 4, "motion masks", s)
    []
    >>> nothing_away = {"share": 0.0, "iou_without": 0.35}
    >>> [f[0] for f in crosscheck_findings(0.5, 0.35, 0.004, 0.002, 4, 4, "motion masks", s,
    ...                                    away=nothing_away)]
    ['unreliable']
    """
    silhouettes_found = iou_silhouettes if away is None else away["iou_without"]
    found = max(iou_written, silhouettes_found)
    if found < settings.min_found_iou:
        return [(CHECK, f"the robot's silhouettes at and near the pose written overlap the "
                 f"{evidence} by IoU {found:.2f} only (below "
                 f"{settings.min_found_iou}): the images cannot confirm the pose; check the "
                 "overlays")]
    out: list[Finding] = []
    if distance_m > settings.rival_m or angle_rad > settings.rival_rad:
        out.append((UNRELIABLE, f"the robot's silhouettes ({evidence}) put the camera "
                    f"{distance_m * 100:.0f} cm and {np.rad2deg(angle_rad):.1f} deg from the "
                    f"pose written (IoU {iou_silhouettes:.2f} there, {iou_written:.2f} at the "
                    f"pose written): the keypoints or {written_by} were pulled away; "
                    "check the overlays, or calibrate without keypoints from this result "
                    "(--camera-guess RESULT.json)"))
    else:
        out.append(cues_finding(distance_m, angle_rad, written_by))
    out += search_findings(iou_silhouettes, None, None, basin_returned, basin_starts, settings,
                           basin_m, silhouettes_found)
    if away is not None:
        out.append(away_finding(away["share"], settings))
    return [f for f in out if f is not None]
