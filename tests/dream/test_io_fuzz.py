"""Fuzzing of every reader: damaged input may only ever raise a `DreamError`.

Each example builds a small valid data set in its own temporary folder, damages one file (JSON
values of random types, missing keys, NaN literals, random or truncated bytes, random arrays in an
.npz) and then reads it, loads every image and mask, and writes it back out.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from dream.camera import CameraIntrinsics
from dream.errors import DreamError, InputError
from dream.io import load_image, load_mask_ids, read_sequence, write_dream
from dream.sequence import Frame, Sequence
from dream.transforms import T_from_rotvec_t

WIDTH, HEIGHT = 8, 6
EXAMPLES = int(os.environ.get("DREAM_FUZZ_EXAMPLES", "60"))  # raise for a deeper search
FUZZ = settings(max_examples=EXAMPLES, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
ROUND_TRIP = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])

JSON_LEAVES = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=6),
    st.sampled_from([0, 1, -1, 0.5, 1e308, 1e-320, "", "panda", "000000.rgb.png"]))
JSON_VALUES = st.recursive(
    JSON_LEAVES,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner,
                                                                max_size=4),
    max_leaves=8)


# ----------------------------------------------------------------------------- builders


def _rgb(rng: np.random.Generator) -> np.ndarray:
    return rng.integers(0, 256, size=(HEIGHT, WIDTH, 3), dtype=np.uint8)


def build_dream(root: Path) -> Path:
    rng = np.random.default_rng(0)
    cv2.imwrite(str(root / "a.png"), _rgb(rng))
    cv2.imwrite(str(root / "b.jpg"), _rgb(rng))
    cv2.imwrite(str(root / "m.png"), rng.integers(0, 3, size=(HEIGHT, WIDTH), dtype=np.uint8))
    frames = [Frame(name=f"{i:06d}", joints=rng.normal(size=2),
                    image_path=root / ("a.png" if i == 0 else "b.jpg"),
                    mask_path=root / "m.png" if i == 0 else None, timestamp=float(i),
                    uv_labels=rng.uniform(0, WIDTH, size=(2, 2)),
                    P_cam_labels=rng.uniform(1, 2, size=(2, 3)),
                    T_cam_base_true=T_from_rotvec_t(rng.normal(size=3), rng.normal(size=3)))
              for i in range(2)]
    sequence = Sequence(robot="panda", camera=CameraIntrinsics(10, 10, 4, 3, WIDTH, HEIGHT,
                                                               (0.1, 0, 0, 0, 0)),
                        joint_names=("j1", "j2"), keypoint_names=("k1", "k2"),
                        frames=tuple(frames), T_cam_base_reference=np.eye(4))
    return write_dream(sequence, root / "data")


def build_teleop(root: Path) -> Path:
    rng = np.random.default_rng(0)
    folder = root / "teleop" / "ep_1"
    folder.mkdir(parents=True)
    steps = {}
    for i, t in enumerate(["1721961385.5", "1721961385.25", "1721961385.75"]):
        cv2.imwrite(str(folder / f"f{i}.png"), _rgb(rng))
        steps[t] = {"img_file": f"f{i}.png", "joint_angles": rng.normal(size=7).tolist()}
    info = {"calibration_info": {"extrinsic": [[0.1, 0.2, 0.3, 0.0, 0.1, 1.0]],
                                 "intrinsic": [[10.0, 0, 4], [0, 10.0, 3], [0, 0, 1]]},
            "steps": steps}
    (folder / "info.json").write_text(json.dumps(info))
    return root / "teleop"


def build_franka(root: Path) -> Path:
    rng = np.random.default_rng(0)
    data = root / "franka"
    for sub in ("color", "mask", "qpos"):
        (data / sub).mkdir(parents=True)
    (data / "K.txt").write_text("10 0 4\n0 10 3\n0 0 1\n")
    for i in range(2):
        cv2.imwrite(str(data / "color" / f"{i:06d}.png"), _rgb(rng))
        cv2.imwrite(str(data / "mask" / f"{i:06d}.png"),
                    (rng.random((HEIGHT, WIDTH)) > 0.5).astype(np.uint8) * 255)
        (data / "qpos" / f"{i:06d}.txt").write_text("\n".join(["0.1"] * 9))
    return data


def build_maniunicon(root: Path) -> Path:
    rng = np.random.default_rng(0)
    path = root / "ep.npz"
    np.savez(path, rgb_images=np.stack([_rgb(rng), _rgb(rng)]),
             captured_joint_values=rng.normal(size=(2, 8)),
             target_joint_values=rng.normal(size=(2, 8)), timestamps=np.array([0.0, 0.1]))
    (root / "ep.intrinsics.json").write_text(json.dumps({"fx": 10, "fy": 10, "cx": 4, "cy": 3}))
    return path


# ----------------------------------------------------------------------------- mutations


def _containers(value: Any, path: tuple = ()) -> list[tuple]:
    """Paths (keys / indices) of every container inside a JSON value, the root included."""
    out = [path] if isinstance(value, (dict, list)) else []
    items = value.items() if isinstance(value, dict) else \
        enumerate(value) if isinstance(value, list) else []
    for key, child in items:
        out += _containers(child, path + (key,))
    return out


def mutate_json(value: Any, data: st.DataObject) -> Any:
    """Replace, delete or add one entry somewhere in a JSON value (or replace it whole)."""
    paths = _containers(value)
    if not paths or data.draw(st.integers(0, 9)) == 0:
        return data.draw(JSON_VALUES)
    target_path = data.draw(st.sampled_from(paths))
    target = value
    for key in target_path:
        target = target[key]
    keys = list(target) if isinstance(target, dict) else list(range(len(target)))
    action = data.draw(st.sampled_from(["replace", "delete", "add"]))
    if action == "add" or not keys:
        if isinstance(target, dict):
            target[data.draw(st.text(max_size=6))] = data.draw(JSON_VALUES)
        else:
            target.append(data.draw(JSON_VALUES))
    else:
        key = data.draw(st.sampled_from(keys))
        if action == "delete":
            del target[key]
        else:
            target[key] = data.draw(JSON_VALUES)
    return value


def mutate_bytes(content: bytes, data: st.DataObject) -> bytes:
    """Truncate, overwrite a few bytes of, empty or replace a file's content."""
    action = data.draw(st.sampled_from(["truncate", "overwrite", "random", "empty"]))
    if action == "truncate" and content:
        return content[: data.draw(st.integers(0, len(content) - 1))]
    if action == "overwrite" and content:
        out = bytearray(content)
        for _ in range(data.draw(st.integers(1, 4))):
            out[data.draw(st.integers(0, len(out) - 1))] = data.draw(st.integers(0, 255))
        return bytes(out)
    if action == "empty":
        return b""
    return data.draw(st.binary(max_size=300))


