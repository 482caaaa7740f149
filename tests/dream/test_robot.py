"""Robot kinematics: URDF loading, registry, FK against MuJoCo, Jacobian, batching, errors."""

from __future__ import annotations

import itertools
import logging
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest

from dream.errors import InputError, RobotError
from dream.robot import (
    Robot,
    builtin_robots,
    load_robot,
    parse_urdf,
    resolve_resource,
    robot_data_dir,
)

POSITION_TOL_M = 1e-6
ROTATION_TOL = 1e-6
FD_STEP = 1e-6  # rad or m, central differences
FD_TOL = 1e-7  # m per rad; central-difference truncation error is ~ FD_STEP**2
MIN_KEYPOINT_SPACING_M = 0.05
BUILTIN = ("panda", "ur5", "xarm7")
PANDA_FINGER_KEYPOINTS = ("panda_link0", "panda_hand", "panda_leftfinger", "panda_rightfinger")

TWO_LINK_URDF = """<?xml version="1.0"?>
<robot name="toy">
  <link name="base"/>
  <link name="upper"/>
  <link name="slider"/>
  <link name="spinner"/>
  <link name="tip"/>
  <link name="twin"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="upper"/>
    <origin xyz="0 0 0.5" rpy="0.3 -0.2 0.1"/>
    <axis xyz="0 1 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/>
  </joint>
  <joint name="slide" type="prismatic">
    <parent link="upper"/><child link="slider"/>
    <origin xyz="0.4 0 0" rpy="0 0 0.5"/>
    <axis xyz="1 0 0"/>
    <limit lower="0" upper="0.2" effort="1" velocity="1"/>
  </joint>
  <joint name="spin" type="continuous">
    <parent link="slider"/><child link="spinner"/>
    <origin xyz="0 0.1 0" rpy="0 0 0"/>
    <axis xyz="0 0 1"/>
  </joint>
  <joint name="tip_fixed" type="fixed">
    <parent link="spinner"/><child link="tip"/>
    <origin xyz="0.1 0 0.05" rpy="0 1.0 0"/>
  </joint>
  <joint name="twin_spin" type="continuous">
    <parent link="slider"/><child link="twin"/>
    <origin xyz="0.05 -0.1 0" rpy="0 0 0"/>
    <axis xyz="0 0 1"/>
    <mimic joint="spin" multiplier="-2" offset="0.1"/>
  </joint>
</robot>
"""


# ----- helpers ---------------------------------------------------------------------------------

def _mujoco_model(urdf_path: Path) -> mujoco.MjModel:
    """MuJoCo model of a URDF's kinematics: geometry dropped, unit inertias, no body fusion."""
    root = ET.parse(urdf_path).getroot()
    for link in root.findall("link"):
        for tag in ("visual", "collision", "inertial"):
            for element in link.findall(tag):
                link.remove(element)
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "mass", value="0.1")
        ET.SubElement(inertial, "inertia", ixx="1e-3", iyy="1e-3", izz="1e-3",
                      ixy="0", ixz="0", iyz="0")
    extension = ET.Element("mujoco")
    ET.SubElement(extension, "compiler", fusestatic="false", discardvisual="false")
    root.insert(0, extension)
    return mujoco.MjModel.from_xml_string(ET.tostring(root, encoding="unicode"))


def _mujoco_poses(model: mujoco.MjModel, named: dict[str, float], base: str,
                  links: tuple[str, ...]) -> np.ndarray:
    """T_base_link (L, 4, 4) from MuJoCo for joint values by name (others at 0)."""
    data = mujoco.MjData(model)
    for name, value in named.items():
        data.qpos[model.joint(name).qposadr[0]] = value
    mujoco.mj_kinematics(model, data)
    R_world_base = data.body(base).xmat.reshape(3, 3)
    p_world_base = data.body(base).xpos
    T = np.tile(np.eye(4), (len(links), 1, 1))
    for n, link in enumerate(links):
        T[n, :3, :3] = R_world_base.T @ data.body(link).xmat.reshape(3, 3)
        T[n, :3, 3] = R_world_base.T @ (data.body(link).xpos - p_world_base)
    return T


