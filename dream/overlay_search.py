"""The overlays of a pose found without keypoints (`dream calibrate` without `--model`: the
silhouette search, `dream.coarse`; file edge). `write_calibration_overlays` is what
`dream calibrate --overlays` calls: these for such a pose, `dream.overlay`'s otherwise.

Per frame: the robot's outline at the pose written (cyan); where the search named something
the URDF lacks moving with a link (RESULT.json `start.carried`), the box it sized around it
(magenta); where the verdict found much of the masks' moving pixels away from the robot
(`start.away`, `dream.coarse.away`: another arm at work, someone walking past; not what
touches the arm), those pixels tinted orange in the frames the search compared.
`summary.png` holds the outlines of every frame the search compared over the first of them,
dimmed, with the away pixels of all of them."""

from __future__ import annotations

import logging

import numpy as np

from dream.overlay import (
    AWAY_RGB,
    CARRIED_RGB,
    OUTLINE_RGB,
    _frame_canvas,
    _Outliner,
    _pose_or_none,
    _write_png,
    blank_image,
    carried_corners,
    draw_box,
    draw_outline,
    tint,
    with_legend,
    write_result_overlays,
)

log = logging.getLogger(__name__)

SUMMARY_DIM = 0.5             # the frame under the search's outlines in its summary, dimmed


def write_calibration_overlays(sequence, robot, obs, result, out_dir, doc: dict,
                               refined_by: str | None) -> None:
    """`dream calibrate --overlays`: those of a pose found without keypoints (no keypoint
    observations, RESULT.json `start`) as the module doc says, else
    `dream.overlay.write_result_overlays`."""
    from dream.result import written_poses

    if obs.uv.shape[1] == len(robot.keypoint_names) or doc.get("start") is None:
        write_result_overlays(sequence, robot, obs, result, out_dir, doc=doc,
                              refined_by=refined_by)
        return
    poses = [_pose_or_none(T) for T in written_poses(doc)]
    write_search_overlays(sequence, robot, poses, out_dir, doc, refined_by)


def write_search_overlays(sequence, robot, poses: list, out_dir, doc: dict,
                          refined_by: str | None) -> None:
    """The overlays of a pose found without keypoints (module doc) into `out_dir`, written
    atomically; `poses`: each frame's written pose (None where none)."""
    from dream.camera import project
    from dream.io.atomic import staged_directory
    from dream.transforms import transform_points

    start = doc["start"]
    index = {frame.name: i for i, frame in enumerate(sequence.frames)}
    compared = {index[name] for name in start.get("frames", ()) if name in index}
    outliner = _Outliner(sequence, robot)
    carried = start.get("carried") or {}
    corners = carried_corners(outliner.robot, outliner.joints, carried)
    away = away_pixels(sequence, robot, doc)
    summary = None
    with staged_directory(out_dir) as stage:
        for i, frame in enumerate(sequence.frames):
            camera, T = sequence.frame_camera(i), poses[i]
            image = _frame_canvas(sequence, frame)
            if i in compared and summary is None:
                summary = (image * SUMMARY_DIM).astype(np.uint8)
            if i in away:
                image = tint(image, away[i])
            silhouette = outliner.silhouette(camera, i, T)
            if silhouette is not None:
                image = draw_outline(image, silhouette)
                if i in compared:
                    summary = draw_outline(summary, silhouette)
            if corners is not None and T is not None:
                image = draw_box(image, project(camera, transform_points(T, corners[i])))
            _write_png(stage / f"{frame.name}.result.png", image)
        if summary is None:
            summary = blank_image(sequence.camera.width, sequence.camera.height)
        if away:
            summary = tint(summary, np.any(list(away.values()), axis=0))
        _write_png(stage / "summary.png", with_legend(summary, search_legend(
            doc, refined_by, len(compared), carried if corners is not None else None,
            bool(away))))


def away_pixels(sequence, robot, doc: dict) -> dict[int, np.ndarray]:
    """Frame index -> (H, W) bool: the search's masks' pixels away from the robot at the pose
    written (`doc["T_cam_base"]`: the search's camera is fixed), in the frames it compared
    (`start.frames`, by name), where the verdict found them more than
    `SearchSettings.max_away_share` of the moving pixels (none otherwise): the search's masks
    made again (`dream.coarse.calibration.search_masks`) from `sequence`, whose joints must be
    those the calibration used (its readings interpolated where it did)."""
    from dream.coarse.away import away_masks_at_pose
    from dream.coarse.calibration import search_masks
    from dream.coarse.settings import SearchSettings
    from dream.errors import DreamError

    settings = SearchSettings()
    share = (doc["start"].get("away") or {}).get("share") or 0.0
    if share <= settings.max_away_share:
        return {}
    try:
        inputs = search_masks(sequence, robot, settings)
    except DreamError as exc:
        log.warning("overlays without the pixels away from the robot: %s", exc)
        return {}
    compared = set(doc["start"].get("frames") or ())
    chosen = [n for n, i in enumerate(inputs.frames) if sequence.frames[int(i)].name in compared]
    if not chosen:
        return {}
    away = away_masks_at_pose(inputs.meshes, inputs.joints[chosen], inputs.masks[chosen],
                              sequence.camera, doc["T_cam_base"], settings.away_margin_px)
    return {int(inputs.frames[n]): mask for n, mask in zip(chosen, away, strict=True)}


def search_legend(doc: dict, refined_by: str | None, compared: int, carried: dict | None,
                  away: bool = False) -> list[tuple[str, tuple[int, int, int]]]:
    """The summary image's lines for a pose found without keypoints."""
    start = doc["start"]
    verdict = (doc.get("quality") or {}).get("verdict", "not given")
    iou = start.get("iou")
    lines = [(f"no keypoints: the pose from the robot's silhouettes ({start.get('evidence')})"
              + ("" if iou is None else f", IoU {iou:.2f}") + f"; quality: {verdict}",
              (255, 255, 255)),
             (f"cyan outline: the pose written ({refined_by or 'the silhouette search'})",
              OUTLINE_RGB),
             (f"above: its outline in each of the {compared} frames the search compared",
              OUTLINE_RGB)]
    if carried is not None:
        left_out = ", left out of the search" if carried.get("left_out_of_search") else ""
        lines.append((f"magenta box, per frame: something the URDF lacks moving with "
                      f"{carried['named']}{left_out}", CARRIED_RGB))
    if away:
        share = start["away"]["share"]
        lines.append((f"orange: moving pixels away from the robot ({100 * share:.0f} % of "
                      f"them), not counted as robot", AWAY_RGB))
    return lines
