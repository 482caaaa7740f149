"""The held-out frames of `dream adapt` scored against the calibrated result's pseudo-labels:
per keypoint the median pixel error and PCK@5 px, the share of labelled keypoints found, and
each frame's own keypoint extrinsic (`--frames each`, keypoints only) against the calibrated
one (median camera-position distance and rotation angle)."""

from __future__ import annotations

import numpy as np

from dream.errors import CalibrationError, InputError

PCK_PX = 5.0
WORSE_PCK = 0.01        # a held-out PCK lower by more than this is worse (not the noise of one
WORSE_M = 0.002         # keypoint); each frame's extrinsic farther by more than this, metres


def keypoint_scores(uv_found: np.ndarray, uv_labels: np.ndarray, names: tuple[str, ...],
                    pck_px: float = PCK_PX) -> dict:
    """Per keypoint and overall: median pixel error and PCK@`pck_px` over the labelled
    keypoints (a missed one counts as beyond the threshold), and the share found.

    >>> labels = np.zeros((2, 1, 2)); found = np.array([[[3.0, 4.0]], [[np.nan, np.nan]]])
    >>> s = keypoint_scores(found, labels, ("a",))
    >>> s["keypoints"]["a"]["median_px"], s["keypoints"]["a"]["pck"], s["found_share"]
    (5.0, 0.5, 0.5)
    """
    if uv_found.shape != uv_labels.shape or uv_found.shape[1] != len(names):
        raise InputError(f"detections {uv_found.shape} and labels {uv_labels.shape} differ")
    labelled = np.all(np.isfinite(uv_labels), axis=-1)
    found = np.all(np.isfinite(uv_found), axis=-1) & labelled
    error = np.where(found, np.linalg.norm(uv_found - uv_labels, axis=-1), np.inf)
    out = {}
    for k, name in enumerate(names):
        e = error[labelled[:, k], k]
        finite = e[np.isfinite(e)]
        out[name] = {"labelled": int(len(e)),
                     "median_px": float(np.median(finite)) if len(finite) else None,
                     "pck": float(np.mean(e <= pck_px)) if len(e) else None}
    e = error[labelled]
    return {"keypoints": out, "pck": float(np.mean(e <= pck_px)) if len(e) else None,
            "found_share": float(found.sum() / max(labelled.sum(), 1)),
            "median_px": float(np.median(e[np.isfinite(e)])) if np.isfinite(e).any() else None}


def frame_extrinsics(sequence, observations, T_cam_base: np.ndarray) -> dict:
    """Each frame's own keypoint extrinsic against `T_cam_base`: solved frames, median camera
    distance (m) and rotation (rad)."""
    from dream.metrics import pose_errors
    from dream.pipeline import calibrate

    try:
        result = calibrate(sequence, observations, "each")
    except (CalibrationError, InputError):
        return {"frames_solved": 0, "median_m": None, "median_rad": None}
    poses = [result.T_cam_base_of_frame(i) for i in range(len(sequence))]
    poses = np.array([T for T in poses if T is not None]).reshape(-1, 4, 4)
    if not len(poses):
        return {"frames_solved": 0, "median_m": None, "median_rad": None}
    m, rad = pose_errors(poses, np.broadcast_to(T_cam_base, poses.shape))
    return {"frames_solved": int(len(poses)), "median_m": float(np.median(m)),
            "median_rad": float(np.median(rad))}


def holdout_report(sequence, robot, model_path: str, uv_labels: np.ndarray,
                   T_cam_base: np.ndarray) -> dict:
    """The scores (module doc) of the model at `model_path` on `sequence` (the held-out
    frames), against their pseudo-labels `uv_labels` (F, K, 2)."""
    import dream

    observations = dream.detect(sequence, robot, dream.load_keypoint_model(model_path))
    names = tuple(observations.keypoint_names)
    return {**keypoint_scores(observations.uv, uv_labels, names),
            "extrinsic_each": frame_extrinsics(sequence, observations, T_cam_base)}


def report_lines(before: dict, after: dict) -> list[str]:
    """The printed comparison of two `holdout_report`s."""
    def median(d: dict, name: str) -> str:
        v = d["keypoints"][name]["median_px"]
        return "-" if v is None else f"{v:.1f}"

    lines = [f"{'keypoint':<22} {'median px':>17} {'PCK@5':>13}"]
    for name in before["keypoints"]:
        b, a = before["keypoints"][name], after["keypoints"][name]
        pck = "-" if b["pck"] is None else f"{b['pck']:.2f} -> {a['pck']:.2f}"
        lines.append(f"{name:<22} {median(before, name):>7} -> {median(after, name):<7} "
                     f"{pck:>13}")
    lines.append(f"all: PCK@5 {before['pck']:.3f} -> {after['pck']:.3f}, found "
                 f"{before['found_share']:.0%} -> {after['found_share']:.0%}")
    for label, d in (("before", before), ("after", after)):
        e = d["extrinsic_each"]
        if e["frames_solved"]:
            lines.append(f"each frame's keypoint extrinsic, {label}: {e['frames_solved']} "
                         f"solved, median {e['median_m'] * 1e3:.1f} mm, "
                         f"{np.rad2deg(e['median_rad']):.2f} deg from the calibrated one")
    return lines


def worse_lines(before: dict, after: dict, model: str) -> list[str]:
    """A warning where the adapted model scores worse than the one it started from on the
    held-out frames (PCK@5 lower, or each frame's keypoint extrinsic farther from the
    calibrated one); none where it does not.

    >>> ok = {"pck": 0.5, "extrinsic_each": {"frames_solved": 3, "median_m": 0.03}}
    >>> worse_lines(ok, {**ok, "pck": 0.6}, "m.onnx")
    []
    >>> worse_lines(ok, {**ok, "pck": 0.4}, "m.onnx")[0][:60]
    'warning: the adapted model scores worse than m.onnx on the h'
    """
    worse = []
    if (before["pck"] is not None and after["pck"] is not None
            and after["pck"] < before["pck"] - WORSE_PCK):
        worse.append(f"PCK@5 {before['pck']:.3f} -> {after['pck']:.3f}")
    b, a = before["extrinsic_each"], after["extrinsic_each"]
    if b["frames_solved"] and a["frames_solved"] and a["median_m"] > b["median_m"] + WORSE_M:
        worse.append(f"each frame's extrinsic {b['median_m'] * 1e3:.1f} -> "
                     f"{a['median_m'] * 1e3:.1f} mm from the calibrated one")
    if not worse:
        return []
    return [f"warning: the adapted model scores worse than {model} on the held-out frames "
            f"({'; '.join(worse)}): keep {model}, or adapt from a better calibration, with more "
            "frames or more --minutes"]
