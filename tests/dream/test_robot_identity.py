"""A model's robot compared with the robot used by URDF content, not by how each is named
(`dream.robot.identity`), and a model's keypoints against --keypoints."""

from __future__ import annotations

import io
import logging
from pathlib import Path

import numpy as np
import pytest
from test_keypoint_choice import lbr_urdf

from dream.camera import CameraIntrinsics
from dream.cli.observe import detect
from dream.detection import load_model_robot
from dream.errors import InputError
from dream.preprocess import Preprocess
from dream.robot import load_robot
from dream.robot.identity import TrainedRobot, robot_difference, urdf_sha256
from dream.sequence import Frame, Sequence

WIDTH, HEIGHT = 64, 48
MED7_KEYPOINTS = ("lbr_link_0", "lbr_link_3", "lbr_link_5", "lbr_link_ee")


class StubModel:
    """A keypoint model that finds nothing, trained on `robot` (its model card's name)."""

    preprocess = Preprocess(64, 48)
    stride = 2

    def __init__(self, robot: str, keypoints: tuple[str, ...], urdf_hash: str | None = None):
        self.robot, self.keypoint_names, self.urdf_sha256 = robot, keypoints, urdf_hash

    def run(self, batch: np.ndarray) -> dict[str, np.ndarray]:
        n, _, h, w = batch.shape
        return {"belief": np.zeros((n, len(self.keypoint_names), h // 2, w // 2), np.float32)}


def _med7_sequence(tmp_path: Path, robot) -> Sequence:
    import cv2

    image = tmp_path / "000000.rgb.png"
    cv2.imwrite(str(image), np.zeros((HEIGHT, WIDTH, 3), np.uint8))
    camera = CameraIntrinsics(50.0, 50.0, WIDTH / 2 - 0.5, HEIGHT / 2 - 0.5, WIDTH, HEIGHT)
    return Sequence("med7", camera, robot.joint_names, (),
                    (Frame("000000", np.zeros(robot.num_joints), image_path=image),))


def _edited(source: Path, out: Path) -> Path:
    """`source` with its flange 1 cm longer."""
    out.write_text(source.read_text().replace('xyz="0 0 0.045"', 'xyz="0 0 0.055"'))
    return out


def test_same_urdf_content_is_the_same_robot(tmp_path):
    panda = load_robot("panda")
    copy = tmp_path / "my_arm.urdf"
    copy.write_bytes(panda.urdf_path.read_bytes())
    assert robot_difference(TrainedRobot(str(copy)), panda) is None
    assert robot_difference(TrainedRobot("panda"),
                            load_robot(copy, keypoints=panda.keypoint_names)) is None
    # a user URDF: the model names its path, the robot its <robot name>
    med7_path = lbr_urdf(tmp_path)
    med7 = load_robot(med7_path, keypoints=MED7_KEYPOINTS)
    assert med7.name == "med7" and str(med7_path) != med7.name
    assert robot_difference(TrainedRobot(str(med7_path)), med7) is None
    # a model trained elsewhere: its path does not exist here, its hash says the same URDF
    elsewhere = "/elsewhere/robots/lbr_med7.urdf"
    assert robot_difference(TrainedRobot(elsewhere, urdf_sha256(med7_path)), med7) is None
    # without a hash, a file name that matches the robot's name is taken at its word
    assert robot_difference(TrainedRobot("/elsewhere/med7.urdf"), med7) is None


def test_different_robots_say_what_differs(tmp_path):
    panda = load_robot("panda")
    text = robot_difference(TrainedRobot("ur5"), panda)
    assert text == ("the model was trained on built-in robot 'ur5', but the robot used is "
                    "built-in robot 'panda': their URDFs differ in content")
    med7_path = lbr_urdf(tmp_path)
    med7 = load_robot(med7_path, keypoints=MED7_KEYPOINTS)
    longer = _edited(med7_path, tmp_path / "med7_long.urdf")
    text = robot_difference(TrainedRobot(str(longer)), med7)
    assert "differ in content" in text and str(med7_path) in text
    text = robot_difference(TrainedRobot("/elsewhere/med7.urdf", urdf_sha256(longer)), med7)
    assert "the URDF hash the model carries differs from that URDF's" in text
    text = robot_difference(TrainedRobot("/elsewhere/iiwa14.urdf"), med7)
    assert text == (f"the model was trained on robot '/elsewhere/iiwa14.urdf', but the robot "
                    f"used is robot 'med7' (URDF {med7_path})")
    with pytest.raises(InputError, match="64 hex digits"):
        TrainedRobot("panda", "abc")


def test_detect_warns_only_for_another_robot(tmp_path, caplog):
    med7_path = lbr_urdf(tmp_path)
    robot = load_robot(med7_path, keypoints=MED7_KEYPOINTS)
    seq = _med7_sequence(tmp_path, robot)
    longer = _edited(med7_path, tmp_path / "med7_long.urdf")
    for trained_on, warned in ((str(med7_path), False), (str(longer), True),
                               ("xarm7", True)):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="dream"):
            found, obs, _ = detect(seq, str(med7_path), "stub.onnx", io.StringIO(),
                                   loaded_model=StubModel(trained_on, MED7_KEYPOINTS))
        assert found.keypoint_names == MED7_KEYPOINTS and obs.found.shape == (1, 4)
        assert ("the model was trained on" in caplog.text) == warned, (trained_on, caplog.text)


def test_keypoints_option_must_name_the_model_keypoints(tmp_path):
    med7_path = lbr_urdf(tmp_path)
    robot = load_robot(med7_path, keypoints=MED7_KEYPOINTS)
    seq = _med7_sequence(tmp_path, robot)
    model = StubModel(str(med7_path), MED7_KEYPOINTS)
    same = load_model_robot(seq, model, str(med7_path), tuple(reversed(MED7_KEYPOINTS)))
    assert same.keypoint_names == MED7_KEYPOINTS           # the model's order
    with pytest.raises(InputError, match="contradicts the keypoints of the model"):
        load_model_robot(seq, model, str(med7_path), ("lbr_link_0", "lbr_link_1"))


def test_robot_names_compare_content_where_both_urdfs_are_here(tmp_path):
    """`dream adapt`, training data and `dream plan` compare robot references alike: the same
    file name on another machine passes, but two readable URDFs named alike of other content
    (robot.urdf of a UR5e and of a Panda) are two robots, and one file under two names is one."""
    from dream.robot.identity import same_robot_name

    (tmp_path / "ur5e").mkdir()
    (tmp_path / "panda").mkdir()
    (tmp_path / "ur5e" / "robot.urdf").write_text('<robot name="ur5e"/>')
    (tmp_path / "panda" / "robot.urdf").write_text('<robot name="panda"/>')
    (tmp_path / "copy.urdf").write_text('<robot name="ur5e"/>')
    assert not same_robot_name(str(tmp_path / "ur5e" / "robot.urdf"),
                               str(tmp_path / "panda" / "robot.urdf"))
    assert same_robot_name(str(tmp_path / "ur5e" / "robot.urdf"), str(tmp_path / "copy.urdf"))
    assert same_robot_name(str(tmp_path / "ur5e" / "robot.urdf"), "/elsewhere/robot.urdf")
