"""Glue between a `Sequence`, a `Robot` and the solvers: observations, truth, evaluation."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dream.calibration import (
    CalibrationResult,
    Observations,
    calibrate_all,
    calibrate_each,
    with_keypoint_jackknife,
)
from dream.camera import project
from dream.errors import CalibrationError, InputError, RobotError
from dream.metrics import (
    ADD_AUC_STEP_M,
    ADD_AUC_THRESHOLD_M,
    MIN_INFRAME_KEYPOINTS,
    PCK_AUC_STEP_PX,
    PCK_AUC_THRESHOLD_PX,
    add_per_frame,
    auc,
    keypoint_errors,
    pose_errors,
    summarise,
)
from dream.pnp import SolverSettings
from dream.robot import Robot, is_robot_reference, load_robot
from dream.sequence import Sequence
from dream.transforms import transform_points

log = logging.getLogger(__name__)


FIX_ROBOT_OPTION = ("give --robot a built-in robot (dream robots lists them) or the path of "
                    "a .urdf file")
KEYPOINTS_OPTION = "--keypoints"


def robot_for(sequence: Sequence, robot: str | None = None,
              keypoints: tuple[str, ...] | None = None, *,
              robot_from: str | Path | None = None,
              keypoints_from: str | Path | None = None,
              option_keypoints: tuple[str, ...] | None = None) -> Robot:
    """The robot of a sequence (or the one named), with the given keypoints or its defaults.

    An unknown robot is an `InputError` naming where its name came from: `robot_from` (a file,
    e.g. RESULT.json), else the --robot option when `robot` is given, else the data
    (`sequence.source`). Keypoints that are not links of the robot are an `InputError` naming
    `keypoints_from` (e.g. the data, whose labels name them) when given; without it they stay a
    `RobotError` for the caller to attribute (`dream.detection` names the model).
    `option_keypoints` (the links of --keypoints) are used where `keypoints` are not given;
    where they are, --keypoints naming other links is an `InputError`."""
    name = robot or sequence.robot
    if keypoints and option_keypoints:
        check_option_agrees(option_keypoints, keypoints, str(keypoints_from or "the data"))
    elif option_keypoints and is_robot_reference(name):
        return robot_with_option_keypoints(name, tuple(option_keypoints))
    try:
        return load_robot(name, list(keypoints) if keypoints else None)
    except RobotError as exc:
        if not is_robot_reference(name):
            if robot_from is not None:
                raise InputError(f"names robot {name!r}, which is not known ({exc})",
                                 robot_from, "correct its robot name, or pass --robot with a "
                                 "built-in robot (dream robots lists them) or a .urdf file"
                                 ) from None
            if robot:
                raise InputError(f"--robot {name!r}: {exc}", fix=FIX_ROBOT_OPTION) from None
            raise InputError(f"the data names robot {name!r}, which is not known ({exc})",
                             sequence.source, "pass --robot with a built-in robot (dream "
                             "robots lists them) or the path of a .urdf file") from None
        if keypoints and keypoints_from is not None:
            raise InputError(f"the keypoints named there are not all links of robot {name!r} "
                             f"({exc})", keypoints_from,
                             "name the keypoints after links of the robot (dream robots lists "
                             "the built-in ones), or pass --robot with the robot they belong "
                             "to") from None
        raise


def check_option_agrees(option_keypoints: tuple[str, ...], keypoints: tuple[str, ...],
                        whose: str) -> None:
    """--keypoints must name the links that fix the keypoints already (`whose`: a model's, the
    labels' or a result's): the same links in any order; otherwise one `InputError` line."""
    if set(option_keypoints) != set(keypoints) or len(option_keypoints) != len(keypoints):
        raise InputError(f"{KEYPOINTS_OPTION} {','.join(option_keypoints)} contradicts the "
                         f"keypoints of {whose} ({', '.join(keypoints)})",
                         fix=f"drop {KEYPOINTS_OPTION} (the keypoints come from {whose})")


def robot_with_option_keypoints(name: str, keypoints: tuple[str, ...]) -> Robot:
    """Robot `name` (built-in name or URDF path) with the links of --keypoints; a link the URDF
    lacks is one `InputError` line naming it and the command that lists the links; keypoints
    that coincide or stay on one line for every joint value are logged as warnings."""
    from dream.robot import parse_urdf
    from dream.robot.keypoint_choice import analyse_keypoints
    from dream.robot.registry import urdf_path_of

    fix = f"dream robots --urdf {name} lists its links and suggests keypoints"
    try:
        robot = load_robot(name, list(keypoints))
    except RobotError as exc:
        links = parse_urdf(urdf_path_of(name)).links
        unknown = [k for k in keypoints if k not in links]
        problem = (f"{KEYPOINTS_OPTION} names {', '.join(repr(k) for k in unknown)}, not "
                   f"{'a link' if len(unknown) == 1 else 'links'} of robot {name!r}"
                   if unknown else f"{KEYPOINTS_OPTION} {','.join(keypoints)}: {exc}")
        raise InputError(problem, fix=fix) from None
    advice = analyse_keypoints(robot.tree, robot.base_link, keypoints)
    for group in advice.given_coincident:
        log.warning("%s: %s coincide for every joint value and cannot be told apart; keep one",
                    KEYPOINTS_OPTION, ", ".join(group))
    line = advice.given_line
    if line is not None:
        log.warning("%s: the keypoints stay on one line %s; %s", KEYPOINTS_OPTION,
                    "(the same for every joint value), so no number of frames fixes the "
                    "camera's rotation about it" if line.fixed_line else "in every joint "
                    "configuration, so no single frame fixes the camera", fix)
    return robot


def joints_in_robot_order(sequence: Sequence, robot: Robot) -> np.ndarray:
    """(F, J) joints of the sequence reordered to the robot's joint names."""
    try:
        return robot.joints_from_named(list(sequence.joint_names), sequence.joints)
    except RobotError as exc:
        raise InputError(f"the data's joints do not fit robot '{robot.name}': {exc}",
                         sequence.source, "give --robot the robot (or URDF file) the data was "
                         "recorded on, or name the data's joint columns after its URDF joints"
                         ) from None


