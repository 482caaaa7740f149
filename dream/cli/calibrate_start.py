"""`dream calibrate` by the silhouette search: without keypoints (neither `--model` nor
`--use-labels`), or with them and `--camera-guess` or `--mark` (the keypoint pose is then one
more hypothesis). The camera pose is searched from the robot's silhouettes (`dream.coarse`),
around `--camera-guess`, around the pose of a tracked `--mark` or, without either, on a shell
around the robot; then the image refinement of `--refine` from there, the verdict of
`dream.coarse.verdict` and RESULT.json's `start` object."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path
from typing import TextIO

import numpy as np

from dream.cli.options import AUTO, EDGES, POLISH, parse_numbers
from dream.errors import InputError

FIX_GUESS = ("give --camera-guess X,Y,Z --look-at X,Y,Z (metres, base frame: where the camera "
             "is and a point on the robot it looks at) or --camera-guess RESULT.json")
FIX_SIGMA = "give --guess-sigma METRES,DEGREES, e.g. 0.3,20"
MAX_SIGMA_DEG = 180.0     # a rotation 1-sigma beyond this is not degrees of one guess
KEYPOINTS = "keypoints"   # the search's hypothesis source of --model / --use-labels
FIX_MARK = ("give --mark MARKS.csv --mark-link LINK [--mark-offset X,Y,Z] (the clicked point, "
            "metres in that link's frame)")


def check_frames(request) -> None:
    """The search finds one pose for all frames (before any reading)."""
    if request.frames != "all":
        raise InputError("the silhouette search finds the one camera pose of a fixed camera "
                         "(--frames all)", request.data,
                         "use --frames all, or give --model without --camera-guess or --mark "
                         "for --frames each")


def check_mark_options(request) -> None:
    """`--mark` with its link, its offset's numbers, and not with a camera guess (before any
    reading)."""
    if request.mark is None:
        if request.mark_link is not None or request.mark_offset is not None:
            raise InputError("--mark-link and --mark-offset describe the point of --mark, and "
                             "no --mark was given", fix=FIX_MARK)
        return
    if request.mark_link is None:
        raise InputError("--mark needs --mark-link: the link the clicked point is fixed to",
                         fix=FIX_MARK)
    if request.camera_guess is not None or request.look_at is not None:
        raise InputError("--mark and --camera-guess both say where to search", fix="give one")
    if request.mark_offset is not None:
        parse_numbers(request.mark_offset, (3,), "--mark-offset", FIX_MARK)


def read_mark(request, seq, robot):
    """The `Mark` of the options (its link checked against the robot)."""
    from dream.coarse.mark import Mark, read_marks

    robot.tree.check_link(request.mark_link)
    offset = (np.zeros(3) if request.mark_offset is None else
              np.array(parse_numbers(request.mark_offset, (3,), "--mark-offset", FIX_MARK)))
    frames, uv = read_marks(request.mark, seq)
    return Mark(request.mark_link, offset, frames, uv)


def camera_guess(camera_guess: str | None, look_at: str | None, guess_sigma: str | None):
    """The `CameraGuess` of the options (`T_cam_base` None: the automatic search)."""
    from dream.coarse.calibration import CameraGuess
    from dream.coarse.hypotheses import guess_pose
    from dream.coarse.settings import SearchSettings

    defaults = SearchSettings()
    sigma_m, sigma_rad = defaults.guess_sigma_m, defaults.guess_sigma_rad
    if guess_sigma is not None:
        m, deg = parse_numbers(guess_sigma, (2,), "--guess-sigma", FIX_SIGMA)
        sigma_m, sigma_rad = float(m), float(np.deg2rad(deg))
        if not (sigma_m > 0 and sigma_rad > 0):
            raise InputError(f"--guess-sigma {guess_sigma} must be positive", fix=FIX_SIGMA)
        if deg > MAX_SIGMA_DEG:
            raise InputError(f"--guess-sigma {guess_sigma}: a 1-sigma of {deg:g} deg turns the "
                             f"camera every way (at most {MAX_SIGMA_DEG:g})", fix=FIX_SIGMA)
    if camera_guess is None:
        if look_at is not None:
            raise InputError("--look-at goes with --camera-guess X,Y,Z", fix=FIX_GUESS)
        if guess_sigma is not None:     # the automatic search and a mark set their own spread
            raise InputError("--guess-sigma goes with --camera-guess (how rough the guess is)",
                             fix=FIX_GUESS)
        return CameraGuess(None, sigma_m, sigma_rad, "automatic search around the robot")
    if Path(camera_guess).suffix.lower() == ".json" or Path(camera_guess).is_file():
        from dream.result import read_result

        if look_at is not None:
            raise InputError("--look-at goes with a camera position, not a result file",
                             fix=FIX_GUESS)
        doc = read_result(camera_guess)
        return CameraGuess(np.asarray(doc["T_cam_base"], float), sigma_m, sigma_rad,
                           f"around the extrinsic of {camera_guess}", user_given=True)
    if look_at is None:
        raise InputError("--camera-guess X,Y,Z needs --look-at X,Y,Z (a point on the robot the "
                         "camera looks at)", fix=FIX_GUESS)
    position = parse_numbers(camera_guess, (3,), "--camera-guess", FIX_GUESS)
    target = parse_numbers(look_at, (3,), "--look-at", FIX_GUESS)
    return CameraGuess(guess_pose(position, target), sigma_m, sigma_rad,
                       f"around a camera at {list(position)} looking at {list(target)}",
                       user_given=True, look_at_base_m=np.asarray(target, float))


def keypoint_hypothesis(request, seq, out: TextIO) -> tuple:
    """The robot and the keypoint pose of `--model` (or the labels) over all frames, as one
    more source of the search's hypotheses ({} where the keypoints give no pose)."""
    from dream.calibration import CalibrationError
    from dream.cli.observe import observe
    from dream.pipeline import calibrate

    robot, obs, _ = observe(seq, request.robot, request.model, request.use_labels, out,
                            threads=request.threads, batch=request.batch,
                            loaded_model=request.loaded_model, keypoints=request.keypoint_links)
    try:
        T = calibrate(seq, obs, "all", request.solver_settings()).fit.T_cam_base
    except (CalibrationError, InputError) as exc:
        print(f"the keypoints give no pose ({exc}); the search goes on without them", file=out)
        return robot, {}
    print("the keypoint pose joins the search's hypotheses", file=out)
    return robot, {KEYPOINTS: np.asarray(T)[None]}