def damage_json_file(path: Path, data: st.DataObject) -> None:
    value = mutate_json(json.loads(path.read_text()), data)
    path.write_text(json.dumps(value, allow_nan=True))  # NaN / Infinity literals included


def damage_bytes(path: Path, data: st.DataObject) -> None:
    path.write_bytes(mutate_bytes(path.read_bytes(), data))


def _files(root: Path, pattern: str = "*") -> list[Path]:
    return sorted(p for p in root.rglob(pattern) if p.is_file())


def check_message(exc: DreamError) -> None:
    """A refusal is one line and, for an input problem, names a file or folder."""
    message = str(exc)
    assert "\n" not in message and "\r" not in message, message
    if isinstance(exc, InputError):
        assert exc.path is not None and str(exc.path) in message, message


def exercise(path: Path, out: Path, **kwargs: Any) -> None:
    """Read, load every image and mask, write back: only `DreamError`s may escape."""
    try:
        sequence = read_sequence(path, **kwargs)
    except DreamError as exc:
        check_message(exc)
        event("read refused")
        return
    event("read accepted")
    for frame in sequence.frames:
        for loader in (load_image, load_mask_ids):
            try:
                loader(frame, sequence.camera)
            except DreamError as exc:
                check_message(exc)
                event(f"{loader.__name__} refused")
    try:
        write_dream(sequence, out)
    except DreamError as exc:
        check_message(exc)
        event("write refused")