def with_robot_joints(sequence: Sequence, robot: Robot, joints: np.ndarray) -> Sequence:
    """The sequence with the robot's joints of every frame replaced by `joints` (F, J), in the
    robot's joint order (other joints of the data, such as fingers, kept)."""
    joints = np.asarray(joints, dtype=float)
    if joints.shape != (len(sequence), len(robot.joint_names)):
        raise InputError(f"joints of shape {joints.shape} for {len(sequence)} frames of robot "
                         f"'{robot.name}' ({len(robot.joint_names)} joints)")
    columns = [list(sequence.joint_names).index(n) for n in robot.joint_names]
    values = sequence.joints
    values[:, columns] = joints
    return sequence.with_joints(values)


def observations_from_labels(sequence: Sequence, robot: Robot) -> Observations:
    """Observations from the 2D labels; labels outside the image count as not observed."""
    if not sequence.has_labels:
        raise InputError("the data has no 2D keypoint labels (projected_location)",
                         sequence.source,
                         "detect the keypoints with a model instead (--model, dream.detect)")
    P_base = robot.forward_kinematics(joints_in_robot_order(sequence, robot))
    uv = sequence.uv_labels()
    uv = np.where(sequence.camera.in_image(uv)[..., None], uv, np.nan)
    confidence = np.where(np.all(np.isfinite(uv), -1), 1.0, 0.0)
    return Observations(P_base, uv, confidence, tuple(f.name for f in sequence.frames),
                        robot.keypoint_names)


def calibrate(sequence: Sequence, obs: Observations, mode: str = "all",
              settings: SolverSettings | None = None) -> CalibrationResult:
    """`calibrate_all` (with its keypoint jackknife) or `calibrate_each` of the sequence; a
    `CalibrationError` names the data (`sequence.source`)."""
    if mode not in ("all", "each"):
        raise InputError(f"unknown frames mode '{mode}'",
                         fix="use 'all' or 'each' (--frames all or --frames each)")
    try:
        if mode == "all":
            camera = sequence.fixed_camera("use --frames each")
            return with_keypoint_jackknife(calibrate_all(obs, camera, settings), obs, camera,
                                           settings)
        cameras = tuple(sequence.frame_camera(i) for i in range(len(sequence)))
        return calibrate_each(obs, sequence.camera, settings, frame_cameras=cameras)
    except CalibrationError as exc:
        if exc.path is not None or sequence.source is None:
            raise
        raise CalibrationError(exc.problem, sequence.source, exc.fix) from None


def truth_poses(sequence: Sequence) -> np.ndarray:
    """(F, 4, 4) ground-truth extrinsic per frame, NaN where the data has none."""
    out = np.full((len(sequence), 4, 4), np.nan)
    for i, frame in enumerate(sequence.frames):
        T = sequence.T_cam_base_truth(frame)
        if T is not None:
            out[i] = T
    return out


def _has_truth(T_true: np.ndarray) -> np.ndarray:
    """(F,) True for the frames whose true extrinsic (`truth_poses`) is known."""
    return np.all(np.isfinite(T_true.reshape(len(T_true), -1)), axis=1)


