"""Silhouette polish: refine a keypoint calibration's `T_cam_base` with the robot masks.

The keypoints fix the extrinsic from a handful of link origins per frame; the robot's outline in
the masks (`NNNNNN.seg.png` of the DREAM layout, franka_offline's `mask/`) holds thousands of
further constraints. The polish aligns the silhouette rendered from the URDF's visual meshes
(`dream.silhouette`) with the observed masks of every frame at once (fixed camera), on the CPU.

Modules, in the order of the work:
    settings: `PolishSettings`, every constant.
    objective: the signed distance to the observed outline at the model's contour points.
    refine: Levenberg-Marquardt on it and the polish of one pose (`polish`, `PolishResult`).
    frames: which frames of a fixed camera agree on its extrinsic (`FrameAgreement`).
    guard: whether the polished pose is kept (IoU gain, `KeypointGuard`, `fit_shrinkage`).
    calibration: the polish of a calibration, all frames or each frame (`dream calibrate
        --polish`).
    documents: the `polish` objects of RESULT.json.

Public API:
    PolishSettings, KeypointSet, KeypointGuard, PolishResult, signed_distance(mask),
    fit_shrinkage(n_keypoints)
    polish(meshes, joints, masks, camera, T_cam_base, keypoints, params, frame_names,
           guard) (pure)
    check_polish_input(sequence, mode, network_masks); has_masks(sequence);
    silhouette_inputs(sequence, robot, params, predict_masks); polish_calibration(sequence,
    robot, result, obs, params, predict_masks); polish_frames(sequence, robot, result, obs, params,
    progress)
    polish_to_dict(result); result_doc_with_polish(doc, result);
    frame_polish_to_dict(result); frame_polish_summary(results);
    result_doc_with_frame_polishes(doc, results)
"""

from dream.polish.calibration import (
    SilhouetteInputs,
    check_polish_input,
    has_masks,
    polish_calibration,
    polish_frames,
    silhouette_inputs,
)
from dream.polish.documents import (
    frame_polish_summary,
    frame_polish_to_dict,
    polish_to_dict,
    result_doc_with_frame_polishes,
    result_doc_with_polish,
)
from dream.polish.guard import KeypointGuard, KeypointSet, fit_shrinkage
from dream.polish.objective import signed_distance
from dream.polish.refine import PolishResult, polish
from dream.polish.settings import PolishSettings

__all__ = [
    "KeypointGuard",
    "KeypointSet",
    "PolishSettings",
    "PolishResult",
    "SilhouetteInputs",
    "check_polish_input",
    "fit_shrinkage",
    "frame_polish_summary",
    "frame_polish_to_dict",
    "has_masks",
    "polish",
    "polish_calibration",
    "polish_frames",
    "polish_to_dict",
    "result_doc_with_frame_polishes",
    "result_doc_with_polish",
    "signed_distance",
    "silhouette_inputs",
]
