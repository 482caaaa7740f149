"""Drawing keypoints, skeletons, the robot's outline and residuals on images (pure functions on
arrays), and the overlay folders of `dream calibrate --overlays` and `dream overlay` (file
edge).

A result's overlays show the pose written to RESULT.json: the outline of the robot's URDF
meshes rendered at that pose (cyan), its skeleton (yellow with red keypoints), the detections
(green rings, grey where the keypoint fit rejected them) with their residuals to that skeleton
(magenta), and, where an image refinement moved the pose away from the keypoint fit, the
keypoint pose's skeleton faintly (grey); `summary.png` says which is which. A pose found
without keypoints (the silhouette search) is drawn by `dream.overlay_search`."""

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
OUTLINE_RGB = (0, 230, 255)
FAINT_RGB = (200, 200, 200)
CARRIED_RGB = (255, 0, 255)   # the box around something the URDF lacks, as the search sized it
AWAY_RGB = (255, 140, 0)      # moving pixels away from the robot, not counted as robot
AWAY_OPACITY = 0.6            # of that tint over the image
FAINT_OPACITY = 0.45       # the keypoint pose's skeleton, where a refinement moved the pose
MOVED_PX = 0.5             # a refinement moved the pose when a keypoint moved this far
_SHIFT = 4  # fixed-point bits for sub-pixel drawing
_SCALE = 1 << _SHIFT


def _pt(uv: np.ndarray) -> tuple[int, int]:
    return int(round(uv[0] * _SCALE)), int(round(uv[1] * _SCALE))


def _ok(uv: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(uv))) and bool(np.all(np.abs(uv) < 1e5))


