"""The recording formats a robot user has: a folder of images with a CSV of joint readings, a
ROS CameraInfo YAML, distortion on the command line, ROS 1 and ROS 2 bags. Each gives the same
sequence as the data it was written from."""

from __future__ import annotations

import csv
import json
import logging
import shutil
from dataclasses import replace
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import pytest

from dream.camera import CameraIntrinsics
from dream.cli import BUNDLED_MODEL, main
from dream.errors import InputError
from dream.io import read_sequence
from dream.io.camera_info import camera_info_text, read_camera_info
from dream.io.images import load_image
from dream.io.rosbag import BagTopics
from dream.sample import SampleSettings, make_sample

rosbags = pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

WIDTH, HEIGHT = 160, 120
CAMERA = CameraIntrinsics(150.0, 151.0, 79.2, 60.3, WIDTH, HEIGHT,
                          (0.05, -0.1, 0.001, -0.002, 0.01))
TELEOP_FRAMES = 40


@pytest.fixture(scope="module")
def imaged(tmp_path_factory):
    """A sample with random images and timestamps (DREAM layout) and its sequence."""
    root = tmp_path_factory.mktemp("readers")
    seq = make_sample(SampleSettings(num_frames=5, seed=3, width=WIDTH, height=HEIGHT,
                                     fx=150.0, fy=151.0, pixel_noise_px=0.0))
    rng = np.random.default_rng(0)
    frames = []
    for i, frame in enumerate(seq.frames):
        path = root / f"img_{i}.png"
        cv2.imwrite(str(path), rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8))
        frames.append(replace(frame, image_path=path, timestamp=1700000000.1 + 0.2 * i))
    seq = replace(seq, frames=tuple(frames), camera=CAMERA)
    return seq, root


def write_csv_layout(seq, folder: Path, image_column: bool = True, camera: bool = True) -> Path:
    folder.mkdir()
    with open(folder / "joints.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow((["image"] if image_column else []) + ["timestamp", *seq.joint_names])
        for i, frame in enumerate(seq.frames):
            name = f"{i:04d}{Path(frame.image_path).suffix}"
            shutil.copy(frame.image_path, folder / name)
            writer.writerow(([name] if image_column else []) + [repr(frame.timestamp)]
                            + [repr(float(v)) for v in frame.joints])
    if camera:
        (folder / "camera_info.yaml").write_text(camera_info_text(seq.camera))
    return folder


def _stamp(ts, t: float):
    ns = round(Fraction(t) * 10 ** 9)
    header = ts.types["std_msgs/msg/Header"]
    extra = {"seq": 0} if "seq" in header.__dataclass_fields__ else {}   # ROS 1
    return header(stamp=ts.types["builtin_interfaces/msg/Time"](sec=ns // 10 ** 9,
                                                                nanosec=ns % 10 ** 9),
                  frame_id="camera", **extra)


def bag_messages(seq, compressed: bool, ts):
    """(topic, msgtype, time s, message) of a sequence: images, joint states, camera info."""
    out = []
    c = seq.camera
    info_type = ts.types["sensor_msgs/msg/CameraInfo"]
    upper = "K" in info_type.__dataclass_fields__                            # ROS 1 names
    matrices = {"d": np.array(c.distortion or (0.0,) * 5), "k": c.K.reshape(-1),
                "r": np.eye(3).reshape(-1),
                "p": np.array([c.fx, 0, c.cx, 0, 0, c.fy, c.cy, 0, 0, 0, 1, 0], float)}
    info = info_type(
        header=_stamp(ts, seq.frames[0].timestamp), height=c.height, width=c.width,
        distortion_model="plumb_bob", binning_x=0, binning_y=0,
        **{k.upper() if upper else k: v for k, v in matrices.items()},
        roi=ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                          width=0, do_rectify=False))
    out.append(("/camera/camera_info", "sensor_msgs/msg/CameraInfo", seq.frames[0].timestamp,
                info))
    for frame in seq.frames:
        header = _stamp(ts, frame.timestamp)
        if compressed:
            data = np.frombuffer(Path(frame.image_path).read_bytes(), np.uint8)
            image = ts.types["sensor_msgs/msg/CompressedImage"](header=header, format="png",
                                                                data=data)
            out.append(("/camera/image/compressed", "sensor_msgs/msg/CompressedImage",
                        frame.timestamp, image))
        else:
            rgb = load_image(frame)
            image = ts.types["sensor_msgs/msg/Image"](
                header=header, height=rgb.shape[0], width=rgb.shape[1], encoding="rgb8",
                is_bigendian=0, step=rgb.shape[1] * 3, data=rgb.reshape(-1))
            out.append(("/camera/image", "sensor_msgs/msg/Image", frame.timestamp, image))
        joints = ts.types["sensor_msgs/msg/JointState"](
            header=header, name=list(seq.joint_names) + ["finger"],
            position=np.append(frame.joints, 0.04), velocity=np.zeros(0), effort=np.zeros(0))
        out.append(("/joint_states", "sensor_msgs/msg/JointState", frame.timestamp, joints))
    return out