def _finite_difference_jacobian(robot: Robot, q: np.ndarray) -> np.ndarray:
    columns = []
    for j in range(robot.num_joints):
        step = np.zeros(robot.num_joints)
        step[j] = FD_STEP
        columns.append((robot.forward_kinematics(q + step)
                        - robot.forward_kinematics(q - step)) / (2 * FD_STEP))
    return np.stack(columns, axis=-1)


@pytest.fixture
def toy_urdf(tmp_path: Path) -> Path:
    path = tmp_path / "toy.urdf"
    path.write_text(TWO_LINK_URDF)
    return path


# ----- agreement with MuJoCo -------------------------------------------------------------------

@pytest.mark.parametrize("name", BUILTIN)
def test_fk_matches_mujoco(name: str) -> None:
    robot = load_robot(name)
    model = _mujoco_model(robot.urdf_path)
    q = robot.sample_joints(np.random.default_rng(7), (4,))
    P_base = robot.forward_kinematics(q)
    T_base_link = robot.link_poses(q, robot.keypoint_names)
    for n in range(len(q)):
        expected = _mujoco_poses(model, dict(zip(robot.joint_names, q[n], strict=True)),
                                 robot.base_link, robot.keypoint_names)
        np.testing.assert_allclose(P_base[n], expected[:, :3, 3], atol=POSITION_TOL_M)
        np.testing.assert_allclose(T_base_link[n], expected, atol=ROTATION_TOL)


def test_mimic_fingers_match_mujoco() -> None:
    robot = load_robot("panda", keypoints=list(PANDA_FINGER_KEYPOINTS))
    assert robot.joint_names[-1] == "panda_finger_joint1"  # master of the mimic finger
    assert "panda_finger_joint2" not in robot.joint_names
    model = _mujoco_model(robot.urdf_path)
    q = robot.sample_joints(np.random.default_rng(3), (3,))
    P_base = robot.forward_kinematics(q)
    for n in range(len(q)):
        named = dict(zip(robot.joint_names, q[n], strict=True))
        named["panda_finger_joint2"] = named["panda_finger_joint1"]  # mimic, multiplier 1
        expected = _mujoco_poses(model, named, robot.base_link, robot.keypoint_names)
        np.testing.assert_allclose(P_base[n], expected[:, :3, 3], atol=POSITION_TOL_M)


def test_link_poses_of_non_keypoint_links_match_mujoco() -> None:
    robot = load_robot("ur5")
    model = _mujoco_model(robot.urdf_path)
    q = robot.sample_joints(np.random.default_rng(5))
    links = ("world", "base", "ee_link", "wrist_3_link")
    expected = _mujoco_poses(model, dict(zip(robot.joint_names, q, strict=True)),
                             robot.base_link, links)
    np.testing.assert_allclose(robot.link_poses(q, links), expected, atol=ROTATION_TOL)


def test_panda_fingers_rest_when_not_driven() -> None:
    robot = load_robot("panda")
    T = robot.link_poses(robot.rest_joints, ["panda_hand", "panda_leftfinger"])
    # finger joint at rest value 0: finger frame 0.0584 m along the hand's z axis
    offset_hand = np.linalg.inv(T[0]) @ T[1]
    np.testing.assert_allclose(offset_hand[:3, 3], [0, 0, 0.0584], atol=1e-12)


# ----- values and structure --------------------------------------------------------------------

