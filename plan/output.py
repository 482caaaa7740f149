"""A plan's files: `joints.txt`, `plan.json` and `contact_sheet.png` (docs/data_format.md).

- joints.txt: one configuration a line, radians (m for prismatic joints), space-separated, in
  the robot's joint order, which a `#` comment line names first (`numpy.loadtxt` reads it);
- plan.json: the poses with their checks, the moves between them with their clearance, the
  predicted 1-sigma of the calibration, the camera and the settings the plan was made with;
- contact_sheet.png: each pose rendered from the stated camera, keypoints drawn.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.io import atomic_directory
from dream.io.atomic import dumps
from dream.io.images import encode_png
from dream.overlay import draw_skeleton
from dream.provenance import camera_record
from dream.robot import Robot
from dream.transforms import invert_T, transform_points
from plan.camera_prior import CameraPrior
from plan.feasibility import DISTANCE_HORIZON_M, Box, Feasibility, place_boxes
from plan.planner import Plan, PlanSettings
from synth.contact_sheet import tile
from synth.render import BACKGROUND_GEOM, SceneRenderer
from synth.scene import build_scene
from synth.scene_settings import SceneSettings

JOINTS_FILE, PLAN_FILE, SHEET_FILE = "joints.txt", "plan.json", "contact_sheet.png"
PLAN_FORMAT_VERSION = 1
JOINTS_DECIMALS = 6
BOX_RGBA = (0.9, 0.3, 0.2, 0.5)   # keep-out boxes on the contact sheet
BACKGROUND_RGB = (110, 120, 130)  # behind the robot on the contact sheet


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _sigmas(predicted: dict) -> dict[str, Any]:
    out = {"camera_position_worst_mm": _finite(predicted["position_worst_m"] * 1e3),
           "camera_rotation_worst_deg": _finite(np.rad2deg(predicted["rotation_worst_rad"]))}
    if "position_base_m" in predicted:
        out["camera_position_base_mm"] = [_finite(v * 1e3) for v in
                                          predicted["position_base_m"]]
    return out


def plan_document(plan: Plan, robot: Robot, prior: CameraPrior, feasibility: Feasibility,
                  settings: PlanSettings) -> dict[str, Any]:
    """plan.json's document."""
    poses = [{"index": i, "joints_rad": q.tolist(),
              "self_clearance_m": _finite(check.self_clearance_m),
              "box_clearance_m": _finite(check.box_clearance_m),
              "table_clearance_m": _finite(check.table_clearance_m),
              "robot_share_outside_image": check.cut,
              "keypoint_border_px": check.border_px}
             for i, (q, check) in enumerate(zip(plan.joints, plan.checks, strict=True))]
    checker = plan.candidates.checker
    return {
        "format_version": PLAN_FORMAT_VERSION,
        "robot": robot.name,
        "joint_names": list(robot.joint_names),
        "keypoint_names": list(robot.keypoint_names),
        "camera": {"source": prior.source, "T_cam_base": prior.T_cam_base.tolist(),
                   "position_base_m": invert_T(prior.T_cam_base)[:3, 3].tolist(),
                   "position_sigma_m": prior.position_sigma_m,
                   "rotation_sigma_deg": float(np.rad2deg(prior.rotation_sigma_rad)),
                   "intrinsics": camera_record(prior.camera)},
        "predicted": {**_sigmas(plan.predicted), "keypoint_noise_px": settings.noise_px},
        "random_valid_poses_median": _sigmas(plan.random_predicted),
        "start_joints_rad": None if plan.start is None else plan.start.tolist(),
        "path_length_rad": plan.path_length,
        "moves": _moves(plan, feasibility),
        "clearance_cap_m": DISTANCE_HORIZON_M,
        "always_in_contact": [] if checker is None else
        [list(pair) for pair in checker.always_in_contact],
        "other_joints": {} if checker is None else dict(zip(
            checker.scene.extra_joint_names, checker.scene.extra_rest.tolist(), strict=True)),
        "candidates": {"valid": len(plan.candidates.joints), "draws": plan.candidates.draws,
                       "rejected": dict(plan.candidates.failures)},
        "feasibility": {**asdict(feasibility),
                        "keep_out": [asdict(b) for b in feasibility.keep_out]},
        "settings": asdict(settings),
        "poses": poses,
    }