def write_bag(seq, path: Path, compressed: bool = True, ros1: bool = False,
              joints_seq=None) -> Path:
    """A bag of `seq` (its joint states those of `joints_seq` where given: other stamps)."""
    ts = get_typestore(Stores.ROS2_HUMBLE if not ros1 else Stores.ROS1_NOETIC)
    messages = bag_messages(seq, compressed, ts)
    if joints_seq is not None:
        messages = [m for m in messages if m[0] != "/joint_states"] + [
            m for m in bag_messages(joints_seq, compressed, ts) if m[0] == "/joint_states"]
    writer = Writer1(path) if ros1 else Writer2(path, version=9)
    with writer:
        connections = {}
        for topic, msgtype, _, _ in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
        for topic, msgtype, t, msg in messages:
            data = ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype)
            writer.write(connections[topic], int(round(t * 1e9)), data)
    return path


def _same(a, b) -> None:
    assert a.camera == b.camera and len(a.frames) == len(b.frames)
    for fa, fb in zip(a.frames, b.frames, strict=True):
        assert np.array_equal(fa.joints, fb.joints) and fa.timestamp == fb.timestamp
        assert np.array_equal(load_image(fa), load_image(fb))


def test_camera_info_yaml_in_every_form(tmp_path):
    path = tmp_path / "ci.yaml"
    path.write_text(camera_info_text(CAMERA))
    assert read_camera_info(path) == CAMERA
    path.write_text(f"width: {WIDTH}\nheight: {HEIGHT}\ndistortion_model: plumb_bob\n"
                    f"d: [0.05, -0.1, 0.001, -0.002, 0.01]\n"
                    f"k: [150.0, 0.0, 79.2, 0.0, 151.0, 60.3, 0.0, 0.0, 1.0]\n")
    assert read_camera_info(path) == CAMERA
    path.write_text(f"width: {WIDTH}\nheight: {HEIGHT}\nD: []\n"
                    f"K: [150.0, 0.0, 79.2, 0.0, 151.0, 60.3, 0.0, 0.0, 1.0]\n")
    assert read_camera_info(path) == replace(CAMERA, distortion=None)
    echoed = (f"width: {WIDTH}\nheight: {HEIGHT}\nd: []\n"
              "k: [150.0, 0.0, 79.2, 0.0, 151.0, 60.3, 0.0, 0.0, 1.0]\n---\n")
    path.write_text(echoed * 2)                       # `ros2 topic echo`, two messages
    assert read_camera_info(path) == replace(CAMERA, distortion=None)
    path.write_text(camera_info_text(CAMERA).replace("plumb_bob", "equidistant"))
    with pytest.raises(InputError, match="equidistant"):
        read_camera_info(path)
    path.write_text("width: 10\nheight: 10\nk: [1, 2, 3]\n")
    with pytest.raises(InputError, match="expected 9"):
        read_camera_info(path)


@pytest.mark.parametrize("image_column", [True, False])
def test_images_and_csv_read_as_the_source(imaged, tmp_path, image_column):
    seq, _ = imaged
    folder = write_csv_layout(seq, tmp_path / "csv", image_column)
    _same(read_sequence(folder), seq)