def _image_copy(image: np.ndarray) -> np.ndarray:
    """A contiguous copy of an (H, W, 3) uint8 RGB image to draw on."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise InputError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    return np.ascontiguousarray(image).copy()


def _check(image: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uv = np.asarray(uv, dtype=float)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InputError(f"uv has shape {uv.shape}, expected (K, 2)")
    return _image_copy(image), uv


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


def draw_outline(image: np.ndarray, silhouette: np.ndarray,
                 color: tuple[int, int, int] = OUTLINE_RGB) -> np.ndarray:
    """RGB image with the outline of a rendered silhouette (H, W) bool drawn over it."""
    out = _image_copy(image)
    silhouette = np.asarray(silhouette, dtype=bool)
    if silhouette.shape != out.shape[:2]:
        raise InputError(f"silhouette has shape {silhouette.shape}, expected {out.shape[:2]}")
    contours, _ = cv2.findContours(silhouette.astype(np.uint8), cv2.RETR_LIST,
                                   cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(out, contours, -1, color, line_width(out), cv2.LINE_8)
    return out


def draw_faint_skeleton(image: np.ndarray, uv: np.ndarray,
                        edges: tuple[tuple[int, int], ...]) -> np.ndarray:
    """RGB image with a skeleton drawn faintly (`FAINT_OPACITY`): a pose shown for comparison."""
    drawn = draw_skeleton(image, uv, edges, FAINT_RGB, FAINT_RGB)
    return cv2.addWeighted(drawn, FAINT_OPACITY, np.asarray(image), 1 - FAINT_OPACITY, 0.0)


# a box's 12 edges between its corners, indexed 4x + 2y + z by their side along each axis
BOX_EDGES = tuple((i, i | bit) for i in range(8) for bit in (4, 2, 1) if not i & bit)


def draw_box(image: np.ndarray, uv: np.ndarray,
             color: tuple[int, int, int] = CARRIED_RGB) -> np.ndarray:
    """RGB image with a box's edges between its projected corners `uv` (8, 2) (`BOX_EDGES`
    order); an edge with a corner that did not project (NaN) is skipped.

    >>> uv = np.array([[x, y] for x in (2.0, 8.0) for y in (2.0, 8.0) for _ in (0, 1)])
    >>> int(draw_box(blank_image(10, 10, gray=0), uv).any(axis=-1).sum()) > 0
    True
    """
    out, uv = _check(image, uv)
    if uv.shape != (8, 2):
        raise InputError(f"a box has 8 corners, got uv of shape {uv.shape}")
    w = line_width(out)
    for i, j in BOX_EDGES:
        if _ok(uv[i]) and _ok(uv[j]):
            cv2.line(out, _pt(uv[i]), _pt(uv[j]), color, w, cv2.LINE_AA, _SHIFT)
    return out


def names_box(carried: dict, robot) -> bool:
    """Whether RESULT.json's `start.carried` sized a box around something the URDF lacks
    moving with a link of `robot`."""
    return bool(carried.get("box_around_hull")) and carried.get("named") in robot.link_names


def carried_corners(robot, joints: np.ndarray, carried: dict) -> np.ndarray | None:
    """(F, 8, 3) base-frame corners of the box the search sized around something the URDF
    lacks moving with a link (RESULT.json `start.carried`), None where it named nothing."""
    from dream.robot.link_geometry import BOX_KIND, LinkGeometry
    from dream.transforms import transform_points

    if not names_box(carried, robot):
        return None
    box, link = carried["box_around_hull"], carried["named"]
    geometry = LinkGeometry(link, BOX_KIND, size_m=box["size_m"], position_m=box["position_m"],
                            rotation_rad=box["rotation_rad"])
    corners, _ = geometry.box_mesh()
    T_base_link = robot.link_poses(joints, (link,))[:, 0]
    return transform_points(T_base_link[:, None], corners)


def tint(image: np.ndarray, where: np.ndarray, color: tuple[int, int, int] = AWAY_RGB,
         opacity: float = AWAY_OPACITY) -> np.ndarray:
    """RGB image (H, W, 3) uint8 with the pixels `where` (H, W) bool blended towards `color`.

    >>> tint(np.zeros((1, 2, 3), np.uint8), np.array([[True, False]]))[0, :, 0].tolist()
    [153, 0]
    """
    image, where = np.asarray(image), np.asarray(where, bool)
    if image.ndim != 3 or where.shape != image.shape[:2]:
        raise InputError(f"tint needs an (H, W, 3) image and an (H, W) mask, got {image.shape} "
                         f"and {where.shape}")
    out = image.copy()
    out[where] = np.round((1 - opacity) * image[where] + opacity * np.asarray(color)).astype(
        np.uint8)
    return out


def with_legend(image: np.ndarray, lines: list[tuple[str, tuple[int, int, int]]]
                ) -> np.ndarray:
    """RGB image with a dark band below it holding one coloured line of text per entry, the
    text scaled down where the longest line would not fit the width."""
    image = np.asarray(image)
    width = image.shape[1]
    scale = LEGEND_SCALE
    longest = max(cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]
                  for text, _ in lines)
    scale *= min(1.0, (width - 2 * LEGEND_MARGIN_PX) / max(longest, 1))
    step = max(1, int(round(LEGEND_LINE_PX * scale / LEGEND_SCALE)))
    band = np.full((step * len(lines) + 2 * LEGEND_MARGIN_PX, width, 3), LEGEND_GRAY, np.uint8)
    for n, (text, color) in enumerate(lines):
        org = (LEGEND_MARGIN_PX, LEGEND_MARGIN_PX + step * (n + 1) - step // 4)
        cv2.putText(band, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, color, 1, cv2.LINE_AA)
    return np.concatenate([image, band], axis=0)


LEGEND_SCALE = 0.5         # the legend's font scale where its lines fit the image's width
LEGEND_LINE_PX = 20        # line spacing at `LEGEND_SCALE`
LEGEND_MARGIN_PX = 6
LEGEND_GRAY = 20


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


class _Outliner:
    """Renders the robot's outline (its URDF meshes) for the overlays; draws nothing, with one
    log line, where the meshes cannot be loaded."""

    def __init__(self, sequence, robot):
        from dream.errors import DreamError
        from dream.outline_robot import with_logged_joints
        from dream.pipeline import joints_in_robot_order
        from dream.silhouette import load_robot_meshes

        self.robot = robot = with_logged_joints(sequence, robot)   # as the images show it
        self.joints = joints_in_robot_order(sequence, robot)
        try:
            self.meshes = load_robot_meshes(robot)
        except DreamError as exc:
            log.warning("overlays without the robot's outline: %s", exc)
            self.meshes = None

    def silhouette(self, camera, i: int, T_cam_base: np.ndarray | None) -> np.ndarray | None:
        """Frame i's silhouette (H, W) bool at `T_cam_base` (None without a pose or meshes)."""
        from dream.silhouette import render_silhouette

        if self.meshes is None or T_cam_base is None:
            return None
        return render_silhouette(self.meshes, self.joints[i], T_cam_base, camera)

    def draw(self, image: np.ndarray, camera, i: int, T_cam_base: np.ndarray | None
             ) -> np.ndarray:
        """`image` with frame i's outline at `T_cam_base` (unchanged without a pose)."""
        silhouette = self.silhouette(camera, i, T_cam_base)
        return image if silhouette is None else draw_outline(image, silhouette)


