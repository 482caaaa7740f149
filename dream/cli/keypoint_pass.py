"""The keypoint path of `dream calibrate` through one camera, and the intrinsics the robot's
outlines ask for adopted there.

A pass (`run_pass`) is the keypoint fit of all the observations, its checks (the camera's
steadiness, the keypoints' focal length and principal point, the joint readings), the image
refinement (`--refine edges`, or `auto` on images without masks: the edge alignment;
`--polish`, or `auto` on data with masks: the silhouette polish) and, for all frames, the
silhouettes' cross-check (`dream.coarse.crosscheck`: on the data's masks where it has them,
else on motion masks, after a polish on motion masks or the mask head too), which fits the
focal length and then the principal point the robot's outlines ask for at its optimum. On the
data's masks the outlines tell the intrinsics apart where the polish alone does not: given
cx, cy 12, -8 px off, the rendered demo scene was polished `good` 3.2 deg off, and given fx, fy
x1.05, `good` 70 mm off, where its masks ask for -12.1, +8.0 px and x0.952. On `panda_teleop`
the polish against the mask head's masks landed 34 mm and 2.7 deg off, its own 1-sigma 17 mm;
the motion masks' optimum lies 33 mm from it, and their disagreement enters the 1-sigma.

Where they ask for a lens distortion the given intrinsics leave out (`dream.coarse.distortion`:
raw images given with a rectified camera), a focal length (a scale beyond 3 of its 1-sigmas
that the overlap agrees with: the rule of `dream.coarse.focal`, by which the search without
keypoints adopts its own) or flag a principal point (a turn of the camera beyond 1.5 deg and 3
of its 1-sigmas: `dream.coarse.principal`), the pass runs again through the camera with them
(`keypoint_calibration`): a left-out distortion bends every outline and pulls the keypoint
fit, a wrong focal length slides the keypoint pose, its alignment and the silhouettes together
along the camera's axis, a wrong principal point turns them, and only through the right
intrinsics do they land where the camera is. No focal length or principal point is adopted
where the outlines leave the principal point unresolved (`asked_intrinsics`). What the
adopted intrinsics leave uncertain enters the covariance (the distortion's and the focal
scale's 1-sigmas through how the pose moves with them; the spread over frame groups of the
pose fitted with the principal point free, and a floor of the point's error), RESULT.json's
`distortion`, `focal` and `principal` say what was given and used, and the verdict says to
correct the intrinsics (at best `check`). `--fixed-distortion`, `--fixed-focal` and
`--fixed-principal` keep the given ones; the cross-check's findings then say how far the pose
may lie off.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, TextIO

import numpy as np

from dream.cli.calibrate_report import (
    add_edges,
    add_frame_edges,
    add_polish,
    add_silhouette_check,
    steadiness_record,
)
from dream.cli.calibrate_write import refined_or_kept, result_document
from dream.cli.intrinsics_records import intrinsics_checks
from dream.cli.options import EDGES, POLISH
from dream.coarse.principal import PrincipalSettings

MAX_ADOPTIONS = 3       # a lens distortion, a principal point, a focal length through both


@dataclass(frozen=True)
class PassInputs:
    """What every pass shares: the request, the robot, its observations, the model extension
    (or None), the refinement mode, the solver's settings, the data's and the joint log's
    records, the camera's measured motion (`measure_steadiness`), and the keypoint model (its
    mask head for `--polish --mask-head`; None with `--use-labels`)."""

    request: Any
    robot: Any
    obs: Any
    extension: Any
    refine: str
    settings: Any
    data_doc: dict
    readings_doc: dict | None
    motion: Any
    model: Any = None


@dataclass(frozen=True)
class KeypointPass:
    """One pass's sequence (its camera), result, RESULT.json document, the verdict's findings
    of its checks, the joint readings' finding (which leads the verdict), and the robot the
    image refinements draw."""

    seq: Any
    result: Any
    doc: dict
    checked: list
    readings: Any
    imaged: Any


def keypoint_calibration(inputs: PassInputs, seq, out: TextIO) -> KeypointPass:
    """The pass through the given camera, then, while the silhouettes' cross-check asks for
    lens distortion, focal length or principal point that the request does not keep fixed
    (and not yet adopted), the pass through the camera with it (module doc,
    `next_adoption`): at most `MAX_ADOPTIONS` times; an asked distortion first, alone, then a
    flagged principal point alone, since the focal length beside it was fitted through the
    wrong one (given cx, cy 24, -16 px off, a rendered scene's outlines asked for x1.092 with
    it, and adopted together the pose lay 142 mm off)."""
    from dream.coarse.intrinsics import intrinsics_change

    request = inputs.request
    first = last = run_pass(inputs, seq, out)
    adopted: dict[str, dict] = {}
    for _ in range(MAX_ADOPTIONS):
        asked = next_adoption(last.doc, request.fixed_distortion or "distortion" in adopted,
                              request.fixed_focal or "focal" in adopted,
                              request.fixed_principal or "principal" in adopted)
        if not asked:
            break
        adopted.update(asked)
        before = last.seq.camera
        camera = asked_camera(before, asked.get("focal"), asked.get("principal"),
                              asked.get("distortion"))
        print(f"intrinsics: {intrinsics_change(before, camera)}, asked for by the robot's "
              "outlines at the silhouettes' optimum: calibrating again through them "
              "(--fixed-distortion, --fixed-focal, --fixed-principal keep the given ones)",
              file=out)
        last = run_pass(inputs, seq.with_fixed_camera(camera), out)
    if not adopted:
        return first
    return with_adopted(last, adopted.get("focal"), adopted.get("principal"), first.doc,
                        seq.camera, adopted.get("distortion"))


def next_adoption(doc: dict, fixed_distortion: bool, fixed_focal: bool, fixed_principal: bool
                  ) -> dict[str, dict]:
    """What the next pass adopts of the pass `doc`'s cross-check (`keypoint_calibration`):
    an asked lens distortion alone (the focal length and the principal point beside it were
    fitted through a camera without it), else a flagged principal point alone, else an asked
    focal length (`asked_intrinsics`); empty where nothing (more) is asked for.

    >>> check = {"ran": True, "focal": {"asked": True, "scale": 0.95},
    ...          "principal": {"flagged": True, "unresolved": False},
    ...          "distortion": {"asked": True, "corner_shift": -0.14, "k2_share": 0.04}}
    >>> sorted(next_adoption({"silhouette_check": check}, False, False, False))
    ['distortion']
    >>> sorted(next_adoption({"silhouette_check": check}, True, False, False))
    []
    >>> lens_kept = {**check, "distortion": {"asked": False}}
    >>> sorted(next_adoption({"silhouette_check": lens_kept}, False, False, False))
    ['principal']
    """
    lens = (doc.get("silhouette_check") or {}).get("distortion")
    if lens is not None and lens.get("asked"):
        return {} if fixed_distortion else {"distortion": lens}
    focal, principal = asked_intrinsics(doc, fixed_focal, fixed_principal)
    if principal is not None:
        return {"principal": principal}
    return {} if focal is None else {"focal": focal}


def asked_intrinsics(doc: dict, fixed_focal: bool = False, fixed_principal: bool = False
                     ) -> tuple[dict | None, dict | None]:
    """The cross-check's focal record (`silhouette_check.focal`) where its outlines ask for
    the scale and its principal record where they flag the point, each None where not or
    where kept fixed; neither where the principal point is unresolved (a turn beyond the
    limit within the noise, `dream.coarse.principal.PrincipalEstimate.unresolved`: the
    outlines then do not tell the camera's intrinsics, and a focal length they ask for may
    only make up for a principal point given wrong; ten rendered grey frames given cx, cy
    24, -16 px off asked for fx, fy x0.918 beyond 6 of its 1-sigmas, the principal point a
    turn of 3.8 deg within 3: adopted, the pose went from 17 to 125 mm off); neither where
    the outlines ask for a lens distortion the given intrinsics leave out (`distortion.asked`:
    the focal length and the principal point were fitted through a camera that is not
    adopted, and without it they make up for part of the distortion).

    >>> doc = {"silhouette_check": {"ran": True, "focal": {"asked": True, "scale": 0.95},
    ...                             "principal": {"flagged": False, "unresolved": False}}}
    >>> asked_intrinsics(doc)
    ({'asked': True, 'scale': 0.95}, None)
    >>> asked_intrinsics(doc, fixed_focal=True)
    (None, None)
    >>> asked_intrinsics({"silhouette_check": {"ran": False}})
    (None, None)
    >>> asked_intrinsics({"silhouette_check": {**doc["silhouette_check"],
    ...                                        "distortion": {"asked": True}}})
    (None, None)
    """
    check = doc.get("silhouette_check") or {}
    focal, principal = check.get("focal"), check.get("principal")
    if (principal is None or principal["unresolved"]
            or (check.get("distortion") or {}).get("asked")):
        return None, None
    return (focal if focal and focal.get("asked") and not fixed_focal else None,
            principal if principal.get("flagged") and not fixed_principal else None)


def asked_camera(camera, focal: dict | None, principal: dict | None,
                 distortion: dict | None = None):
    """`camera` with k1, k2 moved by the asked corner shift, fx, fy times the asked scale and
    cx, cy moved by the asked shift (each where asked for; the scale was fitted through the
    asked distortion, the shift through both)."""
    from dream.coarse.distortion import with_corner_shift
    from dream.coarse.focal import with_focal_scale
    from dream.coarse.principal import with_principal_shift

    if distortion is not None:
        camera = with_corner_shift(camera, float(distortion["corner_shift"]),
                                   float(distortion["k2_share"]))
    if focal is not None:
        camera = with_focal_scale(camera, focal["scale"])
    if principal is not None:
        camera = with_principal_shift(camera, np.asarray(principal["shift_px"], dtype=float))
    return camera


def with_adopted(second: KeypointPass, focal: dict | None, principal: dict | None,
                 doc_given: dict, given, distortion: dict | None = None) -> KeypointPass:
    """The last pass with RESULT.json's `distortion`, `focal` and `principal` (the
    cross-check's records of the passes that asked for them, adopted: `given` the camera's as
    given, `used` those calibrated with, `T_cam_base_given` the first pass's pose), what they
    leave uncertain in the covariance (`distortion`: its `covariance_used` through how the
    pose moves per unit of the corner shift and k2's share, and the move to the pose through
    the other lens, `xi_other_lens`, as
    `dream.coarse.distortion.DistortionEstimate.pose_covariance`; `focal`: `sigma_used` times
    how the pose moves per unit of log scale, as
    `dream.coarse.focal.FocalEstimate.pose_covariance`; `principal`: `spread_xi`, the pose's
    spread with the point free, and the turn of an error the outlines' jackknife does not see,
    `sigma_floor_px`: `dream.coarse.principal.adopted_covariance`) and their findings."""
    from dream.coarse.camera_fit import adopted_pose_covariance
    from dream.coarse.distortion import distortion_finding, lens_pose_covariance
    from dream.coarse.principal import adopted_covariance
    from dream.coarse.verdict import adopted_principal_finding, focal_finding
    from dream.refined_uncertainty import set_covariance

    doc = {**second.doc, "uncertainty": dict(second.doc["uncertainty"])}
    camera = second.seq.camera
    added, findings = np.zeros((6, 6)), []
    adopted = {"adopted": True, "asked_by": "silhouette_check",
               "T_cam_base_given": doc_given["T_cam_base"]}
    if distortion is not None:
        doc["distortion"] = {**distortion, **adopted,
                             "given": {"distortion": list(given.dist_coeffs)},
                             "used": {"distortion": list(camera.dist_coeffs)}}
        added += lens_pose_covariance(distortion["covariance_used"], distortion["xi_per_unit"],
                                      distortion["xi_other_lens"])
        findings.append(distortion_finding(doc["distortion"]))
    if focal is not None:
        doc["focal"] = {**focal, **adopted, "given": {"fx": given.fx, "fy": given.fy},
                        "used": {"fx": camera.fx, "fy": camera.fy}}
        added += adopted_pose_covariance(True, focal["sigma_used"] ** 2,
                                         focal["xi_per_log_scale"])
        findings.append(focal_finding(doc["focal"]))
    if principal is not None:
        floor_px = PrincipalSettings().floor_px(camera)
        doc["principal"] = {**principal, **adopted, "given": {"cx": given.cx, "cy": given.cy},
                            "used": {"cx": camera.cx, "cy": camera.cy},
                            "sigma_floor_px": floor_px.tolist()}
        added += np.asarray(principal["spread_xi"], dtype=float) + adopted_covariance(
            camera, np.asarray(doc["T_cam_base"], dtype=float), floor_px)
        findings.append(adopted_principal_finding(doc["principal"]))
    set_covariance(doc, np.asarray(doc["covariance_xi"]) + added)
    doc["uncertainty"]["method"] += " + what the adopted intrinsics leave uncertain"
    return replace(second, doc=doc, checked=[*second.checked, *findings])


def run_pass(inputs: PassInputs, seq, out: TextIO) -> KeypointPass:
    """The keypoint fit through `seq`'s camera, its checks, its refinement and the
    silhouettes' cross-check (module doc); the verdict comes after, on the pass kept."""
    from dream.outline_robot import with_logged_joints
    from dream.pipeline import calibrate

    request, robot, obs, extension = (inputs.request, inputs.robot, inputs.obs,
                                      inputs.extension)
    result = calibrate(seq, obs, request.frames, inputs.settings)
    doc = result_document(request, seq, result, obs, inputs.data_doc, inputs.readings_doc)
    if extension is not None:
        doc["model_extension"] = {"file": str(request.model_extension),
                                  "effects": extension.to_dict()["effects"],
                                  "camera": {"fx": seq.camera.fx, "fy": seq.camera.fy,
                                             "cx": seq.camera.cx, "cy": seq.camera.cy,
                                             "distortion": seq.camera.distortion}}
    checked: list = [steadiness_record(inputs.motion, seq, doc),
                     *intrinsics_checks(result, obs, seq, doc)]
    readings = None if extension is not None else \
        _readings_check(result, obs, seq, robot, inputs.settings, doc, out)
    # the refinements draw each logged joint too (not under a model extension, whose timing
    # and offsets correct the keypoint robot's joints alone)
    imaged = robot if extension is not None or inputs.refine not in (EDGES, POLISH) else \
        with_logged_joints(seq, robot)
    if inputs.refine == EDGES:
        add = add_edges if request.frames == "all" else add_frame_edges
        doc_keypoints = doc
        doc = refined_or_kept(request, lambda: add(
            seq, imaged, result, obs, doc, out, request.exclude_links,
            () if extension is None else extension.link_geometry), doc, out)
        if request.frames == "all":
            doc, silhouettes = add_silhouette_check(seq, imaged, result, doc, out,
                                                    doc_keypoints)
            checked += silhouettes
    elif inputs.refine == POLISH:
        doc = add_polish(seq, imaged, result, obs, inputs.model, doc, out, frames=request.frames,
                         mask_head=request.mask_head, motion_masks=request.motion_masks,
                         link_geometry=() if extension is None else extension.link_geometry)
        if request.frames == "all":     # on the data's masks, else on motion masks
            doc, silhouettes = add_silhouette_check(seq, imaged, result, doc, out)
            checked += silhouettes
    elif extension is not None and extension.link_geometry:
        print("note: the model extension's link_geometry changes only the image refinements "
              "(--refine edges, --polish), and neither runs here", file=out)
    return KeypointPass(seq, result, doc, checked, readings, imaged)


def _readings_check(result, obs, seq, robot, settings, doc: dict, out: TextIO):
    """Whether a mistake in the joint readings explains the keypoints far better
    (`dream.readings_check`): RESULT.json's `readings_check` and its finding."""
    from dream.pipeline import joints_in_robot_order
    from dream.readings_check import check_readings, readings_finding

    check = check_readings(result, obs, robot, joints_in_robot_order(seq, robot), seq.camera,
                           solver=settings)
    if check is None:
        return None
    if check.tried:
        print(f"readings check: {len(check.tried)} mistakes in the joint readings tried "
              f"against the {check.detections - check.explained} detections the fit leaves "
              "unexplained", file=out)
    finding = readings_finding(check)
    doc["readings_check"] = {**check.to_dict(), "agrees": finding is None}
    return finding
