"""Drawing keypoints, skeletons and residuals on images (pure functions on arrays)."""

from __future__ import annotations

import logging

import cv2
import numpy as np

from dream.errors import InputError

log = logging.getLogger(__name__)

OBSERVED_RGB = (40, 220, 40)
PROJECTED_RGB = (255, 60, 40)
SKELETON_RGB = (255, 200, 0)
RESIDUAL_RGB = (255, 0, 255)
OUTLIER_RGB = (160, 160, 160)
_SHIFT = 4  # fixed-point bits for sub-pixel drawing
_SCALE = 1 << _SHIFT


def _pt(uv: np.ndarray) -> tuple[int, int]:
    return int(round(uv[0] * _SCALE)), int(round(uv[1] * _SCALE))


def _ok(uv: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(uv))) and bool(np.all(np.abs(uv) < 1e5))


def _check(image: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise InputError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    uv = np.asarray(uv, dtype=float)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InputError(f"uv has shape {uv.shape}, expected (K, 2)")
    return np.ascontiguousarray(image).copy(), uv


def line_width(image: np.ndarray) -> int:
    return max(1, round(min(image.shape[:2]) / 240))


def draw_skeleton(image: np.ndarray, uv: np.ndarray, edges: tuple[tuple[int, int], ...],
                  color: tuple[int, int, int] = SKELETON_RGB,
                  point_color: tuple[int, int, int] = PROJECTED_RGB) -> np.ndarray:
    """RGB image with keypoints `uv` (K, 2) joined by `edges`; NaN keypoints are skipped."""
    out, uv = _check(image, uv)
    w = line_width(out)
    for i, j in edges:
        if _ok(uv[i]) and _ok(uv[j]):
            cv2.line(out, _pt(uv[i]), _pt(uv[j]), color, w, cv2.LINE_AA, _SHIFT)
    for p in uv:
        if _ok(p):
            cv2.circle(out, _pt(p), (2 * w + 1) * _SCALE, point_color, -1, cv2.LINE_AA, _SHIFT)
    return out


def draw_observations(image: np.ndarray, uv_observed: np.ndarray, uv_projected: np.ndarray,
                      inlier: np.ndarray) -> np.ndarray:
    """Observed keypoints (rings; grey when rejected) and residual vectors to the projections."""
    out, uv_observed = _check(image, uv_observed)
    w = line_width(out)
    for obs, proj, ok in zip(uv_observed, np.asarray(uv_projected, float), inlier, strict=True):
        if not _ok(obs):
            continue
        color = OBSERVED_RGB if ok else OUTLIER_RGB
        cv2.circle(out, _pt(obs), (3 * w + 2) * _SCALE, color, w, cv2.LINE_AA, _SHIFT)
        if _ok(proj):
            cv2.line(out, _pt(obs), _pt(proj), RESIDUAL_RGB, w, cv2.LINE_AA, _SHIFT)
    return out


CONFIDENCE_FONT_SCALE_PER_PX = 1 / 800   # text height follows the image size
CONFIDENCE_OFFSET_PX = 4                 # text starts this far right of the detection


def draw_confidences(image: np.ndarray, uv_observed: np.ndarray,
                     confidence: np.ndarray) -> np.ndarray:
    """Each observed keypoint's detection confidence written next to it (2 decimals)."""
    out, uv_observed = _check(image, uv_observed)
    confidence = np.asarray(confidence, dtype=float)
    if confidence.shape != uv_observed.shape[:1]:
        raise InputError(f"confidence has shape {confidence.shape}, expected "
                         f"({len(uv_observed)},)")
    scale = max(0.3, min(out.shape[:2]) * CONFIDENCE_FONT_SCALE_PER_PX * 1.5)
    for uv, c in zip(uv_observed, confidence, strict=True):
        if not _ok(uv) or not np.isfinite(c):
            continue
        org = (int(round(uv[0])) + CONFIDENCE_OFFSET_PX, int(round(uv[1])) - CONFIDENCE_OFFSET_PX)
        cv2.putText(out, f"{c:.2f}", org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 2,
                    cv2.LINE_AA)
        cv2.putText(out, f"{c:.2f}", org, cv2.FONT_HERSHEY_SIMPLEX, scale, OBSERVED_RGB, 1,
                    cv2.LINE_AA)
    return out


def blank_image(width: int, height: int, gray: int = 40) -> np.ndarray:
    """A dark canvas for frames without an image (keypoint-only observations)."""
    return np.full((height, width, 3), gray, np.uint8)


# --- File edge: the functions below read images and write PNGs. -----------------------------

RESIDUAL_MAGNIFICATION = 10.0  # residual vectors are drawn this many times longer in the summary


def _write_png(path, rgb: np.ndarray) -> None:
    from pathlib import Path

    from dream.io.fields import os_reason

    path = Path(path)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise InputError("could not encode the overlay image", path)
    try:
        path.write_bytes(buf.tobytes())
    except OSError as exc:
        raise InputError(f"cannot write the overlay image ({os_reason(exc)})", path,
                         "check that the folder is writable and the disk has space") from None


def _frame_canvas(sequence, frame) -> np.ndarray:
    from dream.io.images import load_image

    if frame.image_path is None:
        return blank_image(sequence.camera.width, sequence.camera.height)
    return load_image(frame, sequence.camera)


def check_limit(limit: int | None) -> None:
    """`limit` of `write_skeleton_overlays`: None (every frame) or at least 1."""
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int)
                              or limit < 1):
        raise InputError(f"--limit must be a whole number of frames >= 1, got {limit}",
                         fix="give --limit 1 or more, or leave it out to draw every frame")


