"""The edge alignment in RESULT.json: its `edges` object and, when kept, the aligned pose.

The `edges` object holds the verdict (kept, reason), the outline's agreement with the image
edges at both poses, per link at the kept pose, the links left out (by name, or static in the
background model) and those named as not matching their model, the keypoint detections' median
distance at both poses, both poses and the change between them. When kept, the document's pose
fields are the aligned pose's (`dream.polish.documents.with_pose_fields`), with its own 1-sigma
(`dream.refined_uncertainty`). `--frames each`: each aligned frame's `per_frame` entry gets its own
`edges` object, and the top-level `edges` object counts them.
"""

from __future__ import annotations

from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from typing import Any

from dream.arrays import finite_or_none
from dream.edges.calibration import EdgeResult
from dream.edges.frames import FrameEdgeResult
from dream.polish.documents import with_frame_refinements, with_pose_fields
from dream.refined_uncertainty import with_refined_uncertainty


def edges_to_dict(res: EdgeResult) -> dict[str, Any]:
    """The `edges` object of RESULT.json."""
    moved_m, moved_rad = res.correction
    return {
        "kept": bool(res.kept),
        "reason": res.reason,
        "agreement_before": res.score_before.agreement,
        "agreement_after": res.score_after.agreement,
        "outline_points": res.score_after.points,
        "links": {a.link: {"outline_points": a.points, "agreement": a.agreement,
                           "median_edge_distance_px": finite_or_none(a.median_px)}
                  for a in res.score_kept.links},
        "mismatched_links": list(res.mismatched_links),
        "excluded_links": list(res.excluded_links),
        "static_links": list(res.static_links),
        "background_model": bool(res.background),
        "keypoint_median_px_before": finite_or_none(res.keypoint_median_before),
        "keypoint_median_px_after": finite_or_none(res.keypoint_median_after),
        "T_cam_base_keypoints": res.T_before.tolist(),
        "T_cam_base_aligned": res.T_aligned.tolist(),
        "camera_position_change_m": moved_m,
        "rotation_change_rad": moved_rad,
        "frames": list(res.frames),
        "rounds_per_scale": list(res.trace.rounds),
        "seconds": res.seconds,
    }


def result_doc_with_edges(doc: dict[str, Any], res: EdgeResult,
                          rmse_after_px: float) -> dict[str, Any]:
    """RESULT.json's document with the `edges` object; when kept, its pose fields and
    `rmse_px` (the inlier keypoints' RMSE, `rmse_after_px`) are the aligned pose's."""
    out = dict(doc)
    out["edges"] = edges_to_dict(res)
    if res.kept:
        with_pose_fields(out, res.T_after, rmse_after_px)
        with_refined_uncertainty(out, res.jackknife)
    return out


def frame_edges_to_dict(res: FrameEdgeResult) -> dict[str, Any]:
    """The `edges` object of a `per_frame` entry ("each" mode)."""
    return {
        "kept": bool(res.kept),
        "reason": res.reason,
        "agreement_before": res.agreement_before,
        "agreement_after": res.agreement_after,
        "keypoint_median_px_before": finite_or_none(res.median_before),
        "keypoint_median_px_after": finite_or_none(res.median_after),
        "T_cam_base_keypoints": res.T_before.tolist(),
        "T_cam_base_aligned": res.T_aligned.tolist(),
        "background_model": bool(res.background),
        "seconds": res.seconds,
    }


def result_doc_with_frame_edges(doc: dict[str, Any],
                                results: SequenceOf[FrameEdgeResult | None],
                                rmse_after: Callable[[FrameEdgeResult], float] = lambda res:
                                float("nan")) -> dict[str, Any]:
    """An "each"-mode RESULT.json document with each aligned frame's `edges` object and, where
    kept, its aligned `T_cam_base` and `rmse_after(result)` as its `rmse_px` (the frame's
    inlier keypoints at the aligned pose; `dream.polish.documents.with_frame_refinements`);
    the top-level `edges` object counts them."""
    out = with_frame_refinements(doc, results, "edges", frame_edges_to_dict, rmse_after)
    done = [r for r in results if r is not None]
    out["edges"] = {"mode": "each", "frames_aligned": len(done),
                    "frames_kept": sum(r.kept for r in done),
                    "background_model": any(r.background for r in done),
                    "seconds": float(sum(r.seconds for r in done))}
    return out
