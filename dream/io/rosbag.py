"""ROS 1 and ROS 2 bags: images, joint states and the camera, read without a ROS install.

A ROS 1 `.bag` file or a ROS 2 bag folder (`metadata.yaml` with `.db3` or `.mcap` files) is read
with the `rosbags` library (the `ros` extra). Three topics are used:

- images: `sensor_msgs/Image` (rgb8, bgr8, rgba8, bgra8, mono8) or `sensor_msgs/CompressedImage`;
- joints: `sensor_msgs/JointState`; each image takes the message nearest to it in time, and an
  image with none within `MAX_JOINT_GAP_S` is left out (said in the log);
- camera (optional): `sensor_msgs/CameraInfo`, its first message; else `--intrinsics` or
  `--camera-info`.

A topic not named (`BagTopics`) is found by its type when the bag has exactly one topic of it.
Times are the messages' header stamps (the bag's receive time where a stamp is zero). The
images are decoded once into an image stack (`.npz`) in the cache (`$DREAM_CACHE_DIR/bags` or
`~/.cache/dream/bags`), keyed by the bag's files and the topics; later reads of the same bag
use that stack instead of decoding the images again.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from dream.errors import InputError
from dream.io import fields
from dream.io.atomic import write_bytes_atomic
from dream.io.common import (
    CACHE_ENV,
    PANDA_ROBOT,
    cache_folder,
    check_joint_names,
    check_robot,
    frame_name,
)
from dream.io.images import STACK_KEY
from dream.io.intrinsics import IntrinsicsArg, camera_from_argument, camera_from_K
from dream.io.npz import read_header
from dream.sequence import Frame, Sequence

logger = logging.getLogger(__name__)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
JOINT_STATE = "sensor_msgs/msg/JointState"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
ROS1_SUFFIX = ".bag"
ROS2_METADATA = "metadata.yaml"
ROS2_FILES = (".db3", ".mcap")
MAX_JOINT_GAP_S = 0.1    # an image farther than this from every joint message is left out
NS_PER_S = 10 ** 9
BAGS_FOLDER = "bags"
FIX_ROSBAGS = "pip install rosbags (or the project's 'ros' extra: pip install -e '.[ros]')"
CHANNEL_ORDER = {"rgb8": None, "bgr8": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_RGBA2RGB,
                 "bgra8": cv2.COLOR_BGRA2RGB, "mono8": cv2.COLOR_GRAY2RGB}


@dataclass(frozen=True)
class BagTopics:
    """The topics of a bag to read; None: the one topic of that message type."""

    image: str | None = None
    joints: str | None = None
    camera_info: str | None = None


def is_bag(path: Path) -> bool:
    """A ROS 1 bag file, a ROS 2 bag folder, or a ROS 2 bag's storage file."""
    if path.is_file():
        return path.suffix == ROS1_SUFFIX or (path.suffix in ROS2_FILES and
                                               (path.parent / ROS2_METADATA).is_file())
    return (path / ROS2_METADATA).is_file()


def _bag_path(path: Path) -> Path:
    return path.parent if path.is_file() and path.suffix in ROS2_FILES else path


def _stamp_s(msg: Any, received_ns: int) -> float:
    """The header stamp in seconds, correctly rounded (the receive time when it is zero)."""
    stamp = msg.header.stamp
    ns = int(stamp.sec) * NS_PER_S + int(stamp.nanosec)
    return float(Fraction(ns if ns > 0 else received_ns, NS_PER_S))


def _pick(connections, wanted: str | None, types: tuple[str, ...], what: str, path: Path,
          option: str, required: bool = True):
    if wanted is not None:
        found = [c for c in connections if c.topic == wanted]
        if not found:
            topics = ", ".join(sorted({c.topic for c in connections}))
            raise InputError(f"has no topic {wanted}; its topics: {topics}", path,
                             f"give {option} one of them")
        if found[0].msgtype not in types:
            raise InputError(f"topic {wanted} holds {found[0].msgtype}, not {what}", path,
                             f"give {option} a topic of {' or '.join(types)}")
        return found
    candidates = sorted({c.topic for c in connections if c.msgtype in types})
    if len(candidates) == 1:
        return [c for c in connections if c.topic == candidates[0]]
    if not candidates and not required:
        return []
    listing = ", ".join(candidates) if candidates else "none"
    raise InputError(f"has {len(candidates)} topics of {what} ({listing})", path,
                     f"name the one to use with {option}")