def _run(build: Callable[[Path], Path], damage: Callable[[Path], None], **kwargs: Any) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        data_path = build(root)
        damage(root)
        exercise(data_path, root / "out", **kwargs)


# ----------------------------------------------------------------------------- the fuzz tests


@FUZZ
@given(st.data())
def test_fuzz_dream_json(data: st.DataObject) -> None:
    def damage(root: Path) -> None:
        damage_json_file(data.draw(st.sampled_from(_files(root / "data", "*.json"))), data)
    _run(build_dream, damage)


@FUZZ
@given(st.data())
def test_fuzz_dream_bytes(data: st.DataObject) -> None:
    def damage(root: Path) -> None:
        damage_bytes(data.draw(st.sampled_from(_files(root / "data"))), data)
    _run(build_dream, damage)


@FUZZ
@given(st.data())
def test_fuzz_panda_teleop(data: st.DataObject) -> None:
    def damage(root: Path) -> None:
        info = root / "teleop" / "ep_1" / "info.json"
        if data.draw(st.booleans()):
            damage_json_file(info, data)
        else:
            damage_bytes(data.draw(st.sampled_from(_files(root / "teleop"))), data)
    _run(build_teleop, damage)


@FUZZ
@given(st.data())
def test_fuzz_franka_offline(data: st.DataObject) -> None:
    def damage(root: Path) -> None:
        target = data.draw(st.sampled_from(_files(root / "franka")))
        if target.suffix == ".txt" and data.draw(st.booleans()):
            target.write_text(data.draw(st.text(
                alphabet=st.sampled_from("0123456789.-+eEnaifNI \n\t,x"), max_size=60)))
        elif data.draw(st.integers(0, 5)) == 0:
            target.unlink()
        else:
            damage_bytes(target, data)
    _run(build_franka, damage)


ARRAY_DTYPES = st.sampled_from([np.uint8, np.int32, np.float64, np.float32, np.bool_,
                                np.complex64, ">f8", "<U3", "S2"])


@st.composite
def random_arrays(draw: st.DrawFn) -> np.ndarray:
    if draw(st.integers(0, 9)) == 0:
        return np.array([{"x": 1}, None], dtype=object)
    shape = draw(hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=4))
    if draw(st.booleans()):  # a plausible shape: (N, H, W, 3) or (N, J)
        shape = draw(st.sampled_from([(2, HEIGHT, WIDTH, 3), (2, 8), (2, 5), (3, 8), (2,)]))
    return draw(hnp.arrays(ARRAY_DTYPES, shape))


@FUZZ
@given(st.data())
def test_fuzz_maniunicon_arrays(data: st.DataObject) -> None:
    def damage(root: Path) -> None:
        with np.load(root / "ep.npz") as archive:
            arrays = dict(archive)
        key = data.draw(st.sampled_from(sorted(arrays) + ["extra"]))
        if data.draw(st.integers(0, 3)) == 0:
            arrays.pop(key, None)
        else:
            arrays[key] = data.draw(random_arrays())
        compress = data.draw(st.booleans())
        (np.savez_compressed if compress else np.savez)(root / "ep.npz", **arrays)
    _run(build_maniunicon, damage)


@FUZZ
@given(st.data())
def test_fuzz_maniunicon_files(data: st.DataObject) -> None:
    def damage(root: Path) -> None:
        if data.draw(st.booleans()):
            damage_json_file(root / "ep.intrinsics.json", data)
        else:
            damage_bytes(data.draw(st.sampled_from(_files(root))), data)
    _run(build_maniunicon, damage)


@FUZZ
@given(st.data())
def test_fuzz_maniunicon_intrinsics_argument(data: st.DataObject) -> None:
    value = data.draw(st.one_of(
        st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=5),
        st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), st.floats(-1e3, 1e3),
                  st.floats(-1e3, 1e3)),
        st.text(max_size=5), st.integers()))
    with tempfile.TemporaryDirectory() as tmp:
        path = build_maniunicon(Path(tmp))
        try:
            read_sequence(path, intrinsics=value)
        except DreamError as exc:
            check_message(exc)