def test_panda_keypoints_at_zero_joints() -> None:
    robot = load_robot("panda")
    assert robot.keypoint_names == ("panda_link0", "panda_link2", "panda_link3", "panda_link4",
                                    "panda_link6", "panda_link7", "panda_hand")
    assert robot.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    P = robot.forward_kinematics(np.zeros(7))
    expected = [[0, 0, 0], [0, 0, 0.333], [0, 0, 0.649], [0.0825, 0, 0.649], [0, 0, 1.033],
                [0.088, 0, 1.033], [0.088, 0, 0.926]]
    np.testing.assert_allclose(P, expected, atol=1e-12)
    assert robot.skeleton_edges == ((0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6))
    np.testing.assert_allclose(robot.joint_lower[[0, 3]], [-2.8973, -3.0718])
    np.testing.assert_allclose(robot.joint_upper[[0, 3]], [2.8973, -0.0698])


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_keypoints_are_distinct_and_spread(name: str) -> None:
    entry = {e.name: e for e in builtin_robots()}[name]
    assert entry.description and entry.rationale
    robot = load_robot(name)
    assert robot.keypoint_names[0] == robot.base_link == entry.base_link
    P = robot.forward_kinematics(robot.sample_joints(np.random.default_rng(0), (64,)))
    for a, b in itertools.combinations(range(robot.num_keypoints), 2):  # never coincident
        assert np.linalg.norm(P[:, a] - P[:, b], axis=-1).max() > MIN_KEYPOINT_SPACING_M
    for a, b in robot.skeleton_edges:  # neighbours along the arm: a fixed, visible spacing
        assert np.linalg.norm(P[:, a] - P[:, b], axis=-1).min() > MIN_KEYPOINT_SPACING_M


def test_registry_contents() -> None:
    names = [e.name for e in builtin_robots()]
    assert set(BUILTIN) <= set(names)
    assert load_robot("ur5").joint_names == ("shoulder_pan_joint", "shoulder_lift_joint",
                                             "elbow_joint", "wrist_1_joint", "wrist_2_joint",
                                             "wrist_3_joint")
    assert load_robot("xarm7").joint_names == tuple(f"joint{i}" for i in range(1, 8))
    assert load_robot("PANDA") is load_robot("panda")  # cached, case-insensitive


@pytest.mark.parametrize("name", BUILTIN)
def test_jacobian_matches_finite_differences(name: str) -> None:
    robot = load_robot(name)
    q = robot.sample_joints(np.random.default_rng(11), (3,))
    np.testing.assert_allclose(robot.keypoint_jacobian(q), _finite_difference_jacobian(robot, q),
                               atol=FD_TOL)


def test_jacobian_with_mimic_and_prismatic(toy_urdf: Path) -> None:
    robot = load_robot(toy_urdf, keypoints=["upper", "slider", "tip", "twin"])
    q = robot.sample_joints(np.random.default_rng(2), (5,))
    np.testing.assert_allclose(robot.keypoint_jacobian(q), _finite_difference_jacobian(robot, q),
                               atol=FD_TOL)
    finger_robot = load_robot("panda", keypoints=list(PANDA_FINGER_KEYPOINTS))
    q = finger_robot.sample_joints(np.random.default_rng(4), (2,))
    np.testing.assert_allclose(finger_robot.keypoint_jacobian(q),
                               _finite_difference_jacobian(finger_robot, q), atol=FD_TOL)


@pytest.mark.parametrize("batch", [(), (5,), (3, 4)])
def test_batch_shapes(batch: tuple[int, ...]) -> None:
    robot = load_robot("panda")
    q = robot.sample_joints(np.random.default_rng(1), batch)
    P = robot.forward_kinematics(q)
    T = robot.link_poses(q, ["panda_hand", "panda_link0"])
    J = robot.keypoint_jacobian(q)
    assert P.shape == batch + (7, 3)
    assert T.shape == batch + (2, 4, 4)
    assert J.shape == batch + (7, 3, 7)
    flat_q = q.reshape(-1, 7)
    for n, index in enumerate(np.ndindex(*batch)):
        np.testing.assert_allclose(P[index], robot.forward_kinematics(flat_q[n]), atol=1e-15)
        np.testing.assert_allclose(T[index], robot.link_poses(flat_q[n], ["panda_hand",
                                                                           "panda_link0"]))
        np.testing.assert_allclose(J[index], robot.keypoint_jacobian(flat_q[n]), atol=1e-15)


def test_joint_offsets_are_added_first() -> None:
    robot = load_robot("xarm7")
    rng = np.random.default_rng(9)
    q = robot.sample_joints(rng, (6,))
    offsets = rng.normal(0.0, 0.05, 7)
    np.testing.assert_allclose(robot.forward_kinematics(q, joint_offsets=offsets),
                               robot.forward_kinematics(q + offsets))
    np.testing.assert_allclose(robot.link_poses(q, ["link7"], joint_offsets=offsets),
                               robot.link_poses(q + offsets, ["link7"]))
    with pytest.raises(RobotError, match="joint_offsets"):
        robot.forward_kinematics(q, joint_offsets=np.zeros(3))


