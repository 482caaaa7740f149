"""The keypoint fit's checks of the given intrinsics in `dream calibrate`: the focal length
(`dream.focal_check`) and the principal point (`dream.principal_check`) the inlier keypoints
ask for, their RESULT.json records and their findings, and what they leave open where the
robot's outlines do not judge the intrinsics (`with_keypoint_intrinsics`)."""

from __future__ import annotations

import numpy as np

from dream.quality import CHECK, Finding


def intrinsics_checks(result, obs, seq, doc: dict) -> list[Finding | None]:
    """The findings of an all-frames result's focal and principal-point checks (None where
    the keypoints agree); RESULT.json's `keypoint_focal` and `keypoint_principal` where they
    ran."""
    from dream.focal_check import keypoint_focal, keypoint_focal_finding
    from dream.principal_check import keypoint_principal, keypoint_principal_finding

    findings: list[Finding | None] = []
    focal = keypoint_focal(result, obs, seq.camera)
    if focal is not None:
        findings.append(keypoint_focal_finding(focal, seq.camera))
        doc["keypoint_focal"] = {**focal.to_dict(), "agrees": findings[-1] is None}
    principal = keypoint_principal(result, obs, seq.camera)
    if principal is not None:
        findings.append(keypoint_principal_finding(principal, seq.camera))
        doc["keypoint_principal"] = {**principal.to_dict(), "agrees": findings[-1] is None}
    return findings


def with_keypoint_intrinsics(doc: dict, camera) -> tuple[dict, list[Finding]]:
    """Where the pose written is the keypoint fit's and the robot's outlines did not judge the
    intrinsics (no silhouettes' cross-check fits: `--refine none`, a refinement that could not
    run), the keypoints' checks are all it has. A focal length they ask for, and a principal
    point they ask for beyond the check's limit (a finding, or within their noise:
    unresolved), kept as given move the pose by as much, so that move (`xi_asked` of
    RESULT.json's `keypoint_focal` and `keypoint_principal`), and for the principal point the
    turn of a point as far off as asked in each image axis
    (`dream.coarse.principal.adopted_covariance`), enter the covariance; an unresolved one is
    a `check` finding of its own. The focal length's move enters within the limit too: a
    scale a few per cent off moves the camera along its axis by centimetres, and a network's
    keypoints ask for one within the limit given fx, fy 5 % long (x0.96-0.98 where the truth
    is x0.952). Given fx, fy x1.05 or x1.1, or cx, cy 24, -16 px off, the keypoint fit alone
    had called rendered scenes 81 mm, 92 mm and 5.1 deg off `good`. Returns the document (the
    same where nothing is added) and the unresolved findings. A kept image refinement's pose
    is not the keypoints' to judge: on a rendered scene with masks a biased detector's
    keypoints asked for a turn that the masks did not, and the polish landed within a third of
    the keypoint pose's error."""
    from dream.refined_uncertainty import set_covariance
    from dream.refinement_document import pose_refined_by

    if (doc.get("silhouette_check") or {}).get("focal") is not None or \
            pose_refined_by(doc) is not None:
        return doc, []
    T = np.asarray(doc["T_cam_base"], dtype=float)
    added, findings, names = np.zeros((6, 6)), [], []
    for key, name in (("keypoint_focal", "focal length"),
                      ("keypoint_principal", "principal point")):
        record = doc.get(key)
        if not record or record.get("xi_asked") is None or \
                (key == "keypoint_principal" and not record["beyond_limit"]):
            continue
        xi = np.asarray(record["xi_asked"], dtype=float)
        added += np.outer(xi, xi) + (_turn_as_asked(camera, T, record) if
                                     key == "keypoint_principal" else 0.0)
        names.append(name)
        if record["unresolved"]:
            findings.append(_unresolved_finding(key, record, camera))
    if not names:
        return doc, []
    doc = {**doc, "uncertainty": {**doc["uncertainty"], "keypoint_intrinsics_added": names}}
    set_covariance(doc, np.asarray(doc["covariance_xi"], dtype=float) + added)
    doc["uncertainty"]["method"] += (f" + the move through the {' and '.join(names)} the "
                                     "keypoints ask for")
    return doc, findings


def _turn_as_asked(camera, T_cam_base: np.ndarray, record: dict) -> np.ndarray:
    from dream.coarse.principal import adopted_covariance

    return adopted_covariance(camera, T_cam_base, np.abs(np.asarray(record["shift_px"])))


def _unresolved_finding(key: str, record: dict, camera) -> Finding:
    """`check`: the keypoints ask for intrinsics beyond the limit within their noise."""
    fix = ("refine on the images (--refine auto: on images without masks it checks the "
           "intrinsics on the robot's outlines), or check the intrinsics")
    if key == "keypoint_focal":
        return CHECK, (f"the keypoints ask for a focal length x{record['scale']:.3f} the "
                       f"given one within their noise (+-{record['sigma'] * 100:.1f} %): "
                       "they cannot tell whether fx, fy are right, and the move along the "
                       f"camera's axis it makes is in the 1-sigma; {fix}")
    (du, dv), (su, sv) = record["shift_px"], record["sigma_px"]
    return CHECK, (f"the keypoints ask for the principal point moved by {du:+.1f}, {dv:+.1f} "
                   f"px within their noise (1-sigma {su:.1f}, {sv:.1f}), a turn of "
                   f"{np.rad2deg(record['angle_rad']):.1f} deg: they cannot tell whether cx, "
                   f"cy {camera.cx:.1f}, {camera.cy:.1f} are right, and the turn is in the "
                   f"1-sigma; {fix}")
