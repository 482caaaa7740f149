"""Plausibility of the inputs before solving: the mistakes that look like valid data.

Joint readings in degrees, a focal length in millimetres, a principal point from another
resolution, a distortion coefficient off by orders of magnitude: each still gives a solution,
with a small reprojection error and an extrinsic metres off. These checks refuse such input with
one line naming the value and the likely fix.

    >>> import numpy as np
    >>> from dream.camera import CameraIntrinsics
    >>> check_camera(CameraIntrinsics(4.0, 4.0, 319.5, 239.5, 640, 480))
    Traceback (most recent call last):
    ...
    dream.errors.InputError: fx = 4 px gives a 178.6 deg horizontal field of view on 640 px wide \
images; is the focal length in millimetres? Fix: give fx and fy in pixels (the focal length \
in mm divided by the pixel pitch in mm), as ROS CameraInfo's K does
"""

from __future__ import annotations

import logging
from collections.abc import Sequence as SequenceOf
from pathlib import Path

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError

logger = logging.getLogger(__name__)

JOINT_LIMIT_MARGIN_RAD = 0.1     # readings this far beyond a revolute limit are refused
JOINT_LIMIT_MARGIN_M = 0.01      # ... and this far beyond a prismatic one
MILLIMETRES_PER_METRE = 1000.0
MAX_PRINCIPAL_OFFSET = 0.25      # the principal point lies within this share of the size
                                 # from the image's centre (the middle half of each axis)
SWAPPED_TOLERANCE_PX = 1.0       # cx, cy this near the other axis's centre look swapped
MAX_TIMESTAMP_S = 1e11           # seconds since 1970 reach this in the year 5138
MAX_FRAME_STEP_S = 3600.0        # a recording's frames lie less than an hour apart
MS_FRAME_STEP_S = (5.0, 1000.0)  # a camera's frame interval at 1-200 frames/s, in ms, read as s
STEADY_STEP_SPREAD = 0.05        # steps whose median deviation is within this share: a frame rate
MIN_HFOV_DEG = 2.0               # a pinhole camera's horizontal field of view, plausible range
MAX_HFOV_DEG = 160.0
MAX_FOCAL_ASPECT = 1.5           # fx / fy (or fy / fx): pixels are nearly square
MAX_RADIAL_SCALE_CHANGE = 0.5    # distortion may scale a radius by 0.5-1.5 inside the image
RADIAL_SAMPLES = 64              # radii checked from the centre to the farthest corner


def check_joint_readings(joints: np.ndarray, joint_names: SequenceOf[str], lower: np.ndarray,
                         upper: np.ndarray, prismatic: np.ndarray,
                         frame_names: SequenceOf[str], where: Path | None = None) -> None:
    """Refuse readings (N, J) beyond the limits (J,) by more than the margin; `prismatic` (J,)
    bool picks metres over radians. Continuous joints have infinite limits and pass.

    Raises:
        InputError: the first reading out of bounds, with the frame, the joint, its limits and
            "are these degrees?" (or millimetres), or, where the joint's readings in those
            units would be out of bounds too, whether the columns are in another order.
    """
    joints = np.atleast_2d(np.asarray(joints, dtype=float))
    margin = np.where(prismatic, JOINT_LIMIT_MARGIN_M, JOINT_LIMIT_MARGIN_RAD)
    below, above = joints < lower - margin, joints > upper + margin
    bad = np.argwhere(below | above)
    if not len(bad):
        return
    i, j = (int(k) for k in bad[0])
    value, name = joints[i, j], joint_names[j]
    count = len(np.unique(bad[:, 0]))
    if prismatic[j]:
        unit, units, fix = "m", "millimetres", "give prismatic joints in metres"
        as_base, shown = joints[:, j] / MILLIMETRES_PER_METRE, ""
    else:
        unit, units, fix = "rad", "degrees", "give joint readings in radians (degrees x pi / 180)"
        as_base = np.deg2rad(joints[:, j])
        shown = f" ({value:g} deg = {np.deg2rad(value):.3f} rad)"
    column = "another joint's column (the columns in another order), or another robot's readings"
    order = f"check that the readings are in the robot's joint order ({', '.join(joint_names)})"
    if np.any(as_base < lower[j] - margin[j]) or np.any(as_base > upper[j] + margin[j]):
        guess, fix = f"not in {units} either: is it {column}?", \
            f"{order} and of the robot the data names (--robot)"
    else:
        fix = f"{fix}, and {order}"
        small = np.nanmax(np.abs(joints[:, j])) <= max(abs(lower[j]), abs(upper[j])) + margin[j]
        guess = (f"are these {units}{shown}, or {column}?" if small    # either could be it
                 else f"are these {units}?{shown}")
    raise InputError(f"frame {frame_names[i]}: joint {name} = {value:g} lies outside its URDF "
                     f"limits [{lower[j]:.3f}, {upper[j]:.3f}] {unit} ({count} of {len(joints)} "
                     f"frames are out of bounds); {guess}", where, fix)