def test_origins_are_accessible_and_link_lengths_change() -> None:
    robot = load_robot("panda")
    origins = {j.name: j.origin for j in robot.chain_joints}
    np.testing.assert_allclose(origins["panda_joint3"][:3, 3], [0, -0.316, 0])
    assert "panda_joint8" in origins and "panda_finger_joint1" not in origins
    longer = robot.with_link_length_changes({"panda_joint3": 0.01})
    P = longer.forward_kinematics(np.zeros(7))
    np.testing.assert_allclose(P[2], [0, 0, 0.659], atol=1e-12)
    np.testing.assert_allclose(robot.forward_kinematics(np.zeros(7))[2], [0, 0, 0.649],
                               atol=1e-12)
    with pytest.raises(RobotError, match="zero origin offset"):
        robot.with_link_length_changes({"panda_joint2": 0.01})


# ----- joint vectors and errors ----------------------------------------------------------------

def test_joints_from_named_orders_and_ignores_extras() -> None:
    robot = load_robot("panda")
    names = ["panda_finger_joint1"] + [f"panda_joint{i}" for i in (7, 6, 5, 4, 3, 2, 1)]
    values = np.array([[0.04, 7, 6, 5, 4, 3, 2, 1], [0.0, 70, 60, 50, 40, 30, 20, 10]])
    np.testing.assert_allclose(robot.joints_from_named(names, values),
                               [[1, 2, 3, 4, 5, 6, 7], [10, 20, 30, 40, 50, 60, 70]])
    with pytest.raises(RobotError, match="panda_joint3"):
        robot.joints_from_named(names[:5] + names[6:], values[:, [0, 1, 2, 3, 4, 6, 7]])
    with pytest.raises(RobotError, match="repeat"):
        robot.joints_from_named(names[:-1] + ["panda_joint2"], values)


def test_bad_joint_vectors_raise() -> None:
    robot = load_robot("panda")
    with pytest.raises(RobotError, match="expects 7 joint values.*panda_joint1"):
        robot.forward_kinematics(np.zeros(6))
    with pytest.raises(RobotError, match="panda_joint3.*finite"):
        robot.forward_kinematics([0, 0, np.nan, 0, 0, 0, 0])
    with pytest.raises(RobotError, match="panda_joint7"):
        robot.keypoint_jacobian(np.array([[0, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0, np.inf]]))
    with pytest.raises(RobotError, match="not numbers"):
        robot.validate_joints(["a"] * 7)


def test_unknown_names_raise() -> None:
    with pytest.raises(RobotError, match="unknown robot 'kuka'.*panda, ur5, xarm7"):
        load_robot("kuka")
    robot = load_robot("panda")
    with pytest.raises(RobotError, match="unknown link 'gripper'.*panda_hand"):
        robot.link_poses(np.zeros(7), ["gripper"])
    with pytest.raises(RobotError, match="unknown keypoint link 'gripper'.*panda_link0"):
        robot.with_keypoints(["panda_link0", "gripper"])
    with pytest.raises(RobotError, match="unknown base link"):
        load_robot("panda", base_link="table")
    with pytest.raises(RobotError, match="not attached below base link"):
        load_robot("panda", keypoints=["panda_link0"], base_link="panda_link3")


def test_with_keypoints_changes_joints() -> None:
    robot = load_robot("panda").with_keypoints(["panda_link0", "panda_link4"])
    # joints on the chain count, even joint4 whose rotation leaves link4's origin in place
    assert robot.joint_names == ("panda_joint1", "panda_joint2", "panda_joint3", "panda_joint4")
    assert robot.skeleton_edges == ((0, 1),)
    assert robot.forward_kinematics(np.zeros((2, 4))).shape == (2, 2, 3)
    np.testing.assert_array_equal(robot.keypoint_jacobian(np.zeros(4))[..., 3], 0.0)


