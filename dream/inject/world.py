"""The true world of an injected sequence and the measured-like sequence written from it."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from dream.camera import CameraIntrinsics, project
from dream.errors import InputError
from dream.extended import extended_camera, extended_points, frames_after_move
from dream.extension import ModelExtension
from dream.inject.settings import InjectionSettings
from dream.inject.trajectory import JointTrajectory, random_trajectory, trajectory_joints
from dream.readings import held_update_times
from dream.robot import Robot, load_robot
from dream.sample import random_camera_pose, random_joints
from dream.sequence import Frame, Sequence
from dream.transforms import transform_points


@dataclass(frozen=True, eq=False)
class InjectedWorld:
    """The true world behind an injected sequence and what is written from it.

    Attributes:
        spec, extension: what was asked.
        robot: the nominal robot.
        camera_nominal: written camera; camera_true: the camera the labels are projected with.
        times_s: (F,) image times, s.
        joints_at_images: (F, J) the reading signal at the image times (what
            `effective_joints(readings, times_s, tau)` should recover), rad.
        readings: (F, J) the written joint readings (lagging by the time offset, held between
            updates with held readings), rad.
        T_cam_base: (F, 4, 4) the true extrinsic of each frame.
        P_base: (F, K, 3) the true keypoints in the base frame, m.
        uv_true: (F, K, 2) their noise-free projections through the true camera, px.
        uv_labels: (F, K, 2) the written labels: noisy, NaN outside the image, px.
        trajectory: the motion when `spec.motion == "trajectory"`, else None.
    """

    spec: InjectionSettings
    extension: ModelExtension
    robot: Robot
    camera_nominal: CameraIntrinsics
    camera_true: CameraIntrinsics
    times_s: np.ndarray
    joints_at_images: np.ndarray
    readings: np.ndarray
    T_cam_base: np.ndarray
    P_base: np.ndarray
    uv_true: np.ndarray
    uv_labels: np.ndarray
    trajectory: JointTrajectory | None


def check_extension(spec: InjectionSettings, robot: Robot, extension: ModelExtension) -> None:
    """Refuse an extension this spec cannot inject (InputError)."""
    if not isinstance(extension, ModelExtension):
        raise InputError("extension must be a dream.extension.ModelExtension",
                         fix="use ModelExtension() for the nominal world")
    if extension.robot and extension.robot != robot.name:
        raise InputError(f"the extension is for robot '{extension.robot}', the settings' robot is "
                         f"'{robot.name}'", fix="inject an extension of this robot")
    if (extension.time_offset_s or extension.held_readings) and spec.motion != "trajectory":
        raise InputError("a time offset or held readings need a continuous motion",
                         fix="use motion='trajectory' to inject time_offset or held_readings")


HELD_STREAM = 0x4E1D   # spawn key of the held log's update phase (other draws unchanged)


def held_readings_of(trajectory: JointTrajectory, times_s: np.ndarray, tau: float,
                     extension: ModelExtension, robot: Robot, seed: int) -> np.ndarray:
    """(F, J) the readings a held log writes: the held joints sampled at their last update
    (lagging by `tau`), the others at the image times (lagging by `tau`)."""
    held = extension.held_readings
    readings = trajectory_joints(trajectory, times_s - tau)
    phase = np.random.default_rng([seed, HELD_STREAM]).uniform(0.0, held.period_s)
    updates = held_update_times(times_s, held.period_s, phase)
    sampled = trajectory_joints(trajectory, updates - tau)
    columns = held.columns(robot.joint_names)
    readings[:, columns] = sampled[:, columns]
    return readings


def frame_poses(T_cam_base_before: np.ndarray, after: np.ndarray,
                extension: ModelExtension) -> np.ndarray:
    """(F, 4, 4) true extrinsic per frame: dT @ T from the camera move on (`after`), else T.

    Args:
        T_cam_base_before: (4, 4) extrinsic before the move. after: (F,) bool.
    """
    T = np.asarray(T_cam_base_before, dtype=float)
    after = np.asarray(after, dtype=bool)
    if T.shape != (4, 4) or after.ndim != 1:
        raise InputError(f"frame_poses needs T (4, 4) and after (F,), got {T.shape}, "
                         f"{after.shape}")
    poses = np.broadcast_to(T, (len(after), 4, 4)).copy()
    if extension.camera_moved is not None:
        poses[after] = extension.camera_moved.T_after_before @ T
    return poses


def noisy_labels(uv_true: np.ndarray, noise_px: np.ndarray,
                 camera: CameraIntrinsics) -> np.ndarray:
    """(F, K, 2) labels: projections plus noise, NaN where outside the image (or behind)."""
    uv = np.asarray(uv_true, dtype=float) + np.asarray(noise_px, dtype=float)
    if uv.shape[-1:] != (2,):
        raise InputError(f"labels must be (..., 2), got shape {uv.shape}")
    inside = camera.in_image(uv) & np.all(np.isfinite(uv), -1)
    return np.where(inside[..., None], uv, np.nan)


def inject(spec: InjectionSettings, extension: ModelExtension | None = None) -> InjectedWorld:
    """The true world of `spec` changed by `extension` (None: nominal), deterministic in
    `spec.seed` (camera, then motion, then noise, whatever the extension)."""
    extension = ModelExtension() if extension is None else extension
    robot = load_robot(spec.robot)
    check_extension(spec, robot, extension)
    rng = np.random.default_rng(spec.seed)
    T_before = random_camera_pose(rng, spec.sample_settings())
    times = spec.times_s
    tau = extension.time_offset_s or 0.0
    trajectory = None
    if spec.motion == "trajectory":
        trajectory = random_trajectory(rng, robot, spec)
        joints_at_images = trajectory_joints(trajectory, times)
        readings = trajectory_joints(trajectory, times - tau)
        if extension.held_readings is not None:
            readings = held_readings_of(trajectory, times, tau, extension, robot, spec.seed)
    else:
        joints_at_images = random_joints(rng, robot, spec.num_frames, spec.joint_range_fraction)
        readings = joints_at_images
    noise = rng.normal(0.0, spec.pixel_noise_px, (spec.num_frames, robot.num_keypoints, 2))
    # joints already at the images: no lag, no holding
    kinematic = dataclasses.replace(extension, time_offset_s=None, held_readings=None)
    P_base = extended_points(robot, joints_at_images, times, kinematic)
    T_cam_base = frame_poses(T_before, frames_after_move(spec.frame_names, extension), extension)
    camera_true = extended_camera(spec.camera, extension)
    uv_true = project(camera_true, transform_points(T_cam_base[:, None], P_base))
    return InjectedWorld(spec, extension, robot, spec.camera, camera_true, times,
                         joints_at_images, readings, T_cam_base, P_base, uv_true,
                         noisy_labels(uv_true, noise, camera_true), trajectory)


def sequence_of(world: InjectedWorld) -> Sequence:
    """What a user would log from the world: readings, labels, nominal camera, image times."""
    frames = tuple(
        Frame(name=name, joints=world.readings[i], timestamp=float(world.times_s[i]),
              uv_labels=world.uv_labels[i], T_cam_base_true=world.T_cam_base[i])
        for i, name in enumerate(world.spec.frame_names))
    return Sequence(robot=world.robot.name, camera=world.camera_nominal,
                    joint_names=world.robot.joint_names,
                    keypoint_names=world.robot.keypoint_names, frames=frames,
                    T_cam_base_reference=None)


def make_injected_sequence(spec: InjectionSettings,
                           extension: ModelExtension | None = None) -> Sequence:
    """A measured-like keypoint-only sequence of the world `extension` describes (module doc).

    Write it with `dream.io.write_dream(sequence, folder)`."""
    return sequence_of(inject(spec, extension))