def check_robot_readings(seq, robot) -> None:
    """`check_joint_readings` for a `Sequence` of `robot` (its joints taken by name)."""
    from dream.pipeline import joints_in_robot_order
    from dream.robot.tree import PRISMATIC

    prismatic = np.array([robot.tree.joints[robot.tree.joint_index[n]].type == PRISMATIC
                          for n in robot.joint_names])
    lower, upper = _finite_limits(robot)
    check_joint_readings(joints_in_robot_order(seq, robot), robot.joint_names, lower, upper,
                         prismatic, [f.name for f in seq.frames], seq.source)


def check_robot_joints(robot, joints: np.ndarray, names: SequenceOf[str]) -> None:
    """`check_joint_readings` for joint vectors (N, J) of `robot` in its joint order, named
    `names` in the message (e.g. "--start")."""
    from dream.robot.tree import PRISMATIC

    prismatic = np.array([robot.tree.joints[robot.tree.joint_index[n]].type == PRISMATIC
                          for n in robot.joint_names])
    lower, upper = _finite_limits(robot)
    check_joint_readings(joints, robot.joint_names, lower, upper, prismatic, names)


def _finite_limits(robot) -> tuple[np.ndarray, np.ndarray]:
    """The robot's limits with continuous joints unbounded."""
    from dream.robot.tree import CONTINUOUS

    continuous = np.array([robot.tree.joints[robot.tree.joint_index[n]].type == CONTINUOUS
                           for n in robot.joint_names])
    return (np.where(continuous, -np.inf, robot.joint_lower),
            np.where(continuous, np.inf, robot.joint_upper))


def check_camera(camera: CameraIntrinsics, where: Path | None = None) -> None:
    """Refuse intrinsics that cannot belong to the images: a principal point outside their
    middle half (`MAX_PRINCIPAL_OFFSET`) or at the centre of images of swapped width and
    height, a field of view outside [`MIN_HFOV_DEG`, `MAX_HFOV_DEG`], fx and fy far apart,
    distortion that folds or scales radii by more than `MAX_RADIAL_SCALE_CHANGE` inside the
    image."""
    w, h = camera.width, camera.height
    for name, value, size, side in (("cx", camera.cx, w, "wide"), ("cy", camera.cy, h, "high")):
        if not -0.5 <= value <= size - 0.5:
            raise InputError(f"{name} = {value:g} px lies outside the {size} px {side} images",
                             where, "give the principal point in pixels of these images (for "
                             "a resized image, scale fx, fy, cx and cy by the same factor)")
        if abs(value - (size - 1) / 2) > MAX_PRINCIPAL_OFFSET * size:
            raise InputError(f"{name} = {value:g} px lies far from the centre of the {size} px "
                             f"{side} images ({(size - 1) / 2:g}); is it normalised, or for "
                             "another resolution?", where, "give the principal point in pixels "
                             "of these images (for a resized image, scale fx, fy, cx and cy by "
                             "the same factor)")
    if _looks_swapped(camera):
        raise InputError(f"cx = {camera.cx:g}, cy = {camera.cy:g} px are the centre of "
                         f"{h}x{w} images, these are {w}x{h}: are cx and cy (or the width and "
                         "height) swapped?", where, "give cx along the image's width and cy "
                         "along its height, in pixels")
    hfov = np.rad2deg(2 * np.arctan(w / 2 / camera.fx))
    if not MIN_HFOV_DEG <= hfov <= MAX_HFOV_DEG:
        guess = "is the focal length in millimetres?" if hfov > MAX_HFOV_DEG else \
            "is it for a larger image?"
        raise InputError(f"fx = {camera.fx:g} px gives a {hfov:.1f} deg horizontal field of view "
                         f"on {w} px wide images; {guess}", where,
                         "give fx and fy in pixels (the focal length in mm divided by the pixel "
                         "pitch in mm), as ROS CameraInfo's K does")
    aspect = camera.fx / camera.fy
    if not 1 / MAX_FOCAL_ASPECT <= aspect <= MAX_FOCAL_ASPECT:
        raise InputError(f"fx = {camera.fx:g} and fy = {camera.fy:g} px differ by a factor "
                         f"{max(aspect, 1 / aspect):.2f}; camera pixels are nearly square",
                         where, "check fx and fy (and their order: fx, fy, cx, cy)")
    if camera.distortion is not None:
        _check_distortion(camera, where)