# ----- user URDFs and files --------------------------------------------------------------------

def test_user_urdf(toy_urdf: Path) -> None:
    with pytest.raises(RobotError, match="keypoint links: pass --keypoints.*dream robots --urdf "
                                         ".*toy.urdf lists its 6 links"):
        load_robot(str(toy_urdf))
    robot = load_robot(str(toy_urdf), keypoints=["base", "tip", "twin"])
    assert robot.name == "toy" and robot.base_link == "base"
    assert robot.joint_names == ("shoulder", "slide", "spin")
    np.testing.assert_allclose(robot.joint_lower, [-1, 0, -np.pi])
    np.testing.assert_allclose(robot.joint_upper, [1, 0.2, np.pi])
    assert robot.skeleton_edges == ((0, 1), (0, 2))
    tree = parse_urdf(toy_urdf)
    q = np.array([0.7, 0.15, -2.0])
    model = _mujoco_model(toy_urdf)
    named = dict(zip(robot.joint_names, q, strict=True))
    named["twin_spin"] = -2.0 * named["spin"] + 0.1
    expected = _mujoco_poses(model, named, "base", ("tip", "twin"))
    np.testing.assert_allclose(robot.link_poses(q, ["tip", "twin"]), expected, atol=ROTATION_TOL)
    assert tree.root == "base"


def test_user_urdf_base_link_below_root(toy_urdf: Path) -> None:
    robot = load_robot(toy_urdf, keypoints=["slider", "tip"], base_link="upper")
    assert robot.joint_names == ("slide", "spin")
    full = load_robot(toy_urdf, keypoints=["upper", "slider", "tip"])
    q = np.array([0.4, 0.1, 0.3])
    T = full.link_poses(q, ["upper", "slider", "tip"])
    expected = np.linalg.inv(T[0]) @ T[1:]
    np.testing.assert_allclose(robot.link_poses(q[1:], ["slider", "tip"]), expected, atol=1e-12)
    # links above the base are reached through the root, with undriven joints at rest
    T_upper_base = robot.link_poses(q[1:], ["base"])[0]
    T_base_upper_rest = full.link_poses([0.0, 0.1, 0.3], ["upper"])[0]
    np.testing.assert_allclose(T_upper_base, np.linalg.inv(T_base_upper_rest), atol=1e-12)


def test_bad_urdf_files_raise(tmp_path: Path) -> None:
    missing = tmp_path / "missing.urdf"
    with pytest.raises(InputError, match="missing.urdf"):
        load_robot(str(missing), keypoints=["a"])
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='x'><link name='a'></robot>")
    with pytest.raises(InputError, match="broken.urdf.*not valid XML"):
        load_robot(str(broken), keypoints=["a"])
    dangling = tmp_path / "dangling.urdf"
    dangling.write_text("<robot name='x'><link name='a'/><joint name='j' type='fixed'>"
                        "<parent link='a'/><child link='b'/></joint></robot>")
    with pytest.raises(InputError, match="dangling.urdf.*unknown link 'b'"):
        load_robot(str(dangling), keypoints=["a"])
    odd = tmp_path / "odd.urdf"
    odd.write_text("<robot name='x'><link name='a'/><link name='b'/><joint name='j' type='ball'>"
                   "<parent link='a'/><child link='b'/></joint></robot>")
    with pytest.raises(InputError, match="odd.urdf.*type 'ball'"):
        load_robot(str(odd), keypoints=["a"])
    nameless = tmp_path / "nameless.urdf"  # as a xacro-generated file left empty ships
    nameless.write_text("<?xml version='1.0'?><robot xmlns:xacro='http://wiki.ros.org/xacro'>"
                        "</robot>")
    with pytest.raises(InputError, match="nameless.urdf.*<robot> element has no name"):
        load_robot(str(nameless), keypoints=["a"])