def write_skeleton_overlays(sequence, robot, T_cam_base: np.ndarray, out_dir,
                            limit: int | None = None, skeleton: bool = True,
                            carried: dict | None = None, away: dict | None = None) -> int:
    """The robot's outline (URDF meshes), keypoints and skeleton (without `skeleton`: the
    outline alone) of every imaged frame (the first `limit` of them) projected with
    `T_cam_base` (F, 4, 4), the box a result's search sized around something the URDF lacks
    (`carried`: RESULT.json `start.carried`, where it named one) and the moving pixels away
    from the robot (`away`: frame index -> (H, W) bool, `dream.overlay_search.away_pixels`)
    tinted; returns how many images were written. The folder is written atomically
    (`dream.io.staged_directory`): on a failure nothing is left in it."""
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
    outliner = _Outliner(sequence, robot)
    corners = carried_corners(outliner.robot, outliner.joints, carried or {})
    with staged_directory(out_dir) as stage:
        for n, (i, frame) in enumerate(chosen):
            camera = sequence.frame_camera(i)
            image = _frame_canvas(sequence, frame)
            if away and i in away:
                image = tint(image, away[i])
            image = outliner.draw(image, camera, i, T_cam_base[i])
            if skeleton:
                uv = project(camera, transform_points(T_cam_base[i], P_base[i]))
                image = draw_skeleton(image, uv, robot.skeleton_edges)
            if corners is not None:
                image = draw_box(image, project(camera, transform_points(T_cam_base[i],
                                                                         corners[i])))
            _write_png(stage / f"{frame.name}.overlay.png", image)
            if (n + 1) % 50 == 0:
                log.info("overlays: %d / %d", n + 1, len(chosen))
    return len(chosen)


def _pose_or_none(T: np.ndarray) -> np.ndarray | None:
    """A written pose (4, 4), None where it is NaN (a frame without one)."""
    return T if np.all(np.isfinite(T)) else None


def write_result_overlays(sequence, robot, obs, result, out_dir, doc: dict | None = None,
                          refined_by: str | None = None) -> None:
    """Per frame (module doc): the outline and skeleton at the pose written (`doc`, the
    RESULT.json document; default the keypoint fit's), the detections with their confidence
    and their residuals to it, and the keypoint pose faintly where `refined_by` (an image
    refinement, in words) moved it; plus `summary.png`, every residual of every frame on one
    canvas, magnified, under a legend of the poses drawn. The folder is written atomically
    (`dream.io.staged_directory`): on a failure (an unreadable image...) nothing is left in
    it."""
    from dream.camera import project
    from dream.io.atomic import staged_directory
    from dream.transforms import transform_points

    cam = sequence.camera
    from dream.result import written_poses

    n = len(sequence.frames)
    keypoint_poses = [result.T_cam_base_of_frame(i) for i in range(n)]
    poses = keypoint_poses if doc is None else [_pose_or_none(T) for T in written_poses(doc)]
    # a result found without keypoints (no observations): the outline alone
    edges = robot.skeleton_edges if obs.uv.shape[1] == len(robot.keypoint_names) else ()
    outliner = _Outliner(sequence, robot)
    summary = blank_image(cam.width, cam.height)
    moved_any = False
    with staged_directory(out_dir) as stage:
        for i, frame in enumerate(sequence.frames):
            camera, T = sequence.frame_camera(i), poses[i]
            uv_proj = np.full(obs.uv[i].shape, np.nan) if T is None else \
                project(camera, transform_points(T, obs.P_base[i]))
            image = outliner.draw(_frame_canvas(sequence, frame), camera, i, T)
            if keypoint_poses[i] is not None and T is not None and edges:
                uv_keypoint_pose = project(camera, transform_points(keypoint_poses[i],
                                                                    obs.P_base[i]))
                if np.nanmax(np.linalg.norm(uv_keypoint_pose - uv_proj, axis=-1)) > MOVED_PX:
                    moved_any = True
                    image = draw_faint_skeleton(image, uv_keypoint_pose, edges)
            image = draw_skeleton(image, uv_proj, edges)
            image = draw_observations(image, obs.uv[i], uv_proj, result.inlier[i])
            image = draw_confidences(image, obs.uv[i], obs.confidence[i])
            _write_png(stage / f"{frame.name}.result.png", image)
            magnified = obs.uv[i] + RESIDUAL_MAGNIFICATION * (uv_proj - obs.uv[i])
            summary = draw_observations(summary, obs.uv[i], magnified, result.inlier[i])
        _write_png(stage / "summary.png", with_legend(summary, _legend(
            result, refined_by if moved_any else None)))


def _legend(result, refined_by: str | None) -> list[tuple[str, tuple[int, int, int]]]:
    """The summary image's lines: which pose each colour shows."""
    written = f"the pose written ({refined_by})" if refined_by else "the pose written (keypoints)"
    lines = [(f"{result.mode} frames: keypoint fit RMSE {result.fit.rmse_px:.2f} px over "
              f"{result.fit.num_inliers} keypoints", (255, 255, 255)),
             (f"cyan outline, yellow skeleton: {written}", OUTLINE_RGB),
             ("green rings: detections (grey: rejected by the keypoint fit)", OBSERVED_RGB),
             (f"magenta: residuals to the pose written (x{RESIDUAL_MAGNIFICATION:g} above)",
              RESIDUAL_RGB)]
    if refined_by:
        lines.append(("faint grey skeleton, per frame: the keypoint pose", FAINT_RGB))
    return lines