def _looks_swapped(camera: CameraIntrinsics) -> bool:
    """Whether the principal point is the centre of an image of swapped width and height."""
    w, h = camera.width, camera.height

    def centred(value: float, size: int) -> bool:
        return any(abs(value - c) <= SWAPPED_TOLERANCE_PX for c in ((size - 1) / 2, size / 2))

    return w != h and centred(camera.cx, h) and centred(camera.cy, w)


def _check_distortion(camera: CameraIntrinsics, where: Path | None) -> None:
    k1, k2, _, _, k3 = camera.distortion
    corners = np.array([[0, 0], [camera.width - 1, 0], [0, camera.height - 1],
                        [camera.width - 1, camera.height - 1]], dtype=float)
    x = (corners[:, 0] - camera.cx) / camera.fx
    y = (corners[:, 1] - camera.cy) / camera.fy
    r = np.linspace(0.0, float(np.hypot(x, y).max()), RADIAL_SAMPLES)
    scale = 1 + k1 * r ** 2 + k2 * r ** 4 + k3 * r ** 6
    folds = np.any(np.diff(r * scale) <= 0)
    if folds or np.max(np.abs(scale - 1)) > MAX_RADIAL_SCALE_CHANGE:
        what = "folds the image over" if folds else \
            f"scales radii by {scale[np.argmax(np.abs(scale - 1))]:.2f} at the image corner"
        raise InputError(f"distortion (k1 {k1:g}, k2 {k2:g}, k3 {k3:g}) {what}; a lens "
                         "model from another camera or resolution?", where,
                         "give plumb_bob coefficients (k1, k2, p1, p2, k3) for normalised "
                         "image coordinates, as OpenCV and ROS CameraInfo's D do")


def check_sequence_cameras(seq) -> None:
    """`check_camera` for the sequence's camera and every frame's own."""
    seen = {seq.camera}
    check_camera(seq.camera, seq.source)
    for frame in seq.frames:
        if frame.camera is not None and frame.camera not in seen:
            seen.add(frame.camera)
            check_camera(frame.camera, frame.source or seq.source)


def check_seconds(times: SequenceOf[float], path: Path | None) -> None:
    """Refuse timestamps that cannot be seconds: beyond `MAX_TIMESTAMP_S`, or frames more
    than `MAX_FRAME_STEP_S` apart (median), as milli-, micro- or nanoseconds are; warn of
    frames a steady 5-1000 s apart (a video's frame interval in milliseconds, from 0).

    >>> check_seconds([1.7e9, 1.7e9 + 0.033], Path("joints.csv"))
    >>> check_seconds([0, 33_333_333, 66_666_666], Path("joints.csv"))
    Traceback (most recent call last):
    ...
    dream.errors.InputError: joints.csv: timestamps lie 3.33333e+07 s apart (median) and reach \
6.66667e+07 s: they are not seconds. Fix: give the timestamps in seconds (nanoseconds divided \
by 1e9, microseconds by 1e6, milliseconds by 1e3)
    """
    t = np.sort(np.asarray(times, float))
    steps = np.diff(t)
    step = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    if step > MAX_FRAME_STEP_S or np.abs(t).max() > MAX_TIMESTAMP_S:
        raise InputError(f"timestamps lie {step:g} s apart (median) and reach "
                         f"{np.abs(t).max():g} s: they are not seconds", path,
                         "give the timestamps in seconds (nanoseconds divided by 1e9, "
                         "microseconds by 1e6, milliseconds by 1e3)")
    if MS_FRAME_STEP_S[0] <= step <= MS_FRAME_STEP_S[1] and \
            np.median(np.abs(steps - step)) <= STEADY_STEP_SPREAD * step:
        logger.warning("%s: the frames lie a steady %.4g s apart (%.3g frames an hour): a "
                       "camera's frame interval in milliseconds? Give the timestamps in seconds "
                       "(milliseconds divided by 1e3); read as seconds, a joint log's lag "
                       "behind the images is not found", path or "timestamps", step,
                       3600.0 / step)


def check_sequence_times(seq) -> None:
    """`check_seconds` of the frames' timestamps, where they have any."""
    times = [f.timestamp for f in seq.frames if f.timestamp is not None]
    if times:
        check_seconds(times, seq.source)
