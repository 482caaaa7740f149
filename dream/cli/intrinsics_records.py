"""The keypoint fit's checks of the given intrinsics in `dream calibrate`: the focal length
(`dream.focal_check`) and the principal point (`dream.principal_check`) the inlier keypoints
ask for, their RESULT.json records and their findings."""

from __future__ import annotations

from dream.quality import Finding


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
