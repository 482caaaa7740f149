"""RESULT.json after an image refinement: the edge alignment's or the silhouette polish's pose,
its keypoint RMSE, 1-sigma and verdict, written the way `dream calibrate` writes them. The
command and the Python API (`dream.result_document(..., refined=)`) share these functions, so
a script that saves a refined result gets the pose it refined, not the keypoint pose.

Example:
    >>> pose_refined_by({"frames_mode": "all", "edges": {"kept": True}})
    'the edge alignment'
    >>> pose_refined_by({"frames_mode": "all", "polish": {"kept": False}}) is None
    True
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceOf
from typing import Any

import numpy as np

from dream.calibration import CalibrationResult, Observations
from dream.errors import InputError
from dream.sequence import Sequence

_REFINED_NAMES = {"edges": "the edge alignment", "polish": "the silhouette polish"}


def pose_refined_by(doc: dict[str, Any]) -> str | None:
    """The image refinement whose pose a RESULT.json document holds, in words (None: the
    keypoint pose): all frames' kept refinement, or the reported frame's (`--frames each`)."""
    if doc.get("frames_mode") == "all":
        return next((name for key, name in _REFINED_NAMES.items()
                     if doc.get(key, {}).get("kept")), None)
    entry = next((e for e in doc["per_frame"] if e["frame"] == doc.get("reported_frame")), {})
    return next((name for key, name in _REFINED_NAMES.items()
                 if entry.get(key, {}).get("kept")), None)


def inlier_rmse_px(sequence: Sequence, result: CalibrationResult, obs: Observations,
                   T_cam_base: np.ndarray, frame: int | None = None) -> float:
    """RESULT.json's `rmse_px` at a refined pose: the keypoint fit's inliers' RMSE (NaN
    without inliers), of every frame or of `frame` alone (through its own intrinsics)."""
    from dream.polish.calibration import inlier_keypoints

    if frame is None:
        inliers, camera = inlier_keypoints(result, obs, slice(None)), sequence.camera
    else:
        inliers, camera = inlier_keypoints(result, obs, frame), sequence.frame_camera(frame)
    return inliers.rmse_px(camera, T_cam_base) if inliers is not None else float("nan")


def with_refinement(doc: dict[str, Any], refined: Any, sequence: Sequence,
                    result: CalibrationResult, obs: Observations,
                    kind: str | None = None) -> dict[str, Any]:
    """A copy of the keypoint result's document with the refinement `refined` in it: an
    `EdgeResult` or `PolishResult` of all frames, or a tuple of `FrameEdgeResult` /
    `PolishResult` (None: a frame not refined) of each frame; a kept refinement's pose,
    `rmse_px` and 1-sigma replace the keypoint fit's. `kind` ("edges" or "polish") names
    the refinement of a tuple in which no frame was refined (default: from its types; none
    refined and no `kind`: the document as it was).

    Raises:
        InputError: `refined` is not a refinement of `result` (another kind, another mode, or
            started from another pose).
    """
    from dream.edges.calibration import EdgeResult
    from dream.edges.documents import result_doc_with_edges, result_doc_with_frame_edges
    from dream.edges.frames import FrameEdgeResult
    from dream.polish.documents import result_doc_with_frame_polishes, result_doc_with_polish
    from dream.polish.refine import PolishResult

    if result.mode == "all" and isinstance(refined, EdgeResult | PolishResult):
        _check_started_at(refined.T_before, result.T_cam_base, "the result")
        rmse = inlier_rmse_px(sequence, result, obs, refined.T_after)
        if isinstance(refined, EdgeResult):
            return result_doc_with_edges(doc, refined, rmse)
        return result_doc_with_polish(doc, refined, rmse)
    if result.mode == "each" and isinstance(refined, SequenceOf) and not isinstance(refined, str):
        names = {FrameEdgeResult: "edges", PolishResult: "polish"}
        kinds = {names.get(type(r), "") for r in refined if r is not None} or {kind}
        if len(refined) != len(result.frames):
            raise InputError(f"refined holds {len(refined)} frames, the result "
                             f"{len(result.frames)}", fix="pass what dream.refine_edges or "
                             "dream.polish_result returned for this result")
        if kinds == {None}:           # no frame was refined: the keypoint document
            return dict(doc)
        if len(kinds) == 1:
            _check_frames_started_at(refined, result)
            if kinds == {"edges"}:
                index = {frame.name: i for i, frame in enumerate(sequence.frames)}
                return result_doc_with_frame_edges(doc, refined, lambda res: inlier_rmse_px(
                    sequence, result, obs, res.T_after, index[res.frame]))
            if kinds == {"polish"}:
                return result_doc_with_frame_polishes(doc, refined)
    raise InputError(
        f"refined is a {_kind(refined)}, not a refinement of this {result.mode}-frames result",
        fix="pass what dream.refine_edges or dream.polish_result returned for this result "
            "(all frames: one EdgeResult or PolishResult; each frame: their tuple)")


def written_quality(result: CalibrationResult, obs: Observations, doc: dict[str, Any],
                    extra: SequenceOf[Any] = (), leading: SequenceOf[Any] = ()) -> Any:
    """The verdict (`dream.quality.Quality`) on the pose a RESULT.json document holds: the
    keypoint fit's, or a kept refinement's with its own 1-sigma; `extra`: more findings;
    `leading`: findings listed first (`dream.quality.result_quality`)."""
    from dream.quality import result_quality
    from dream.result import written_poses

    return result_quality(result, obs, pose_refined_by(doc),
                          covariance=np.asarray(doc["covariance_xi"], dtype=float),
                          T_cam_base=np.asarray(doc["T_cam_base"], dtype=float),
                          T_frames=written_poses(doc), extra=list(extra),
                          leading=list(leading))


def _check_started_at(T_before: np.ndarray, T_result: np.ndarray | None, what: str) -> None:
    """A refinement must start from the pose of the result it is written into."""
    if T_result is None or not np.allclose(T_before, T_result):
        raise InputError(f"refined started from another pose than {what}'s",
                         fix="refine this result (dream.refine_edges / dream.polish_result "
                             "with it), or write the result it was refined from")


def _check_frames_started_at(refined: SequenceOf[Any], result: CalibrationResult) -> None:
    for i, res in enumerate(refined):
        if res is not None:
            _check_started_at(res.T_before, result.T_cam_base_of_frame(i),
                              f"frame {i}")


def _kind(value: Any) -> str:
    if isinstance(value, SequenceOf) and not isinstance(value, str):
        kinds = sorted({type(r).__name__ for r in value if r is not None}) or ["None"]
        return f"{type(value).__name__} of {len(value)} ({', '.join(kinds)})"
    return type(value).__name__
