"""The polish in RESULT.json: its `polish` objects and the pose fields of a kept polish.

All frames: RESULT.json gets a `polish` object (iou_before, iou_after: means; kept; reason;
per-frame IoUs, keypoint RMSEs, both poses; `polish_to_dict`); when kept, its pose fields are
the polished pose's, with its own 1-sigma (`result_doc_with_polish`). `--frames each`: each
polished `per_frame` entry gets its own `polish` object (`frame_polish_to_dict`) and, when
kept, the polished `T_cam_base`; the top-level `polish` object counts them
(`frame_polish_summary`), and the top-level pose is the reported frame's polished one, with
its own 1-sigma, when that frame's polish was kept
(`result_doc_with_frame_polishes`).
"""

from __future__ import annotations

from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from typing import Any

import numpy as np

from dream.arrays import finite_or_none
from dream.errors import InputError
from dream.polish.refine import PolishResult
from dream.refined_uncertainty import with_refined_uncertainty
from dream.transforms import invert_T, quaternion_xyzw_from_R


def _floats(a: np.ndarray) -> list[float]:
    return [float(x) for x in a]


def polish_to_dict(res: PolishResult) -> dict[str, Any]:
    """The `polish` object of RESULT.json."""
    moved_m, moved_rad = res.correction
    return {
        "iou_before": res.iou_before_mean,
        "iou_after": res.iou_after_mean,
        "kept": bool(res.kept),
        "reason": res.reason,
        "frames": list(res.frames),
        "iou_before_per_frame": _floats(res.iou_before),
        "iou_after_per_frame": _floats(res.iou_after),
        "rmse_px_before": finite_or_none(res.rmse_before),
        "rmse_px_after": finite_or_none(res.rmse_after),
        "median_px_before": finite_or_none(res.median_before),
        "median_px_after": finite_or_none(res.median_after),
        "keypoint_guard": res.guard,
        "started_without_keypoint": res.start or None,
        "T_cam_base_keypoints": res.T_before.tolist(),
        "T_cam_base_polished": res.T_polished.tolist(),
        "camera_position_change_m": moved_m,
        "rotation_change_rad": moved_rad,
        "search_frames": list(res.search_frames),
        "frames_left_out": _left_out(res),
        "seconds": res.seconds,
    }


def _left_out(res: PolishResult) -> list[dict[str, Any]]:
    """The frames an all-frames polish left out, each with why and its IoU at the common pose
    and alone (`dream.polish.frames`)."""
    a = res.agreement
    if a is None:
        return []
    return [{"frame": res.frames[i], "reason": a.reasons[i], "iou_common": float(a.iou_common[i]),
             "iou_alone": float(a.iou_own[i])} for i in a.left_out]


def with_pose_fields(doc: dict[str, Any], T: np.ndarray, rmse_px: float) -> None:
    """Set a RESULT.json document's pose fields (`T_cam_base`, `translation_m`,
    `quaternion_xyzw`, `T_base_cam`, `sigma_camera_position_base_m`) and, when finite,
    `rmse_px` to those of the pose `T`, polished or aligned (the covariance is still the
    keypoint fit's: `dream.refined_uncertainty.with_refined_uncertainty` replaces it)."""
    from dream.transforms import camera_position_covariance

    doc["T_cam_base"] = T.tolist()
    doc["translation_m"] = T[:3, 3].tolist()
    doc["quaternion_xyzw"] = quaternion_xyzw_from_R(T[:3, :3]).tolist()
    doc["T_base_cam"] = invert_T(T).tolist()
    if np.isfinite(rmse_px):
        doc["rmse_px"] = float(rmse_px)
    if doc.get("covariance_xi") is not None:
        cov = camera_position_covariance(T, np.asarray(doc["covariance_xi"], dtype=float))
        doc["sigma_camera_position_base_m"] = np.sqrt(np.diag(cov)).tolist()


