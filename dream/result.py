"""RESULT.json (docs/data_format.md#resultjson): writing a calibration result, reading it back."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dream.calibration import CalibrationResult, Observations
from dream.errors import InputError
from dream.io import fields
from dream.pnp import PoseFit
from dream.transforms import (
    camera_position_covariance,
    invert_T,
    is_rigid,
    quaternion_xyzw_from_R,
)

RESULT_FORMAT_VERSION = 1


def _matrix(a: np.ndarray | None) -> list | None:
    return None if a is None else np.asarray(a, dtype=float).tolist()


def result_to_dict(result: CalibrationResult, obs: Observations, *, robot: str) -> dict[str, Any]:
    """The RESULT.json document (docs/data_format.md#resultjson)."""
    fit = result.fit
    T = fit.T_cam_base
    T_base_cam = invert_T(T)
    per_frame = []
    found = obs.found
    for i, name in enumerate(obs.frame_names):
        frame_fit = result.frames[i].fit
        T_frame = result.T_cam_base_of_frame(i) if result.mode == "each" else (
            frame_fit.T_cam_base if isinstance(frame_fit, PoseFit) else None)
        res = result.residuals_px[i]
        keep = result.inlier[i]
        rmse = float(np.sqrt(np.mean(np.sum(res[keep] ** 2, 1)))) if keep.any() else None
        keypoints = []
        for k, kp in enumerate(obs.keypoint_names):
            ok = bool(found[i, k])
            keypoints.append({
                "name": kp,
                "uv": obs.uv[i, k].tolist() if ok else None,
                "confidence": float(obs.confidence[i, k]) if ok else None,
                "inlier": bool(keep[k]),
            })
        entry = {"frame": name, "T_cam_base": _matrix(T_frame), "rmse_px": rmse,
                 "keypoints_found": int(found[i].sum()), "keypoints": keypoints}
        if not isinstance(frame_fit, PoseFit):
            entry["no_solution_reason"] = frame_fit.reason
        per_frame.append(entry)
    covariance = result.covariance
    cov_c = camera_position_covariance(T, covariance)
    jackknife = result.jackknife
    return {
        "format_version": RESULT_FORMAT_VERSION,
        "robot": robot,
        "frames_mode": result.mode,
        "T_cam_base": _matrix(T),
        "translation_m": T[:3, 3].tolist(),
        "quaternion_xyzw": quaternion_xyzw_from_R(T[:3, :3]).tolist(),
        "rmse_px": float(fit.rmse_px),
        "frames_used": result.frames_used,
        # Extension: "each" mode's reported frame (the best-determined one), null in "all" mode.
        "reported_frame": None if result.reported_frame is None
        else obs.frame_names[result.reported_frame],
        "keypoints_used": int(fit.num_inliers),
        # 1-sigma of `covariance_xi` (the fit's, plus the keypoint jackknife's when present)
        "sigma_translation_m": result.sigma_translation_m.tolist(),
        "sigma_rotation_rad": result.sigma_rotation_rad.tolist(),
        # Extensions: the camera pose in the base frame and the full covariance.
        "T_base_cam": _matrix(T_base_cam),
        "sigma_camera_position_base_m": np.sqrt(np.diag(cov_c)).tolist(),
        "covariance_xi": _matrix(covariance),
        "covariance_xi_order": "rotation about camera x,y,z (rad), translation along camera "
                               "x,y,z (m); update P_cam = exp(rot) R P_base + t + trans",
        "uncertainty": {
            "method": "fit" if jackknife is None else "fit + keypoint jackknife",
            "covariance_xi_fit": _matrix(fit.covariance),
            "covariance_xi_keypoint_jackknife": None if jackknife is None
            else _matrix(jackknife.covariance),
            "keypoint_jackknife_left_out": None if jackknife is None else list(jackknife.left_out),
        },
        "per_frame": per_frame,
    }


def written_poses(doc: dict[str, Any]) -> np.ndarray:
    """(F, 4, 4) the pose a RESULT.json document wrote for each of its `per_frame` entries: the
    one extrinsic of all frames, or each frame's own in "each" mode (NaN where it has none)."""
    frames = doc["per_frame"]
    out = np.array(np.broadcast_to(np.asarray(doc["T_cam_base"], dtype=float),
                                   (len(frames), 4, 4)))
    if doc.get("frames_mode", "all") == "each":
        for i, entry in enumerate(frames):
            out[i] = np.nan if entry.get("T_cam_base") is None else entry["T_cam_base"]
    return out


def adopted_intrinsics(doc: dict[str, Any]) -> dict[str, Any]:
    """The intrinsics a RESULT.json's pose was calibrated through where the calibration
    adopted those the robot's outlines asked for: `fx`, `fy` of an adopted focal length
    (`start.focal` of the search without keypoints, `focal` of the keypoint path), `cx`, `cy`
    of an adopted principal point (`start.principal`, `principal`), `distortion` (a tuple) of
    an adopted radial distortion (`start.distortion`, `distortion`); empty where the data's
    own were used.

    >>> adopted_intrinsics({"focal": {"adopted": True, "used": {"fx": 510.0, "fy": 512.0}}})
    {'fx': 510.0, 'fy': 512.0}
    >>> adopted_intrinsics({"start": {"focal": {"adopted": False}}})
    {}
    """
    used: dict[str, Any] = {}
    start = doc.get("start") or {}
    for record in (start.get("distortion"), start.get("focal"), start.get("principal"),
                   doc.get("distortion"), doc.get("focal"), doc.get("principal")):
        if record and record.get("adopted"):
            used.update({k: tuple(float(c) for c in v) if isinstance(v, list) else float(v)
                         for k, v in record["used"].items()})
    return used


FIX_RESULT = ("give a RESULT.json written by dream calibrate (run it again if the file was "
              "edited or cut short)")
FRAMES_MODES = ("all", "each")


def _rigid(value: Any, what: str, path: Path) -> np.ndarray:
    """`value` as a finite 4x4 rigid transform, or an `InputError` naming `what` in `path`."""
    T = fields.as_matrix(value, what, path, 4, 4, FIX_RESULT)
    if not is_rigid(T, atol=1e-6):
        raise InputError(f"{what} is not a 4x4 rigid transform (orthonormal rotation, last row "
                         "0 0 0 1)", path, FIX_RESULT)
    return T


def _check_per_frame(per_frame: Any, path: Path) -> list[dict[str, Any]]:
    """The `per_frame` list, each entry checked as `dream.pipeline.evaluate` reads it."""
    for i, entry in enumerate(fields.as_list(per_frame, "per_frame", path, FIX_RESULT)):
        what = f"per_frame[{i}]"
        fields.as_dict(entry, what, path, FIX_RESULT)
        fields.as_str(fields.require(entry, "frame", f"{what}.frame", path, FIX_RESULT),
                      f"{what}.frame", path, FIX_RESULT)
        if entry.get("T_cam_base") is not None:
            _rigid(entry["T_cam_base"], f"{what}.T_cam_base", path)
        keypoints = entry.get("keypoints")
        if keypoints is None:
            continue
        for k, kp in enumerate(fields.as_list(keypoints, f"{what}.keypoints", path,
                                              FIX_RESULT)):
            where = f"{what}.keypoints[{k}]"
            fields.as_dict(kp, where, path, FIX_RESULT)
            fields.as_str(fields.require(kp, "name", f"{where}.name", path, FIX_RESULT),
                          f"{where}.name", path, FIX_RESULT)
            if kp.get("uv") is not None:
                fields.as_vector(kp["uv"], f"{where}.uv", path, 2, FIX_RESULT)
    return per_frame


def read_result(path: str | Path) -> dict[str, Any]:
    """Load and check a RESULT.json; returns the document with `T_cam_base` as an array.

    Checked: `T_cam_base` (a finite 4x4 rigid transform), `robot` and `frames_mode` when
    present, and `per_frame` (frame names, per-frame transforms, keypoint names and pixels).
    Every problem is an `InputError` naming the file and the fix."""
    path = Path(path)
    doc = fields.load_json(path, FIX_RESULT if path.exists() else
                           "run dream calibrate first, or give the RESULT.json it wrote")
    fields.as_dict(doc, "the result", path, FIX_RESULT)
    if doc.get("T_cam_base") is None:
        raise InputError("no T_cam_base in the result", path, FIX_RESULT)
    doc["T_cam_base"] = _rigid(doc["T_cam_base"], "T_cam_base", path)
    if doc.get("robot") is not None:
        fields.as_str(doc["robot"], "robot", path, FIX_RESULT)
    mode = doc.get("frames_mode")
    if mode is not None and mode not in FRAMES_MODES:
        raise InputError(f"frames_mode must be \"all\" or \"each\", got {fields.describe(mode)}",
                         path, FIX_RESULT)
    doc["per_frame"] = _check_per_frame(doc.get("per_frame") or [], path)
    return doc