@FUZZ
@given(st.data())
def test_fuzz_any_layout_detection(data: st.DataObject) -> None:
    """Random file trees: detection and reading fail cleanly."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        names = data.draw(st.lists(st.sampled_from(
            ["_camera_settings.json", "000000.json", "info.json", "a/info.json", "K.txt",
             "qpos/000000.txt", "color/000000.png", "x.npz", "intrinsics.json"]),
            max_size=4, unique=True))
        for name in names:
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            (root / name).write_bytes(data.draw(st.sampled_from(
                [b"", b"{}", b"[]", b"{\"steps\": {}}", b"1 2 3", b"\x89PNG\r\n\x1a\n"])))
        exercise(root, root / "out")


# ----------------------------------------------------------------------------- round trip


FINITE = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_subnormal=True)
LABEL = st.one_of(st.just(float("nan")), FINITE)


@st.composite
def sequences(draw: st.DrawFn) -> Sequence:
    n_frames = draw(st.integers(1, 3))
    n_joints = draw(st.integers(1, 4))
    n_keypoints = draw(st.integers(1, 3))
    frames = []
    for i in range(n_frames):
        uv = draw(hnp.arrays(float, (n_keypoints, 2), elements=LABEL))
        P = draw(hnp.arrays(float, (n_keypoints, 3), elements=LABEL))
        uv[np.isnan(uv).any(axis=1)] = np.nan  # a label is a whole row or nothing
        P[np.isnan(P).any(axis=1)] = np.nan
        rotvec = draw(hnp.arrays(float, 3, elements=st.floats(-3, 3)))
        t = draw(hnp.arrays(float, 3, elements=FINITE))
        frames.append(Frame(
            name=f"{i:06d}", joints=draw(hnp.arrays(float, n_joints, elements=FINITE)),
            timestamp=draw(st.none() | FINITE),
            uv_labels=uv if not np.isnan(uv).all() else None,
            P_cam_labels=P if not np.isnan(P).all() else None,
            T_cam_base_true=draw(st.none() | st.just(T_from_rotvec_t(rotvec, t)))))
    camera = CameraIntrinsics(draw(st.floats(1, 1e4)), draw(st.floats(1, 1e4)), draw(FINITE),
                              draw(FINITE), draw(st.integers(1, 5000)), draw(st.integers(1, 5000)),
                              draw(st.none() | st.tuples(*[st.floats(-1, 1)] * 5)))
    return Sequence(robot=draw(st.sampled_from(["panda", "ur5", "/robots/x.urdf"])),
                    camera=camera, joint_names=tuple(f"joint {j}" for j in range(n_joints)),
                    keypoint_names=tuple(f"kp{k}" for k in range(n_keypoints)),
                    frames=tuple(frames), camera_name=draw(st.sampled_from(["camera", "c1"])))


@ROUND_TRIP
@given(sequences())
def test_round_trip_property(sequence: Sequence) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        back = read_sequence(write_dream(sequence, Path(tmp) / "out"))
    assert (back.robot, back.camera, back.camera_name) == \
        (sequence.robot, sequence.camera, sequence.camera_name)
    assert (back.joint_names, back.keypoint_names) == \
        (sequence.joint_names, sequence.keypoint_names)
    for a, b in zip(sequence.frames, back.frames, strict=True):
        assert np.array_equal(a.joints, b.joints) and a.timestamp == b.timestamp
        for x, y in ((a.uv_labels, b.uv_labels), (a.P_cam_labels, b.P_cam_labels)):
            assert (x is None and y is None) or np.array_equal(x, y, equal_nan=True)
        if a.T_cam_base_true is None:
            assert b.T_cam_base_true is None
        else:
            assert np.array_equal(a.T_cam_base_true[:, 3], b.T_cam_base_true[:, 3])
            np.testing.assert_allclose(a.T_cam_base_true, b.T_cam_base_true, rtol=0,
                                       atol=1e-12 * max(1.0, np.abs(a.T_cam_base_true).max()))