def result_doc_with_polish(doc: dict[str, Any], res: PolishResult,
                           rmse_px: float = float("nan")) -> dict[str, Any]:
    """A copy of an all-frames RESULT.json document with its `polish` object; when the polish
    is kept, the pose fields and, when finite, `rmse_px` (the fit's inlier keypoints at the
    polished pose) describe the polished pose (`with_pose_fields`)."""
    out = dict(doc)
    out["polish"] = polish_to_dict(res)
    if res.kept:
        with_pose_fields(out, res.T_after, rmse_px)
        with_refined_uncertainty(out, res.jackknife)
    return out


_MULTI_FRAME_KEYS = ("frames", "iou_before_per_frame", "iou_after_per_frame", "search_frames",
                     "frames_left_out")


def frame_polish_to_dict(res: PolishResult) -> dict[str, Any]:
    """The `polish` object of a `per_frame` entry ("each" mode): `polish_to_dict` without the
    lists of frames."""
    return {k: v for k, v in polish_to_dict(res).items() if k not in _MULTI_FRAME_KEYS}


def frame_polish_summary(results: SequenceOf[PolishResult | None]) -> dict[str, Any]:
    """The top-level `polish` object of an "each"-mode RESULT.json: how many frames were
    polished and kept, their mean IoU before, at the polished poses, and at the poses kept."""
    done = [r for r in results if r is not None]
    if not done:
        return {"mode": "each", "frames_polished": 0, "frames_kept": 0, "iou_before": None,
                "iou_after": None, "iou_kept": None, "seconds": 0.0}
    return {
        "mode": "each",
        "frames_polished": len(done),
        "frames_kept": sum(r.kept for r in done),
        "iou_before": float(np.mean([r.iou_before_mean for r in done])),
        "iou_after": float(np.mean([r.iou_after_mean for r in done])),
        "iou_kept": float(np.mean([r.iou_after_mean if r.kept else r.iou_before_mean
                                   for r in done])),
        "seconds": float(sum(r.seconds for r in done)),
    }


def result_doc_with_frame_polishes(doc: dict[str, Any],
                                   results: SequenceOf[PolishResult | None]) -> dict[str, Any]:
    """A copy of an "each"-mode RESULT.json document with each polished frame's `polish`
    object and, where kept, its polished `T_cam_base` and `rmse_px` (`with_frame_refinements`);
    the top-level `polish` object is `frame_polish_summary`."""
    out = with_frame_refinements(doc, results, "polish", frame_polish_to_dict,
                                 lambda res: res.rmse_after)
    out["polish"] = frame_polish_summary(results)
    return out


def with_frame_refinements(doc: dict[str, Any], results: SequenceOf[Any | None], key: str,
                           to_dict: Callable[[Any], dict[str, Any]],
                           rmse_after: Callable[[Any], float] = lambda res: float("nan")
                           ) -> dict[str, Any]:
    """A copy of an "each"-mode RESULT.json document with each refined frame's `key` object
    (`to_dict(result)`) in its `per_frame` entry and, where the refinement was kept
    (`result.kept`, pose `result.T_after`), that pose as the entry's `T_cam_base` and, when
    finite, `rmse_after(result)` as its `rmse_px`; the top-level pose is the reported frame's
    refined one when that frame's was kept (`with_pose_fields`). None: a frame not refined.

    Raises:
        InputError: not an each-mode document with one entry per result.
    """
    if doc.get("frames_mode") != "each" or len(doc["per_frame"]) != len(results):
        raise InputError(f"per-frame {key} results need an each-mode result with "
                         f"{len(results)} frames")
    out = dict(doc)
    per_frame = []
    for entry, res in zip(doc["per_frame"], results, strict=True):
        entry = dict(entry)
        if res is not None:
            entry[key] = to_dict(res)
            if res.kept:
                rmse = rmse_after(res)
                entry["T_cam_base"] = res.T_after.tolist()
                if np.isfinite(rmse):
                    entry["rmse_px"] = float(rmse)
                if entry["frame"] == doc.get("reported_frame"):
                    with_pose_fields(out, res.T_after, rmse)
                    with_refined_uncertainty(out, res.jackknife)
        per_frame.append(entry)
    out["per_frame"] = per_frame
    return out