def search_start(request, seq, out: TextIO):
    """The search (module doc): robot, the stand-in result and observations at its pose, its
    outcome and masks, and the guess."""
    from dream.cli.search_robot import robot_for_search
    from dream.coarse.calibration import coarse_start
    from dream.coarse.distortion import DistortionSettings
    from dream.coarse.focal import FocalSettings
    from dream.coarse.principal import PrincipalSettings
    from dream.coarse.result import search_covariance, stand_in_result
    from dream.coarse.timing import TimingSettings

    guess = camera_guess(request.camera_guess, request.look_at, request.guess_sigma)
    robot, extra = (keypoint_hypothesis(request, seq, out) if request.keypoints_given
                    else (robot_for_search(seq, request), {}))
    marked = None
    if request.mark is not None:
        from dream.coarse.calibration import mark_start

        marked = mark_start(seq, robot, read_mark(request, seq, robot))
        guess = marked.guess
        extra = {**extra, **marked.hypotheses}
        known = f"mark: {marked.clicked} clicked and {len(marked.frames) - marked.clicked} " \
                "tracked frames"
        print(f"{known}, too few for a pose of their own: they place each orientation of the "
              f"automatic search ({marked.placed} cameras)"
              if marked.fit is None else
              f"{known}, pose over time RMSE {marked.fit.rmse_px:.1f} px; searching within "
              f"{guess.sigma_m * 100:.0f} cm / {np.rad2deg(guess.sigma_rad):.0f} deg", file=out)
    if KEYPOINTS in extra:
        guess = replace(guess, description=guess.description + "; the keypoint pose")
    print(f"searching the camera pose from the robot's silhouettes, "
          f"{guess.description}", file=out)

    outcome, inputs = coarse_start(seq, robot, guess, progress=_progress, extra=extra,
                                   focal=FocalSettings(fit=not request.fixed_focal),
                                   principal=PrincipalSettings(
                                       adopt=not request.fixed_principal),
                                   timing=TimingSettings(fit=not request.stamped_timing),
                                   distortion=DistortionSettings(
                                       fit=not request.fixed_distortion))
    result, obs = stand_in_result(seq, outcome.best.T_cam_base,
                                  search_covariance(outcome, focal=inputs.focal,
                                                    timing=inputs.timing,
                                                    principal=inputs.principal,
                                                    distortion=inputs.distortion))
    print(f"search ({outcome.seconds:.1f} s, {inputs.source} of {len(inputs.frames)} frames): "
          f"best IoU {outcome.best.iou:.3f}, best rival "
          f"{'none' if outcome.rival is None else f'{outcome.rival.iou:.3f}'}, "
          f"{outcome.basin_returned} of {outcome.basin_starts} restarts returned", file=out)
    return robot, result, obs, outcome, inputs, guess, marked