def _moves(plan: Plan, feasibility: Feasibility) -> list[dict[str, Any]]:
    """Each straight joint-space move of the path (from the start, then pose to pose) with its
    least clearance; `clear` False where it comes closer than the clearance asked for."""
    if plan.move_clearance_m is None:
        return []
    first = 0 if plan.start is not None else 1
    names = ["start", *range(len(plan.joints))]
    return [{"from": names[i], "to": i, "clearance_m": _finite(c),
             "clear": bool(c >= feasibility.clearance_m)}
            for i, c in enumerate(plan.move_clearance_m, start=first)]


def joints_text(plan: Plan, robot: Robot) -> str:
    """joints.txt's text."""
    lines = ["# " + " ".join(robot.joint_names) + " (rad; m for prismatic joints)"]
    lines += [" ".join(f"{v:.{JOINTS_DECIMALS}f}" for v in q) for q in plan.joints]
    return "\n".join(lines) + "\n"


def render_poses(robot: Robot, joints: np.ndarray, camera: CameraIntrinsics,
                 T_cam_base: np.ndarray, boxes: tuple[Box, ...] = ()) -> list[np.ndarray]:
    """(H, W, 3) uint8 renders of the robot at each of `joints` (N, J) through `camera` at
    `T_cam_base`, keep-out `boxes` shaded, on grey (dark arms stay visible)."""
    scene = build_scene(robot, SceneSettings(num_lights=2, num_distractors=len(boxes)))
    place_boxes(scene, boxes)
    scene.model.geom_rgba[scene.distractor_geom_ids] = BOX_RGBA
    with SceneRenderer(scene, camera) as renderer:
        images = []
        for q in joints:
            renderer.set_state(q, T_cam_base)
            out = renderer.render(rgb=True, segmentation=True)
            rgb = out.rgb.copy()
            rgb[out.geom_ids == BACKGROUND_GEOM] = BACKGROUND_RGB
            images.append(rgb)
    return images


def render_sheet(plan: Plan, robot: Robot, prior: CameraPrior,
                 feasibility: Feasibility) -> np.ndarray:
    """(H, W, 3) uint8: every pose rendered from the stated camera (`render_poses`),
    keypoints drawn, in visiting order."""
    images = render_poses(robot, plan.joints, prior.camera, prior.T_cam_base,
                          feasibility.keep_out)
    return tile([draw_skeleton(rgb, _project(robot, q, prior), robot.skeleton_edges)
                 for rgb, q in zip(images, plan.joints, strict=True)])


def _project(robot: Robot, q: np.ndarray, prior: CameraPrior) -> np.ndarray:
    return project(prior.camera, transform_points(prior.T_cam_base, robot.forward_kinematics(q)))


def write_plan(out_dir: str | Path, plan: Plan, robot: Robot, prior: CameraPrior,
               feasibility: Feasibility, settings: PlanSettings, sheet: np.ndarray | None,
               overwrite: bool = False) -> Path:
    """The plan's files in `out_dir`, all or none (`dream.io.atomic_directory`)."""
    out_dir = Path(out_dir)
    document = plan_document(plan, robot, prior, feasibility, settings)
    with atomic_directory(out_dir, overwrite) as tmp:
        (tmp / JOINTS_FILE).write_text(joints_text(plan, robot))
        (tmp / PLAN_FILE).write_text(dumps(document) + "\n")
        if sheet is not None:
            (tmp / SHEET_FILE).write_bytes(encode_png(sheet, out_dir / SHEET_FILE))
    return out_dir