def write_skeleton_overlays(sequence, robot, T_cam_base: np.ndarray, out_dir,
                            limit: int | None = None) -> int:
    """Keypoints and skeleton of every imaged frame (the first `limit` of them) projected with
    `T_cam_base` (F, 4, 4); returns how many images were written. The folder is written
    atomically (`dream.io.staged_directory`): on a failure nothing is left in it."""
    from dream.camera import project
    from dream.io.atomic import staged_directory
    from dream.pipeline import joints_in_robot_order
    from dream.transforms import transform_points

    check_limit(limit)
    frames = [(i, f) for i, f in enumerate(sequence.frames) if f.image_path is not None]
    if not frames:
        raise InputError("the data has no images to draw on", sequence.source)
    chosen = frames[:limit]
    P_base = robot.forward_kinematics(joints_in_robot_order(sequence, robot))
    with staged_directory(out_dir) as stage:
        for n, (i, frame) in enumerate(chosen):
            uv = project(sequence.frame_camera(i), transform_points(T_cam_base[i], P_base[i]))
            image = draw_skeleton(_frame_canvas(sequence, frame), uv, robot.skeleton_edges)
            _write_png(stage / f"{frame.name}.overlay.png", image)
            if (n + 1) % 50 == 0:
                log.info("overlays: %d / %d", n + 1, len(chosen))
    return len(chosen)


def write_result_overlays(sequence, robot, obs, result, out_dir) -> None:
    """Per frame: observations with their detection confidence, the skeleton re-projected with
    the solution and the residual vectors; plus `summary.png`, every residual of every frame
    on one canvas, magnified. The folder is written atomically (`dream.io.staged_directory`):
    on a failure (an unreadable image...) nothing is left in it."""
    from dream.camera import project
    from dream.io.atomic import staged_directory
    from dream.transforms import transform_points

    cam = sequence.camera
    summary = blank_image(cam.width, cam.height)
    with staged_directory(out_dir) as stage:
        for i, frame in enumerate(sequence.frames):
            T = result.T_cam_base_of_frame(i)
            uv_proj = np.full(obs.uv[i].shape, np.nan) if T is None else \
                project(sequence.frame_camera(i), transform_points(T, obs.P_base[i]))
            image = draw_skeleton(_frame_canvas(sequence, frame), uv_proj, robot.skeleton_edges)
            image = draw_observations(image, obs.uv[i], uv_proj, result.inlier[i])
            image = draw_confidences(image, obs.uv[i], obs.confidence[i])
            _write_png(stage / f"{frame.name}.result.png", image)
            magnified = obs.uv[i] + RESIDUAL_MAGNIFICATION * (uv_proj - obs.uv[i])
            summary = draw_observations(summary, obs.uv[i], magnified, result.inlier[i])
        text = (f"{result.mode}: RMSE {result.fit.rmse_px:.2f} px, {result.fit.num_inliers} "
                f"keypoints; residuals x{RESIDUAL_MAGNIFICATION:g}")
        cv2.putText(summary, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1,
                    cv2.LINE_AA)
        _write_png(stage / "summary.png", summary)
