"""Effect injection: measured-like keypoint-only sequences of a world that differs from the model.

The "true world" is the nominal robot and camera changed by a `ModelExtension`
(`dream.extension`); the written data is what a user would log from it, so `dream diagnose`
can be tested against a known answer:

- labels (`Frame.uv_labels`): the TRUE keypoints (joint offsets, link lengths, keypoint bias, at
  the true joint values of the image time) projected through the TRUE camera (corrected
  intrinsics, distortion) from the TRUE per-frame extrinsic (after a camera move
  `T_cam_base_after = dT @ T_cam_base_before`), plus Gaussian pixel noise; labels outside the
  image are NaN.
- joints (`Frame.joints`): the joint READINGS, without the offsets; with a time offset tau the
  reading stamped at image time t is the reading signal at t - tau (the readings lag), so
  `effective_joints(readings, times, tau)` recovers the signal at the image times.
- camera (`Sequence.camera`): the NOMINAL camera (the intrinsics the user believes, no
  distortion).
- `Frame.timestamp`: the image times, s; `Frame.T_cam_base_true`: the true per-frame extrinsic;
  `Sequence.T_cam_base_reference`: None.

The motion is a smooth random joint trajectory (sums of low-frequency sinusoids; needed for a
time offset) or independent random configurations. The camera, the motion and the pixel noise
are drawn from `spec.seed` alone, in that order, so two extensions injected with one seed differ
only by their effects.

`random_effect` draws one effect of the vocabulary with a realistic random magnitude
(`EFFECT_RANGES`); `random_effects` merges several. Units: metres, radians, seconds, pixels.

Modules: `settings` (`InjectionSettings`), `trajectory` (the joint motion), `world` (the true
world and the sequence written from it), `identifiability` (what a fixed camera can see),
`effects` (random effects).
"""

from dream.inject.effects import (
    CAMERA_MOVE_FRAME_FRACTION,
    CAMERA_MOVE_ROTATION_PROB,
    CAMERA_ROTATION_RANGE_RAD,
    CAMERA_TRANSLATION_RANGE_M,
    DISTORTION_K1_RANGE,
    EFFECT_RANGES,
    FOCAL_ERROR_RANGE,
    JOINT_OFFSET_RANGE_RAD,
    KEYPOINT_BIAS_RANGE_M,
    LINK_LENGTH_RANGE_M,
    TIME_OFFSET_RANGE_S,
    random_effect,
    random_effects,
)
from dream.inject.identifiability import (
    MIN_KEYPOINT_MOTION,
    MIN_NON_RIGID_FRACTION,
    PROBE_CONFIGS,
    PROBE_RANGE_FRACTION,
    PROBE_SEED,
    PROBE_STRETCH_M,
    identifiable_joints,
    moving_keypoints,
    rigid_motion_residual,
    stretchable_joints,
)
from dream.inject.settings import (
    MOTIONS,
    InjectionSettings,
)
from dream.inject.trajectory import (
    CENTRE_JITTER_FRACTION,
    COMPONENT_WEIGHT_RANGE,
    RELATIVE_FREQUENCY_RANGE,
    JointTrajectory,
    random_trajectory,
    trajectory_joints,
)
from dream.inject.world import (
    InjectedWorld,
    check_extension,
    frame_poses,
    inject,
    make_injected_sequence,
    noisy_labels,
    sequence_of,
)

__all__ = [
    "CAMERA_MOVE_FRAME_FRACTION",
    "CAMERA_MOVE_ROTATION_PROB",
    "CAMERA_ROTATION_RANGE_RAD",
    "CAMERA_TRANSLATION_RANGE_M",
    "DISTORTION_K1_RANGE",
    "EFFECT_RANGES",
    "FOCAL_ERROR_RANGE",
    "JOINT_OFFSET_RANGE_RAD",
    "KEYPOINT_BIAS_RANGE_M",
    "LINK_LENGTH_RANGE_M",
    "TIME_OFFSET_RANGE_S",
    "random_effect",
    "random_effects",
    "MIN_KEYPOINT_MOTION",
    "MIN_NON_RIGID_FRACTION",
    "PROBE_CONFIGS",
    "PROBE_RANGE_FRACTION",
    "PROBE_SEED",
    "PROBE_STRETCH_M",
    "identifiable_joints",
    "moving_keypoints",
    "rigid_motion_residual",
    "stretchable_joints",
    "MOTIONS",
    "InjectionSettings",
    "CENTRE_JITTER_FRACTION",
    "COMPONENT_WEIGHT_RANGE",
    "RELATIVE_FREQUENCY_RANGE",
    "JointTrajectory",
    "random_trajectory",
    "trajectory_joints",
    "InjectedWorld",
    "check_extension",
    "frame_poses",
    "inject",
    "make_injected_sequence",
    "noisy_labels",
    "sequence_of",
]
