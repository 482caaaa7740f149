"""One in-memory representation of a measured or synthetic sequence seen by one camera.

Readers of every supported layout (`dream.io`) produce a `Sequence`; the calibration, metrics and
CLI consume only this. Arrays are stored read-only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from dream.camera import CameraIntrinsics
from dream.errors import InputError
from dream.transforms import is_rigid


def _frozen_array(a: np.ndarray | None, shape: tuple[int, ...], what: str,
                  where: Path | None, allow_nan: bool) -> np.ndarray | None:
    if a is None:
        return None
    try:
        a = np.array(a, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{what} is not numeric ({exc})", where) from None
    if a.shape != shape:
        raise InputError(f"{what} has shape {a.shape}, expected {shape}", where)
    bad = np.isinf(a) if allow_nan else ~np.isfinite(a)
    if np.any(bad):
        raise InputError(f"{what} contains non-finite values", where,
                         "write finite numbers (metres, radians, pixels)")
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class Frame:
    """One observation: joint angles plus whatever the source has for that instant.

    Attributes:
        name: the frame's id, e.g. "000000".
        joints: (J,) joint positions, rad (or m), ordered as `Sequence.joint_names`.
        image_path: RGB image file, or an .npz holding an image stack (then `image_index`).
        image_index: index into the image stack of `image_path` when it is an .npz.
        mask_path: robot mask image (0 background, non-zero robot).
        timestamp: capture time, s.
        uv_labels: (K, 2) 2D keypoint labels in image pixels, NaN where absent; order
            `Sequence.keypoint_names`.
        P_cam_labels: (K, 3) keypoint positions in the camera frame, m, NaN where absent.
        T_cam_base_true: (4, 4) ground-truth extrinsic of this frame.
        camera: this frame's own intrinsics where the source gives them (a synthetic set with a
            random field of view per frame); None: the sequence's camera.
    """

    name: str
    joints: np.ndarray
    image_path: Path | None = None
    image_index: int | None = None
    mask_path: Path | None = None
    timestamp: float | None = None
    uv_labels: np.ndarray | None = None
    P_cam_labels: np.ndarray | None = None
    T_cam_base_true: np.ndarray | None = None
    source: Path | None = field(default=None, compare=False)
    camera: CameraIntrinsics | None = None

    def __post_init__(self) -> None:
        where = self.source
        joints = np.array(self.joints, dtype=float) if self.joints is not None else None
        if joints is None or joints.ndim != 1:
            raise InputError(f"frame {self.name}: joints must be a flat list of numbers", where)
        object.__setattr__(self, "joints", _frozen_array(joints, joints.shape,
                                                         f"frame {self.name} joints", where,
                                                         allow_nan=False))
        if self.uv_labels is not None:
            uv = np.asarray(self.uv_labels, dtype=float)
            object.__setattr__(self, "uv_labels", _frozen_array(
                uv, (uv.shape[0] if uv.ndim else -1, 2), f"frame {self.name} uv_labels", where,
                allow_nan=True))
        if self.P_cam_labels is not None:
            P = np.asarray(self.P_cam_labels, dtype=float)
            object.__setattr__(self, "P_cam_labels", _frozen_array(
                P, (P.shape[0] if P.ndim else -1, 3), f"frame {self.name} P_cam_labels", where,
                allow_nan=True))
        if self.T_cam_base_true is not None:
            T = _frozen_array(self.T_cam_base_true, (4, 4), f"frame {self.name} T_cam_base",
                              where, allow_nan=False)
            if not is_rigid(T, atol=1e-4):
                raise InputError(f"frame {self.name}: ground-truth pose is not a rigid transform",
                                 where, "write a unit quaternion_xyzw and a location in metres")
            object.__setattr__(self, "T_cam_base_true", T)
        if self.timestamp is not None and not np.isfinite(self.timestamp):
            raise InputError(f"frame {self.name}: timestamp is not finite", where)
        for name in ("image_path", "mask_path"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, Path(value))


@dataclass(frozen=True)
class Sequence:
    """Frames of one robot seen by one camera.

    Attributes:
        robot: a built-in robot name (`dream robots`) or a URDF path.
        camera: intrinsics shared by every frame (a frame's own `Frame.camera` replaces them).
        joint_names: names of `Frame.joints` entries, in order.
        keypoint_names: names of `Frame.uv_labels` / `P_cam_labels` rows, in order.
        frames: the frames, in capture order.
        T_cam_base_reference: a reference extrinsic for the whole sequence (fixed camera),
            e.g. from a target-based calibration; None when the source has none.
        source: where it was read from.
    """

    robot: str
    camera: CameraIntrinsics
    joint_names: tuple[str, ...]
    keypoint_names: tuple[str, ...]
    frames: tuple[Frame, ...]
    T_cam_base_reference: np.ndarray | None = None
    source: Path | None = field(default=None, compare=False)
    camera_name: str = "camera"

    def __post_init__(self) -> None:
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "keypoint_names", tuple(self.keypoint_names))
        object.__setattr__(self, "frames", tuple(self.frames))
        if not self.frames:
            raise InputError("the sequence has no frames", self.source,
                             "point --data at a folder with at least one frame")
        names = [f.name for f in self.frames]
        if len(set(names)) != len(names):
            raise InputError("two frames share one name", self.source)
        J, K = len(self.joint_names), len(self.keypoint_names)
        for f in self.frames:
            if f.joints.shape != (J,):
                raise InputError(f"frame {f.name} has {f.joints.shape[0]} joint values, expected "
                                 f"{J} ({', '.join(self.joint_names)})", f.source or self.source,
                                 "write one value per joint")
            for what, arr in (("uv_labels", f.uv_labels), ("P_cam_labels", f.P_cam_labels)):
                if arr is not None and arr.shape[0] != K:
                    raise InputError(f"frame {f.name} {what} has {arr.shape[0]} rows, expected "
                                     f"{K}", f.source or self.source)
            if f.camera is not None and (f.camera.width, f.camera.height) != (
                    self.camera.width, self.camera.height):
                raise InputError(f"frame {f.name} has its own intrinsics for a "
                                 f"{f.camera.width}x{f.camera.height} image, the sequence's "
                                 f"camera is {self.camera.width}x{self.camera.height}",
                                 f.source or self.source, "give every frame one image size")
        if self.T_cam_base_reference is not None:
            T = _frozen_array(self.T_cam_base_reference, (4, 4), "reference extrinsic",
                              self.source, allow_nan=False)
            if not is_rigid(T, atol=1e-4):
                raise InputError("reference extrinsic is not a rigid transform", self.source)
            object.__setattr__(self, "T_cam_base_reference", T)

    def __len__(self) -> int:
        return len(self.frames)

    def subset(self, keep: np.ndarray) -> Sequence:
        """The sequence of the frames where `keep` ((F,) bool) is True, in their order."""
        keep = np.asarray(keep)
        if keep.dtype != bool or keep.shape != (len(self.frames),):
            raise InputError(f"a frame subset must be ({len(self.frames)},) bool, got "
                             f"{keep.dtype} {keep.shape}", self.source)
        return replace(self, frames=tuple(f for f, k in zip(self.frames, keep, strict=True)
                                          if k))

    @property
    def joints(self) -> np.ndarray:
        """(F, J) joint positions of every frame."""
        return np.stack([f.joints for f in self.frames])

    def with_joints(self, joints: np.ndarray) -> Sequence:
        """The same frames with their joints replaced by `joints` ((F, J), ordered as
        `joint_names`): readings interpolated in time or shifted by a lag."""
        joints = np.asarray(joints, dtype=float)
        if joints.shape != (len(self.frames), len(self.joint_names)):
            raise InputError(f"joints of shape {joints.shape} for {len(self.frames)} frames of "
                             f"{len(self.joint_names)} joints", self.source)
        return replace(self, frames=tuple(replace(f, joints=q)
                                          for f, q in zip(self.frames, joints, strict=True)))

    @property
    def timestamps(self) -> np.ndarray | None:
        """(F,) every frame's capture time (s); None where some frame has none."""
        if any(f.timestamp is None for f in self.frames):
            return None
        return np.array([f.timestamp for f in self.frames], dtype=float)

    @property
    def increasing_timestamps(self) -> np.ndarray | None:
        """(F,) `timestamps` where there are at least two and they increase strictly; else
        None (nothing can be interpolated in time)."""
        t = self.timestamps
        return t if t is not None and len(t) >= 2 and np.all(np.diff(t) > 0) else None

    def frame_camera(self, index: int) -> CameraIntrinsics:
        """The intrinsics of frame `index`: its own, else the sequence's."""
        own = self.frames[index].camera
        return own if own is not None else self.camera

    @property
    def has_frame_cameras(self) -> bool:
        """Whether some frame's own intrinsics differ from the sequence's camera."""
        return any(f.camera is not None and f.camera != self.camera for f in self.frames)

    def fixed_camera(self, fix: str) -> CameraIntrinsics:
        """The one camera of every frame, for the analyses that assume a fixed camera.

        Raises:
            InputError: frames carry their own intrinsics (`fix` says what to do instead).
        """
        if self.has_frame_cameras:
            raise InputError("the frames have their own intrinsics (camera_intrinsics), so they "
                             "do not come from one fixed camera", self.source, fix)
        return self.camera

    def with_fixed_camera(self, camera: CameraIntrinsics) -> Sequence:
        """The same frames seen through `camera` alone (no frame keeps its own intrinsics): a
        fixed camera's intrinsics corrected, e.g. a focal length fitted to the images."""
        return replace(self, camera=camera, frames=tuple(replace(f, camera=None)
                                                          for f in self.frames))

    @property
    def has_labels(self) -> bool:
        return any(f.uv_labels is not None for f in self.frames)

    @property
    def has_images(self) -> bool:
        return any(f.image_path is not None for f in self.frames)

    @property
    def has_ground_truth(self) -> bool:
        return self.T_cam_base_reference is not None or any(
            f.T_cam_base_true is not None for f in self.frames)

    def T_cam_base_truth(self, frame: Frame) -> np.ndarray | None:
        """Ground-truth extrinsic of a frame: its own, else the sequence's reference."""
        return frame.T_cam_base_true if frame.T_cam_base_true is not None \
            else self.T_cam_base_reference

    def uv_labels(self) -> np.ndarray:
        """(F, K, 2) labels, NaN where a frame or keypoint has none."""
        out = np.full((len(self.frames), len(self.keypoint_names), 2), np.nan)
        for i, f in enumerate(self.frames):
            if f.uv_labels is not None:
                out[i] = f.uv_labels
        return out