def test_csv_problems_say_what_to_do(imaged, tmp_path, capsys):
    seq, _ = imaged
    folder = write_csv_layout(seq, tmp_path / "nocam", camera=False)
    with pytest.raises(InputError, match="has no camera.*--camera-info"):
        read_sequence(folder)
    (tmp_path / "ci.yaml").write_text(camera_info_text(CAMERA))
    assert read_sequence(folder, intrinsics=read_camera_info(tmp_path / "ci.yaml")).camera == \
        CAMERA
    code = main(["info", str(folder), "--camera-info", str(tmp_path / "ci.yaml")])
    assert code == 0 and "distortion: 0.05, -0.1, 0.001, -0.002, 0.01" in \
        capsys.readouterr().out
    code = main(["info", str(folder), "--intrinsics", "150,151,79.2,60.3", "--distortion",
                 "0.05,-0.1,0.001,-0.002"])
    assert code == 0 and "distortion: 0.05, -0.1, 0.001, -0.002, 0" in capsys.readouterr().out
    (folder / "0001.png").unlink()
    with pytest.raises(InputError, match="0001.png.*not found"):
        read_sequence(folder, intrinsics=CAMERA)


def test_distortion_needs_intrinsics(imaged, tmp_path, capsys):
    seq, _ = imaged
    folder = write_csv_layout(seq, tmp_path / "csv")
    code = main(["info", str(folder), "--distortion", "0.1,0,0,0"])
    err = capsys.readouterr().err
    assert code == 2 and "--distortion goes with --intrinsics" in err


@pytest.mark.parametrize("compressed, ros1", [(True, False), (False, False), (True, True)])
def test_bags_read_as_the_source(imaged, tmp_path, compressed, ros1):
    seq, _ = imaged
    bag = write_bag(seq, tmp_path / ("run.bag" if ros1 else "run"), compressed, ros1)
    read = read_sequence(bag, joint_names=seq.joint_names)
    _same(read, seq)
    everything = read_sequence(bag)                      # every joint of the messages
    assert everything.joint_names == seq.joint_names + ("finger",)


def test_bag_topics_and_problems(imaged, tmp_path):
    seq, _ = imaged
    bag = write_bag(seq, tmp_path / "run")
    topics = BagTopics("/camera/image/compressed", "/joint_states", "/camera/camera_info")
    _same(read_sequence(bag, joint_names=seq.joint_names, topics=topics), seq)
    with pytest.raises(InputError, match="has no topic /cam; its topics"):
        read_sequence(bag, topics=BagTopics(image="/cam"))
    with pytest.raises(InputError, match="holds sensor_msgs/msg/JointState, not images"):
        read_sequence(bag, topics=BagTopics(image="/joint_states"))
    with pytest.raises(InputError, match="topics are for ROS bags"):
        read_sequence(write_csv_layout(seq, tmp_path / "csv"), topics=BagTopics(image="/x"))


def test_joint_states_on_another_clock_are_shown_with_both_spans(imaged, tmp_path):
    seq, _ = imaged
    later = replace(seq, frames=tuple(replace(f, timestamp=f.timestamp + 100.0)
                                      for f in seq.frames))
    bag = write_bag(seq, tmp_path / "run", joints_seq=later)
    with pytest.raises(InputError) as exc:
        read_sequence(bag, joint_names=seq.joint_names)
    message = str(exc.value)
    assert "no image has a joint state within" in message
    assert "the images' median lies 100.000 s before the joint states' (two clocks?)" in message
    t0 = seq.frames[0].timestamp
    assert f"the images span {t0:.3f}.." in message and f"joint states {t0 + 100:.3f}.." in message


def _teleop_subset(teleop: Path, dest: Path) -> Path:
    """The first frames of panda_teleop in its own layout."""
    info = json.loads((teleop / "info.json").read_text())
    keys = sorted(info["steps"], key=float)[:TELEOP_FRAMES]
    info["steps"] = {k: info["steps"][k] for k in keys}
    dest.mkdir()
    for k in keys:
        (dest / info["steps"][k]["img_file"]).symlink_to(teleop / info["steps"][k]["img_file"])
    (dest / "info.json").write_text(json.dumps(info))
    return dest


def test_teleop_calibrates_the_same_from_three_layouts(realdata, tmp_path):
    """panda_teleop read from its own layout, images + CSV and a ROS 2 bag written from it:
    the same extrinsic to 1e-9."""
    own = _teleop_subset(realdata / "panda_teleop" / "panda_1", tmp_path / "own")
    seq = read_sequence(own)
    layouts = {"own": own, "csv": write_csv_layout(seq, tmp_path / "csv"),
               "bag": write_bag(seq, tmp_path / "bag")}
    T = {}
    for name, data in layouts.items():
        out = tmp_path / f"{name}.json"
        assert main(["calibrate", "--data", str(data), "--model", str(BUNDLED_MODEL),
                     "--refine", "none", "--out", str(out)]) == 0
        T[name] = np.array(json.loads(out.read_text())["T_cam_base"])
    assert np.abs(T["csv"] - T["own"]).max() < 1e-9
    assert np.abs(T["bag"] - T["own"]).max() < 1e-9


