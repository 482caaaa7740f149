"""RESULT.json (contract in SPEC.md): writing a calibration result and reading it back."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from dream.calibrate import CalibrationResult, Observations
from dream.errors import InputError
from dream.pnp import PoseFit
from dream.transforms import invert_T, is_rigid, quaternion_xyzw_from_R, skew

RESULT_FORMAT_VERSION = 1


def camera_position_covariance(T_cam_base: np.ndarray, covariance_xi: np.ndarray) -> np.ndarray:
    """Covariance (3, 3) of the camera centre in the base frame, c = -R^T t, propagated from the
    covariance of xi = (delta_rot, delta_t) (camera frame, `dream.pnp`)."""
    R, t = T_cam_base[:3, :3], T_cam_base[:3, 3]
    J = np.concatenate([-R.T @ skew(t), -R.T], axis=1)  # d c / d xi
    return J @ covariance_xi @ J.T


def _matrix(a: np.ndarray | None) -> list | None:
    return None if a is None else np.asarray(a, dtype=float).tolist()


def _num(x: float | None) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def result_to_dict(result: CalibrationResult, obs: Observations, *, robot: str) -> dict[str, Any]:
    """The RESULT.json document of SPEC.md, with a few documented extensions."""
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
        "sigma_translation_m": np.sqrt(np.diag(covariance)[3:]).tolist(),
        "sigma_rotation_rad": np.sqrt(np.diag(covariance)[:3]).tolist(),
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


def read_result(path: str | Path) -> dict[str, Any]:
    """Load and check a RESULT.json; returns the document with `T_cam_base` as an array."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError("result file not found", path, "run `dream calibrate` first") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not a readable JSON file ({exc})", path) from None
    if not isinstance(doc, dict) or "T_cam_base" not in doc:
        raise InputError("no T_cam_base in the result", path, "give a RESULT.json of `dream "
                         "calibrate`")
    try:
        T = np.array(doc["T_cam_base"], dtype=float)
    except (TypeError, ValueError):
        T = None
    if T is None or not is_rigid(T, atol=1e-6):
        raise InputError("T_cam_base is not a 4x4 rigid transform", path)
    doc["T_cam_base"] = T
    per_frame = doc.get("per_frame", [])
    if not isinstance(per_frame, list) or not all(isinstance(f, dict) and "frame" in f
                                                  for f in per_frame):
        raise InputError("per_frame must be a list of objects with a 'frame' name", path)
    return doc