def with_fitted_intrinsics(seq, inputs, out: TextIO):
    """The sequence through the camera whose principal point or focal length the search
    fitted and adopted (`dream.coarse.intrinsics`), so that the refinements after it see what
    it saw; else as given."""
    from dream.coarse.intrinsics import adopted_camera, intrinsics_change

    given, camera = seq.camera, adopted_camera(seq.camera, inputs)
    if camera == given:
        return seq
    print(f"intrinsics: {intrinsics_change(given, camera)}, fitted to the robot's outlines; "
          "the pose and every refinement after the search use them (--fixed-distortion, "
          "--fixed-focal, --fixed-principal keep the given ones)", file=out)
    return seq.with_fixed_camera(camera)


def _progress(line: str) -> None:
    print(f"  search: {line}", file=sys.stderr)


def search_quality(doc: dict, cue_move: tuple[float, float] | None, out: TextIO,
                   marked=None, camera=None, extra: tuple = ()) -> dict:
    """The verdict on a pose found without keypoints: the search's findings, the cues', the
    mark's clicks at the pose written (with `--mark`), the condition of the pose written
    (`dream.quality`) and the `extra` findings (a camera that moved)."""
    from dream.coarse.distortion import distortion_finding
    from dream.coarse.settings import SearchSettings
    from dream.coarse.timing import timing_finding
    from dream.coarse.verdict import (
        away_finding,
        carried_finding,
        cues_finding,
        focal_finding,
        mark_finding,
        principal_finding,
        ran_off_finding,
        search_findings,
    )
    from dream.quality import condition_findings, quality_from

    s, settings = doc["start"], SearchSettings()
    away = s.get("away")
    found = s.get("found_iou") if away is None else away.get("found_iou_without")
    findings = search_findings(s["iou"], s["rival_iou"], s["rival_distance_m"],
                               s["basin_returned"], s["basin_starts"], settings,
                               s["basin_m"], None if away is None else away["iou_without"],
                               s.get("basin_ends_iou"), found)
    if away is not None:
        findings.append(away_finding(away["share"], settings))
    if cue_move is not None:
        findings.append(cues_finding(*cue_move))
    findings.append(ran_off_finding(doc, settings))
    findings += [f for f in (distortion_finding(s.get("distortion")),
                             focal_finding(s.get("focal")), timing_finding(s.get("timing")),
                             principal_finding(s.get("principal"))) if f is not None]
    carried = s.get("carried") or {}
    if carried.get("named"):
        findings.append(carried_finding(carried["named"],
                                        carried["box_around_hull"]["size_m"]))
    if marked is not None:
        from dream.coarse.mark import MarkSettings, click_residuals

        residuals = click_residuals(np.asarray(doc["T_cam_base"]), marked.mark,
                                    marked.P_clicked_base, camera)
        s["mark"]["click_residuals_px"] = residuals.tolist()
        findings.append(mark_finding(residuals, MarkSettings().max_click_residual_px))
    findings += condition_findings(np.asarray(doc["covariance_xi"]),
                                   np.asarray(doc["T_cam_base"]))
    quality = quality_from(0, 0, findings + list(extra))
    print(f"quality: {quality.verdict}", file=out)
    for warning in quality.warnings:
        print(f"  - {warning}", file=out)
    return quality.to_dict()