def test_bag_cache_that_cannot_be_written_says_what_to_do(imaged, tmp_path, monkeypatch):
    seq, _ = imaged
    bag = write_bag(seq, tmp_path / "run")
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("x")
    monkeypatch.setenv("DREAM_CACHE_DIR", str(blocker))
    with pytest.raises(InputError, match="DREAM_CACHE_DIR"):
        read_sequence(bag)


def test_a_bag_read_again_takes_its_images_from_the_cache(imaged, tmp_path, monkeypatch):
    import dream.io.rosbag as rosbag

    seq, _ = imaged
    bag = write_bag(seq, tmp_path / "run")
    first = read_sequence(bag, joint_names=seq.joint_names)

    def no_decoding(*args):
        raise AssertionError("decoded again")

    with monkeypatch.context() as patch:
        patch.setattr(rosbag, "_rgb", no_decoding)
        _same(read_sequence(bag, joint_names=seq.joint_names), first)
    stack = first.frames[0].image_path
    np.savez(stack, rgb_images=np.zeros((2, HEIGHT, WIDTH, 3), np.uint8))   # stale: 2 of 5
    _same(read_sequence(bag, joint_names=seq.joint_names), seq)


def _jpeg_with_orientation(rgb: np.ndarray, orientation: int) -> tuple[bytes, bytes]:
    """A JPEG of `rgb` as written, and the same bytes with an EXIF orientation tag (APP1)."""
    plain = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1].tobytes()
    ifd = (b"\x01\x00" + b"\x12\x01" + b"\x03\x00" + b"\x01\x00\x00\x00"
           + orientation.to_bytes(2, "little") + b"\x00\x00" + b"\x00\x00\x00\x00")
    exif = b"Exif\x00\x00" + b"II*\x00" + b"\x08\x00\x00\x00" + ifd
    app1 = b"\xff\xe1" + (len(exif) + 2).to_bytes(2, "big") + exif
    return plain, plain[:2] + app1 + plain[2:]


def test_an_exif_rotation_leaves_the_pixels_as_stored(imaged, tmp_path):
    """The intrinsics describe the sensor's pixels: a JPEG's EXIF orientation (a phone's, a
    camera turned upside down) must not turn the image the keypoints are found in."""
    seq, _ = imaged
    rgb = np.random.default_rng(1).integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    for orientation in (3, 6):
        plain, tagged = _jpeg_with_orientation(rgb, orientation)
        (tmp_path / "plain.jpg").write_bytes(plain)
        (tmp_path / "tagged.jpg").write_bytes(tagged)
        frames = [replace(seq.frames[0], image_path=tmp_path / name)
                  for name in ("plain.jpg", "tagged.jpg")]
        assert np.array_equal(load_image(frames[1], CAMERA), load_image(frames[0], CAMERA))