def _rgb(msg: Any, msgtype: str, path: Path) -> np.ndarray:
    if msgtype == COMPRESSED:
        bgr = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise InputError(f"a CompressedImage ({msg.format}) cannot be decoded", path,
                             "record jpeg or png compressed images")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    if msg.encoding not in CHANNEL_ORDER:
        raise InputError(f"image encoding {msg.encoding!r} is not supported (only "
                         f"{', '.join(CHANNEL_ORDER)})", path, "record 8-bit colour images")
    channels = 1 if msg.encoding == "mono8" else (4 if msg.encoding.endswith("a8") else 3)
    rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)
    image = np.ascontiguousarray(rows[:, :msg.width * channels].reshape(
        msg.height, msg.width, channels) if channels > 1 else rows[:, :msg.width])
    code = CHANNEL_ORDER[msg.encoding]
    return image if code is None else cv2.cvtColor(image, code)


def _field(msg: Any, ros2: str, ros1: str) -> Any:
    """A CameraInfo field: ROS 2 names it in lower case (k, d), ROS 1 in upper case (K, D)."""
    return getattr(msg, ros2) if hasattr(msg, ros2) else getattr(msg, ros1)


def _camera_info(msg: Any, path: Path):
    distortion = [float(v) for v in _field(msg, "d", "D")]
    if not any(distortion):
        distortion = None
    elif msg.distortion_model != "plumb_bob" or len(distortion) not in (4, 5):
        raise InputError(f"CameraInfo distortion {msg.distortion_model} with {len(distortion)} "
                         "coefficients is not supported (only plumb_bob)", path,
                         "give --intrinsics and --distortion, or --camera-info FILE")
    elif len(distortion) == 4:
        distortion = distortion + [0.0]
    return camera_from_K(np.asarray(_field(msg, "k", "K"), float).reshape(3, 3), int(msg.width),
                         int(msg.height), path, None if distortion is None else
                         tuple(distortion))


def _span(times) -> str:
    """A stamp range in words: its first and last value and how long it lasts."""
    times = np.asarray(times, float)
    return f"{times.min():.3f}..{times.max():.3f} s ({np.ptp(times):.2f} s)"


def _stamp_spans(image_t, joint_t) -> str:
    """Why no image found a joint state, in words: both stamp spans, and how far apart they lie
    where they do not overlap, else the longest wait between two joint states."""
    image_t, joint_t = np.sort(np.asarray(image_t, float)), np.sort(np.asarray(joint_t, float))
    spans = f"the images span {_span(image_t)}, the joint states {_span(joint_t)}"
    if image_t[-1] < joint_t[0] or joint_t[-1] < image_t[0]:
        ahead = float(np.median(joint_t) - np.median(image_t))
        return (f"{spans}: the images' median lies {abs(ahead):.3f} s "
                f"{'before' if ahead > 0 else 'after'} the joint states' (two clocks?)")
    gap = float(np.diff(joint_t).max()) if len(joint_t) > 1 else 0.0
    return f"{spans}; the joint states are up to {gap:.3f} s apart"


def _cache_file(bag: Path, topics: tuple[str, str]) -> Path:
    digest = hashlib.sha256("|".join(topics).encode())
    files = [bag] if bag.is_file() else sorted(p for p in bag.iterdir() if p.is_file())
    for f in files:
        stat = f.stat()
        digest.update(f"{f.resolve()}:{stat.st_size}:{stat.st_mtime_ns}".encode())
    return cache_folder(BAGS_FOLDER) / f"{digest.hexdigest()[:32]}.npz"


def _cached_stack(stack: Path, count: int) -> tuple[int, int] | None:
    """(height, width) of a cached image stack of `count` images, None where there is none
    (or an unreadable or stale one, which is decoded again)."""
    if not stack.is_file():
        return None
    try:
        header = read_header(stack, STACK_KEY)
    except InputError:
        return None
    shape = tuple(header.shape)
    return (shape[1], shape[2]) if len(shape) == 4 and shape[0] == count else None


def _write_stack(images: list[np.ndarray], target: Path, path: Path) -> None:
    import io

    if len({im.shape for im in images}) > 1:
        raise InputError("the image topic holds images of several sizes", path,
                         "record one resolution")
    buffer = io.BytesIO()
    np.savez(buffer, **{STACK_KEY: np.stack(images)})
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(target, buffer.getvalue())
    except OSError as exc:
        raise InputError(f"cannot cache the bag's images ({fields.os_reason(exc)})",
                         target.parent, f"set {CACHE_ENV} to a writable folder") from None