def run_search(request, seq, data_doc: dict, readings_doc: dict | None, refine: str, paths,
               out: TextIO, motion=None) -> dict:
    """`dream calibrate` by the silhouette search (`dream.cli.calibrate_start`); `motion`:
    the camera's, where it was measured (`measure_steadiness`)."""
    from dream.cli.calibrate_report import add_polish, steadiness_record
    from dream.cli.calibrate_write import finish
    from dream.coarse.timing import lag_applied
    from dream.refined_uncertainty import with_cue_term

    if request.model_extension:
        raise InputError("--model-extension corrects a keypoint calibration, not the "
                         "silhouette search", request.model_extension,
                         "drop --model-extension, or give --model without --camera-guess and "
                         "--mark")
    robot, result, obs, outcome, inputs, guess, marked = search_start(request, seq, out)
    seq = with_fitted_intrinsics(seq, inputs, out)
    seq, marked = lag_applied(seq, robot, inputs.timing, marked)
    found = (seq, outcome, inputs, guess, marked)
    doc = search_document(request, data_doc, readings_doc, result, obs, found)
    T_other = T_own = None
    if refine == POLISH:
        doc = add_polish(seq, robot, result, obs, None, doc, out, frames="all",
                         mask_head=False)
    elif refine == EDGES:
        doc, T_other = _edges_after_search(request, seq, robot, result, obs, doc, out)
        if request.refine == AUTO and T_other is not None:
            result, obs, doc, T_own = _challenged(request, data_doc, readings_doc, found,
                                                  T_other, (result, obs, doc), out)
    doc, cue_move = with_cue_term(doc, counted_cue(doc, T_other), T_own)
    moved = steadiness_record(motion, seq, doc)
    doc["quality"] = search_quality(doc, cue_move, out, marked, seq.camera, (moved,))
    finish(request, seq, robot, obs, result, doc, paths, out)
    return doc


def counted_cue(doc: dict, T_other: np.ndarray | None) -> np.ndarray | None:
    """The other image cue's optimum whose distance enters the 1-sigma and the cues finding:
    `T_other`, or None where it ran off (`dream.coarse.verdict.cue_ran_off`): its distance
    measures nothing.

    >>> counted_cue({"start": {"challenge": None}, "edges": {"cross_check": True,
    ...     "agreement_before": 0.36, "agreement_after": 0.07}}, np.eye(4)) is None
    True
    """
    from dream.coarse.settings import SearchSettings
    from dream.coarse.verdict import cue_ran_off

    if T_other is None or cue_ran_off(doc, SearchSettings()):
        return None
    return T_other


def search_document(request, data_doc: dict, readings_doc: dict | None, result, obs,
                    found: tuple) -> dict:
    """RESULT.json's document of the search's stand-in `result`, with its `start` object;
    `found`: the sequence, the search's outcome, its masks, the guess and the mark."""
    from dream.cli.calibrate_write import result_document
    from dream.cli.start_record import start_doc

    seq, outcome, inputs, guess, marked = found
    doc = result_document(request, seq, result, obs, data_doc, readings_doc)
    doc["rmse_px"] = None
    doc["start"] = start_doc(outcome, inputs, guess, seq, marked)
    doc["uncertainty"]["method"] = (
        f"jackknife of the search's finish over {len(outcome.frames_xi)} frame groups and "
        f"{len(outcome.links_xi)} links + spread of its restarts around the pose found (the "
        "basin check)" if len(outcome.frames_xi) or len(outcome.links_xi) else
        "spread of the search's restarts around the pose found (the basin check)")
    return doc


