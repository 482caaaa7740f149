"""RESULT.json's `start` object of `dream calibrate` by the silhouette search
(`dream.cli.calibrate_start`): how the pose was searched, what the masks held, what the arm
carried, the mark, and how clearly the winner won."""

from __future__ import annotations


def start_doc(outcome, inputs, guess, seq, marked=None) -> dict:
    """RESULT.json's `start` object: how the pose was searched and how clearly it won."""
    from dream.coarse.calibration import CARRIED
    from dream.metrics import pose_errors
    from dream.outline_robot import joints_at_rest
    from dream.pnp import increment_between

    rival = outcome.rival
    distance = None if rival is None else [float(v) for v in pose_errors(
        rival.T_cam_base, outcome.best.T_cam_base)]
    return {"method": "silhouette search", "hypotheses": guess.description,
            "hypotheses_scored": outcome.hypotheses, "evidence": inputs.source,
            "frames": [seq.frames[int(i)].name for i in inputs.frames],
            "joints_moved": list(inputs.meshes.robot.joint_names),
            "joints_at_rest": joints_at_rest(inputs.meshes.robot),
            "left_out_links": list(inputs.left_out), "motion_masks": inputs.motion,
            "carried": carried_doc(inputs.carried, CARRIED in outcome.hypotheses),
            "focal": None if inputs.focal is None else inputs.focal.to_dict(),
            "distortion": None if inputs.distortion is None else inputs.distortion.to_dict(),
            "timing": None if inputs.timing is None else inputs.timing.to_dict(),
            "principal": None if inputs.principal is None else inputs.principal.to_dict(),
            "T_cam_base": outcome.best.T_cam_base.tolist(), "iou": outcome.best.iou,
            "found_iou": outcome.best.found_iou, "away": away_doc(outcome, inputs, seq),
            "rival_iou": None if rival is None else rival.iou,
            "rival_distance_m": None if distance is None else distance[0],
            "rival_angle_rad": None if distance is None else distance[1],
            "finish_left_out_frames": [seq.frames[int(inputs.frames[i])].name
                                       for i in outcome.best.left_out_frames],
            "gap": outcome.gap, "basin_returned": outcome.basin_returned,
            "basin_starts": outcome.basin_starts, "basin_m": outcome.basin_m,
            "basin_return_m": outcome.basin_return_m,
            "basin_ends_xi": [increment_between(outcome.best.T_cam_base, T).tolist()
                              for T in outcome.basin_ends],
            "basin_ends_iou": None if outcome.basin_ious is None
            else [float(v) for v in outcome.basin_ious],
            "frames_jackknife_xi": outcome.frames_xi.tolist(),
            "links_jackknife_xi": outcome.links_xi.tolist(),
            "jackknife_links": list(outcome.jackknife_links),
            "candidates": [{"source": c.source, "iou": c.iou, "coarse_iou": c.coarse_iou}
                           for c in outcome.candidates],
            "seconds": outcome.seconds, "challenge": None,
            "mark": None if marked is None else mark_doc(marked, seq)}


def away_doc(outcome, inputs, seq) -> dict:
    """RESULT.json's `start.away`: the masks' moving pixels away from the robot at the
    search's winner (`dream.coarse.away`) and its IoUs without them (`iou` and `found_iou`
    without them: the found test's)."""
    from dream.coarse.away import away_at_pose
    from dream.coarse.settings import SearchSettings

    away = away_at_pose(inputs.meshes, inputs.joints, inputs.masks, seq.camera,
                        outcome.best.T_cam_base, SearchSettings().away_margin_px)
    found = outcome.best.found_iou
    return {**away.to_dict(), "iou_without": away.iou_without(outcome.best.iou),
            "found_iou_without": None if found is None else away.iou_without(found)}


def carried_doc(carving, left_out: bool) -> dict | None:
    """RESULT.json's `start.carried`: what the carving at the search's winner found the arm
    carrying, whether its pixels were `left_out` (the search ran again without them), or why
    nothing; None where it did not run."""
    if carving is None:
        return None
    finding = carving.finding
    return {**carving.to_dict(), "left_out_of_search": left_out,
            "box_around_hull": None if finding is None else finding.geometry.to_params()}


def mark_doc(marked, seq) -> dict:
    """RESULT.json's `start.mark`: the mark's frames, its PnP pose and fit (None where it is
    known in too few frames for one) and how many cameras it placed for the search."""
    fit = marked.fit
    return {"clicked_frames": marked.clicked,
            "tracked_frames": len(marked.frames) - marked.clicked,
            "frames": [seq.frames[int(i)].name for i in marked.frames],
            "T_cam_base": None if fit is None else fit.T_cam_base.tolist(),
            "rmse_px": None if fit is None else fit.rmse_px,
            "placed_hypotheses": marked.placed,
            "search_sigma_m": None if fit is None else marked.guess.sigma_m,
            "search_sigma_rad": None if fit is None else marked.guess.sigma_rad}