def test_mimic_of_a_missing_joint_is_read_as_independent(toy_urdf: Path, caplog) -> None:
    broken = toy_urdf.with_name("broken_mimic.urdf")
    broken.write_text(TWO_LINK_URDF.replace('mimic joint="spin"', 'mimic joint="spinner_joint"'))
    with caplog.at_level(logging.WARNING, logger="dream.robot.urdf"):
        robot = load_robot(broken, keypoints=["upper", "tip", "twin"])
    assert "twin_spin -> spinner_joint" in caplog.text and "broken_mimic.urdf" in caplog.text
    assert "twin_spin" in robot.joint_names  # drives a keypoint now, as any joint would
    q = robot.sample_joints(np.random.default_rng(0), (3,))
    moved = q.copy()
    moved[:, robot.joint_names.index("spin")] += 0.5  # no longer turns the twin
    np.testing.assert_allclose(robot.link_poses(moved, "twin"), robot.link_poses(q, "twin"),
                               atol=ROTATION_TOL)
    moved[:, robot.joint_names.index("twin_spin")] += 0.5  # the twin's own joint does
    assert not np.allclose(robot.link_poses(moved, "twin"), robot.link_poses(q, "twin"))


def test_package_uri_resolves_to_example_robot_data() -> None:
    robot = load_robot("panda")
    mesh = resolve_resource(
        "package://example-robot-data/robots/panda_description/meshes/visual/link0.dae",
        robot.urdf_path)
    assert mesh.is_file()
    assert mesh.is_relative_to(robot_data_dir())
    with pytest.raises(InputError, match="not found"):
        resolve_resource("package://example-robot-data/nothing/here.stl", robot.urdf_path)
    relative = resolve_resource("../meshes/visual/link0.dae", robot.urdf_path)
    assert relative.resolve() == mesh.resolve()


def _mesh_tree(root: Path, package_dir: Path) -> Path:
    """A URDF under `root/robot/urdf` and a mesh file under `package_dir/meshes`."""
    mesh = package_dir / "meshes" / "link.stl"
    mesh.parent.mkdir(parents=True)
    mesh.write_text("solid link\nendsolid link\n")
    urdf = root / "robot" / "urdf" / "r.urdf"
    urdf.parent.mkdir(parents=True)
    urdf.write_text("<robot name='r'/>")
    return urdf


def test_package_uri_with_three_slashes_reads_as_two() -> None:
    urdf = load_robot("panda").urdf_path
    mesh = resolve_resource(
        "package:///example-robot-data/robots/panda_description/meshes/visual/link0.dae", urdf)
    assert mesh.name == "link0.dae"
    assert mesh.is_relative_to(robot_data_dir())


def test_package_uri_found_through_ros_package_path(tmp_path: Path, monkeypatch) -> None:
    package = tmp_path / "ws" / "src" / "group" / "my_arm_description"
    urdf = _mesh_tree(tmp_path, package)
    (package / "package.xml").write_text("<package><name>my_arm_description</name></package>")
    uri = "package://my_arm_description/meshes/link.stl"
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    with pytest.raises(InputError, match="ROS_PACKAGE_PATH"):
        resolve_resource(uri, urdf)
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "ws" / "src"))
    assert resolve_resource(uri, urdf) == package / "meshes" / "link.stl"


def test_package_uri_found_through_ament_prefix_path(tmp_path: Path, monkeypatch) -> None:
    package = tmp_path / "install" / "share" / "my_arm_description"
    urdf = _mesh_tree(tmp_path, package)
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    monkeypatch.setenv("AMENT_PREFIX_PATH", f"/nonexistent:{tmp_path / 'install'}")
    assert (resolve_resource("package://my_arm_description/meshes/link.stl", urdf)
            == package / "meshes" / "link.stl")


def test_package_checked_out_under_another_name_is_found_above_the_urdf(tmp_path: Path,
                                                                         monkeypatch) -> None:
    # the package `my_arm_description` cloned as folder `robot`: the mesh beside urdf/
    urdf = _mesh_tree(tmp_path, tmp_path / "robot")
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    assert (resolve_resource("package://my_arm_description/meshes/link.stl", urdf)
            == tmp_path / "robot" / "meshes" / "link.stl")
    with pytest.raises(InputError, match="parent folders"):
        resolve_resource("package://my_arm_description/meshes/other.stl", urdf)