def _challenged(request, data_doc: dict, readings_doc: dict | None, found: tuple,
                T_edges: np.ndarray, written: tuple, out: TextIO) -> tuple:
    """The edge alignment's optimum against the search's winner on the masks, and the pose
    between the two that the masks choose (`dream.coarse.challenge`): the stand-in result,
    observations and document of that pose (of the search run again where the alignment's
    optimum won; the alignment's object kept), else `written` (the result, observations and
    document as they were); and the masks' own optimum (`Challenge.masks_optimum`), None
    where the pose written is the winner. RESULT.json's `start.challenge` says what happened."""
    from dream.coarse.challenge import challenged
    from dream.coarse.result import search_covariance, stand_in_result

    seq, outcome, inputs, guess, marked = found
    result, obs, doc = written
    outcome, challenge = challenged(seq.camera, inputs, outcome, T_edges, "the edge alignment",
                                    progress=_progress)
    if challenge is None:
        return result, obs, doc, None
    if challenge.won:
        print(f"the edge alignment's optimum, finished on the masks, explains them better (IoU "
              f"{challenge.iou_winner:.3f} -> {challenge.iou_challenger:.3f}): the search "
              f"from it won, best IoU {outcome.best.iou:.3f}", file=out)
    if challenge.share > 0:
        print(f"the masks put the pose {challenge.share:.0%} of the way from their optimum to "
              f"the edge alignment's (IoU {challenge.iou_between:.3f})", file=out)
    if challenge.won or challenge.share > 0:
        result, obs = stand_in_result(seq, challenge.T_cam_base_between,
                                      search_covariance(outcome, focal=inputs.focal,
                                                        timing=inputs.timing,
                                                        principal=inputs.principal,
                                                        distortion=inputs.distortion))
        doc = {**search_document(request, data_doc, readings_doc, result, obs,
                                 (seq, outcome, inputs, guess, marked)), "edges": doc["edges"]}
    doc["start"]["challenge"] = challenge.to_dict()
    doc["start"]["seconds"] = outcome.seconds
    return result, obs, doc, (challenge.masks_optimum(outcome.best.T_cam_base)
                              if challenge.share > 0 else None)


def _edges_after_search(request, seq, robot, result, obs, doc: dict,
                        out: TextIO) -> tuple[dict, np.ndarray | None]:
    """The edge alignment after the search: with `--refine edges` its pose is written (the
    masks' optimum is the other cue); under `--refine auto` the masks' optimum is written and
    the alignment's own optimum is the cross-check whose disagreement enters the 1-sigma and
    the verdict (on rendered scenes the edges of a small, glossy arm pull it centimetres off
    where the masks do not), whether or not it gained agreement (`edge_cross_check`). Returns
    the document and the other cue's pose."""
    from dream.cli.calibrate_report import add_edges
    from dream.cli.calibrate_write import refined_or_kept

    start = np.asarray(doc["start"]["T_cam_base"])
    aligned = refined_or_kept(request, lambda: add_edges(
        seq, robot, result, obs, doc, out, request.exclude_links), doc, out)
    if request.refine == EDGES:
        return aligned, start
    edges, T_edges = edge_cross_check(aligned["edges"])
    if T_edges is not None:
        print("  (--refine auto without keypoints writes the masks' optimum; the edge "
              "alignment's optimum cross-checks it: --refine edges writes the alignment's)",
              file=out)
    return {**doc, "edges": edges}, T_edges


def edge_cross_check(edges: dict) -> tuple[dict, np.ndarray | None]:
    """An edge alignment's RESULT.json object as the search's cross-check, and its own
    optimum: where it ran, the aligned pose whether or not its keep rule kept it (an
    agreement gain a few tenths of a per cent either side of zero must not switch the
    disagreement in and out of the 1-sigma), never written (`kept` false); None where it did
    not run.

    >>> edge_cross_check({"ran": False, "kept": False})
    ({'ran': False, 'kept': False}, None)
    >>> edges, T = edge_cross_check({"kept": False, "T_cam_base_aligned": np.eye(4).tolist()})
    >>> edges["cross_check"], T.shape
    (True, (4, 4))
    """
    if edges.get("T_cam_base_aligned") is None:
        return edges, None
    return ({**edges, "kept": False, "cross_check": True},
            np.asarray(edges["T_cam_base_aligned"], float))