@dataclass(frozen=True)
class TrueKeypoints:
    """Each frame's keypoints at its true extrinsic (`true_keypoints`).

    Attributes:
        P_base: (F, N, 3) keypoints in the base frame, m.
        T_cam_base: (F, 4, 4) the true extrinsics (`truth_poses`; NaN where unknown).
        uv: (F, N, 2) their pixels in each frame's own camera (finite also where unknown).
        in_frame: (F, N) True where a keypoint projects into the image of a frame with truth.
        counted: (F,) True for frames with at least `MIN_INFRAME_KEYPOINTS` in-frame keypoints
            (those in `dream eval`'s ADD AUC).
    """

    P_base: np.ndarray
    T_cam_base: np.ndarray
    uv: np.ndarray
    in_frame: np.ndarray
    counted: np.ndarray


def true_keypoints(sequence: Sequence, robot: Robot) -> TrueKeypoints:
    """The keypoints of every frame at its true extrinsic, and which of them `dream eval`
    counts. The sequence must have ground truth or a reference extrinsic."""
    T_true = truth_poses(sequence)
    has_truth = _has_truth(T_true)
    P_base = robot.forward_kinematics(joints_in_robot_order(sequence, robot))
    T_true_safe = np.where(has_truth[:, None, None], T_true, np.eye(4))
    P_cam_true = transform_points(T_true_safe[:, None], P_base)
    uv_true = np.stack([project(sequence.frame_camera(i), P_cam_true[i])
                        for i in range(len(sequence))])
    in_frame = sequence.camera.in_image(uv_true) & np.all(np.isfinite(uv_true), -1)
    in_frame &= has_truth[:, None]
    return TrueKeypoints(P_base, T_true, uv_true, in_frame,
                         in_frame.sum(1) >= MIN_INFRAME_KEYPOINTS)


def evaluate(sequence: Sequence, robot: Robot, result_doc: dict[str, Any]) -> dict[str, Any]:
    """METRICS.json of `dream eval`: the result against the sequence's ground truth."""
    if not sequence.has_ground_truth:
        raise InputError("the data has no ground truth or reference extrinsic", sequence.source,
                         "evaluate on data with location/quaternion_xyzw or a reference")
    names = [f.name for f in sequence.frames]
    by_name = {f["frame"]: f for f in result_doc.get("per_frame", [])}
    mode = result_doc.get("frames_mode", "all")
    truth = true_keypoints(sequence, robot)
    P_base, T_true, uv_true, in_frame = truth.P_base, truth.T_cam_base, truth.uv, truth.in_frame
    has_truth, counted = _has_truth(T_true), truth.counted
    T_est = np.full((len(names), 4, 4), np.nan)
    for i, name in enumerate(names):
        if mode == "all":
            T_est[i] = result_doc["T_cam_base"]
        elif by_name.get(name, {}).get("T_cam_base") is not None:
            T_est[i] = np.asarray(by_name[name]["T_cam_base"], dtype=float)
    add = add_per_frame(P_base[has_truth], T_est[has_truth], T_true[has_truth])
    add_counted = add[counted[has_truth]]
    uv_det = np.full(uv_true.shape, np.nan)
    kp_index = {k: j for j, k in enumerate(robot.keypoint_names)}
    for i, name in enumerate(names):
        for kp in by_name.get(name, {}).get("keypoints", []):
            j = kp_index.get(kp.get("name"))
            if j is not None and kp.get("uv") is not None:
                uv_det[i, j] = kp["uv"]
    # a result calibrated without keypoints (the image search) has none to score
    scored = any(by_name.get(name, {}).get("keypoints") for name in names)
    kp_err = keypoint_errors(uv_det, uv_true, in_frame) if scored else None
    t_err, r_err = pose_errors(T_est[has_truth], T_true[has_truth])
    solved = np.all(np.isfinite(T_est[has_truth].reshape(-1, 16)), axis=1)
    return {
        "frames": len(names),
        "frames_with_truth": int(has_truth.sum()),
        "frames_in_add_auc": int(counted.sum()),
        "frames_mode": mode,
        "add_m": summarise(add_counted),
        "add_auc": auc(add_counted, ADD_AUC_THRESHOLD_M, ADD_AUC_STEP_M),
        "add_auc_threshold_m": ADD_AUC_THRESHOLD_M,
        "keypoint_l2_px": None if kp_err is None else summarise(kp_err),
        "pck_auc": None if kp_err is None else auc(kp_err, PCK_AUC_THRESHOLD_PX,
                                                   PCK_AUC_STEP_PX),
        "pck_auc_threshold_px": PCK_AUC_THRESHOLD_PX,
        "translation_error_m": summarise(np.where(solved, t_err, np.inf)),
        "rotation_error_rad": summarise(np.where(solved, r_err, np.inf)),
    }