def test_a_users_csv_is_read_as_a_spreadsheet_writes_it(imaged, tmp_path, capsys, caplog):
    """Image names numbered without leading zeros pair with the rows in numeric order; a
    byte-order mark is read past; rows stamped alike with other readings are a warning;
    another spelling of the time or image column, and
    timestamps in nanoseconds, are refused in one line."""
    seq, _ = imaged
    folder = write_csv_layout(seq, tmp_path / "csv", image_column=False)
    for i, number in enumerate((1, 2, 10, 11, 20)):        # as text: 1, 10, 11, 2, 20
        (folder / f"{i:04d}.png").rename(folder / f"frame_{number}.png")
    csv_path = folder / "joints.csv"
    text = csv_path.read_text()
    csv_path.write_text("\ufeff" + text, encoding="utf-8")
    _same(read_sequence(folder), seq)
    header, *rows = text.splitlines()
    for renamed, message in (("time", "looks like a time"), ("Timestamp", "looks like a time"),
                             ("stamp_ns", "looks like a time"), ("timestamps", "looks like a "
                             "time"), ("ts", "looks like a time"), ("time_sec", "looks like a "
                             "time"), ("header.stamp", "looks like a time")):
        csv_path.write_text("\n".join([header.replace("timestamp", renamed), *rows]))
        with pytest.raises(InputError, match=message):
            read_sequence(folder)
    repeated = [",".join([rows[0].split(",")[0], *r.split(",")[1:]]) for r in rows[:2]]
    csv_path.write_text("\n".join([header, *repeated, *rows[2:]]))
    with caplog.at_level(logging.WARNING, logger="dream.io.csv_layout"):
        read_sequence(folder)
    assert "lines 2 and 3 share the timestamp" in caplog.text
    csv_path.write_text("\n".join(rows))                  # no header row
    with pytest.raises(InputError, match="first line holds numbers"):
        read_sequence(folder)
    gap = rows[1].split(",")
    gap[-1] = "nan"                                       # a reading the log lost
    csv_path.write_text("\n".join([header, rows[0], ",".join(gap), *rows[2:]]))
    with pytest.raises(InputError, match="not a finite number.*or drop the row"):
        read_sequence(folder)
    nanoseconds = [",".join([str(int(float(r.split(",")[0]) * 1e9)), *r.split(",")[1:]])
                   for r in rows]
    csv_path.write_text("\n".join([header, *nanoseconds]))
    with pytest.raises(InputError, match="not seconds.*divided by 1e9"):
        read_sequence(folder)
    image_folder = write_csv_layout(seq, tmp_path / "named")
    named = image_folder / "joints.csv"
    named.write_text(named.read_text().replace("image,", "Image,", 1))
    with pytest.raises(InputError, match="the image column is called"):
        read_sequence(image_folder)
    named.write_text(named.read_text().replace("Image,", "image_path,", 1))
    with pytest.raises(InputError, match="looks like the image column"):
        read_sequence(image_folder)
    named.write_text(named.read_text().replace("image_path,", "Image,", 1))
    text = named.read_text().replace("Image,", "image,", 1)
    named.write_text(text.replace(",", ";"))           # a spreadsheet's locale
    with pytest.raises(InputError, match="separated by ';'.*Fix: save it as CSV with commas"):
        read_sequence(image_folder)
    named.write_text(text)
    (image_folder / "camera_info.yaml").unlink()
    (image_folder / "K.txt").write_text("150 0 0\n0 151 0\n79.2 60.3 1\n")
    with pytest.raises(InputError, match="K.txt: .*it is transposed.*Fix: write K row by row"):
        read_sequence(image_folder)
    with pytest.raises(InputError, match="^the given intrinsics are for 640x480 images"):
        read_sequence(image_folder, intrinsics=replace(CAMERA, width=640, height=480))
    (image_folder / "K.txt").write_text("150 0 79.2\n0 151 60.3\n0 0 1\n")
    named.write_text(text.replace("panda_joint1", "z1_joint1"))  # another arm's, no --robot
    assert main(["info", str(image_folder)]) == 0
    assert "robot:     panda, but the data has no joint panda_joint1" in capsys.readouterr().out
    assert main(["calibrate", "--data", str(image_folder), "--camera-guess", "1.5,0.5,1",
                 "--look-at", "0,0,0.4", "--out", str(tmp_path / "r.json")]) == 2
    assert "Fix: give --robot the robot" in capsys.readouterr().err


def test_no_output_writes_over_the_recording(imaged, tmp_path, capsys):
    """--out naming the joint log, the camera file or an image of the recording, or a frame's
    file name in a DREAM folder, is refused before any work and the file left as it was."""
    from dream.io import write_dream
    from dream.io.recording_files import check_spares_recording

    seq, _ = imaged
    folder = write_csv_layout(seq, tmp_path / "csv")
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    for name in ("joints.csv", "camera_info.yaml", "0001.png", "K.txt"):
        code = main(["calibrate", "--data", str(folder), "--use-labels", "--out",
                     str(folder / name)])
        err = capsys.readouterr().err
        assert code == 2 and "writing it would change the recording" in err, err
        assert len(err.strip().splitlines()) == 1
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    check_spares_recording([folder / "result.json"], read_sequence(folder), folder)
    dream = tmp_path / "dream"
    write_dream(seq, dream)
    with pytest.raises(InputError, match="would be read as a frame"):
        check_spares_recording([dream / "000010.json"], read_sequence(dream), dream)