def _read_messages(path: Path, topics: BagTopics, reuse: bool = True):
    """(image times, RGB images, joint times, joint names, joint positions, CameraInfo or
    None, the image and joint topics). With `reuse`, where the images' stack is already in the
    cache, the images are not decoded (None each)."""
    try:
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise InputError("reading ROS bags needs the rosbags package", path,
                         FIX_ROSBAGS) from None
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            conns = reader.connections
            image_c = _pick(conns, topics.image, (IMAGE, COMPRESSED), "images", path,
                            "--image-topic")
            joint_c = _pick(conns, topics.joints, (JOINT_STATE,), "joint states", path,
                            "--joint-topic")
            info_c = _pick(conns, topics.camera_info, (CAMERA_INFO,), "camera infos", path,
                           "--camera-info-topic", required=topics.camera_info is not None)
            used = (image_c[0].topic, joint_c[0].topic)
            decode = not (reuse and _cache_file(path, used).is_file())
            image_t, images, joint_t, joint_names, positions, info = [], [], [], None, [], None
            for conn, received, raw in reader.messages(connections=image_c + joint_c + info_c):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn in info_c:
                    info = info if info is not None else msg
                elif conn in image_c:
                    image_t.append(_stamp_s(msg, received))
                    images.append(_rgb(msg, conn.msgtype, path) if decode else None)
                else:
                    joint_t.append(_stamp_s(msg, received))
                    joint_names = joint_names or tuple(msg.name)
                    if tuple(msg.name) != joint_names:
                        raise InputError(f"the joint states change their names at "
                                         f"{joint_t[-1]:.3f} s", path,
                                         "record one joint state topic of fixed names")
                    positions.append(np.asarray(msg.position, dtype=float))
    except (AnyReaderError, OSError, KeyError) as exc:
        raise InputError(f"cannot read the bag ({fields.one_line(exc)})", path,
                         "give a ROS 1 .bag file or a ROS 2 bag folder") from None
    return image_t, images, joint_t, joint_names, positions, info, used


def read_rosbag(path: str | Path, *, joint_names: SequenceOf[str] | None = None,
                intrinsics: IntrinsicsArg | None = None, robot: str | None = None,
                topics: BagTopics | None = None) -> Sequence:
    """Read a bag (module doc) into a `Sequence`, frames in image time order.

    Args:
        path: a ROS 1 `.bag` file or a ROS 2 bag folder (or one of its storage files).
        joint_names: the joints to keep, in this order; default every joint of the messages.
        intrinsics: the camera, replacing the CameraInfo topic's.
        robot: robot name; default "panda".
        topics: the topics; default: found by type.
    """
    path = _bag_path(Path(path))
    topics = topics or BagTopics()
    image_t, images, joint_t, names, positions, info, used = _read_messages(path, topics)
    if not images or not joint_t:
        raise InputError(f"holds {len(images)} images and {len(joint_t)} joint states", path,
                         "record both the image and the joint state topics")
    keep = check_joint_names(joint_names, names)
    missing = [n for n in keep if n not in names]
    if missing:
        raise InputError(f"the joint states have no joints {', '.join(missing)}", path,
                         f"choose among {', '.join(names)}")
    q = np.stack(positions)[:, [names.index(n) for n in keep]]
    order = np.argsort(joint_t, kind="stable")
    joint_t, q = np.asarray(joint_t)[order], q[order]
    pairs = []   # (image, its nearest joint state), images in time order
    for i in np.argsort(image_t, kind="stable"):
        j = int(np.argmin(np.abs(joint_t - image_t[i])))
        if abs(joint_t[j] - image_t[i]) <= MAX_JOINT_GAP_S:
            pairs.append((int(i), j))
    if len(pairs) < len(images):
        logger.warning("%s: %d of %d images have no joint state within %.2f s and are left out",
                       path, len(images) - len(pairs), len(images), MAX_JOINT_GAP_S)
    if not pairs:
        raise InputError(f"no image has a joint state within {MAX_JOINT_GAP_S} s: "
                         f"{_stamp_spans(image_t, joint_t)}", path, "record the joint states "
                         "with the images, stamped by one clock (a camera's own clock, sim "
                         "time or a zero header stamp, which falls back to the receive time, "
                         "gives another)")
    stack = _cache_file(path, used)
    size = _cached_stack(stack, len(pairs)) if images[0] is None else None
    if images[0] is None and size is None:   # a stale stack: decode the images again
        images = _read_messages(path, topics, reuse=False)[1]
    if images[0] is not None:
        _write_stack([images[i] for i, _ in pairs], stack, path)
        size = images[0].shape[:2]
    height, width = size
    if intrinsics is not None:
        camera = camera_from_argument(intrinsics, width, height, path)
    elif info is not None:
        camera = camera_from_argument(_camera_info(info, path), width, height, path)
    else:
        raise InputError("has no CameraInfo topic", path, "name one with --camera-info-topic, "
                         "or give --camera-info FILE or --intrinsics fx,fy,cx,cy")
    frames = [Frame(name=frame_name(k), joints=q[j], image_path=stack, image_index=k,
                    timestamp=image_t[i], source=path) for k, (i, j) in enumerate(pairs)]
    logger.info("read %d frames of %s and %s from %s", len(frames), *used, path)
    return Sequence(robot=check_robot(robot, PANDA_ROBOT), camera=camera, joint_names=keep,
                    keypoint_names=(), frames=tuple(frames), source=path)
