"""Loading a description: velocity limits never read from actuators, and every problem one RobotError.

Small hand-written MJCF / URDF files: a two-link arm driven by position servos, by torque motors,
by velocity servos; a scene with ``<include>``; pinocchio 4.1.0's dropped first-body pose; a
prismatic joint; a URDF joint without ``<limit velocity>``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import robots
from robots import InvalidDescription, Robot, RobotError, RobotSpec

ARM = """
<mujoco model="two_link">
  <compiler angle="radian"/>
  <worldbody>
    <body name="base">
      <geom type="cylinder" size="0.05 0.05"/>
      <body name="link1" pos="0 0 0.1">
        <joint name="j1" axis="0 0 1" range="-2 2"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
        <body name="link2" pos="0.3 0 0">
          <joint name="j2" axis="0 1 0" range="-1.5 1.5"/>
          <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.025"/>
          <body name="tip" pos="0.25 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>{actuators}</actuator>
  <keyframe><key name="home" qpos="0.3 -0.4"/></keyframe>
</mujoco>
"""
POSITION_SERVOS = '<position joint="j1" kp="50" ctrlrange="-2 2"/><position joint="j2" kp="50" ctrlrange="-1.5 1.5"/>'
TORQUE_MOTORS = '<motor joint="j1" ctrlrange="-320 320"/><motor joint="j2" ctrlrange="-176 176"/>'
VELOCITY_SERVOS = (
    '<velocity joint="j1" kv="10" ctrlrange="-0.018 0.018"/><velocity joint="j2" kv="10" ctrlrange="-9 9"/>'
)


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _mjcf_spec(path: Path, **kw: object) -> RobotSpec:
    return RobotSpec(description=path, ee_frame="tip", control_points=("link2",), **kw)


@pytest.mark.parametrize("actuators", [POSITION_SERVOS, TORQUE_MOTORS, VELOCITY_SERVOS, ""])
def test_mjcf_velocity_limits_come_from_the_spec_whatever_the_actuators(tmp_path, actuators):
    path = _write(tmp_path, "arm.xml", ARM.format(actuators=actuators))
    arm = Robot("arm", _mjcf_spec(path, velocity_limits=(1.5, 2.5)))
    # Not 2 / 1.5 (position ranges), not 320 / 176 (torques), not 0.018 / 9 (servo ranges).
    np.testing.assert_array_equal(arm.v_max, [1.5, 2.5])


@pytest.mark.parametrize("actuators", [POSITION_SERVOS, TORQUE_MOTORS, VELOCITY_SERVOS])
def test_mjcf_without_velocity_limits_is_a_clear_robot_error(tmp_path, actuators):
    path = _write(tmp_path, "arm.xml", ARM.format(actuators=actuators))
    with pytest.raises(InvalidDescription, match="no joint velocity limits.*velocity_limits") as err:
        Robot("arm", _mjcf_spec(path))
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def test_wrong_number_of_velocity_limits_is_refused(tmp_path):
    path = _write(tmp_path, "arm.xml", ARM.format(actuators=""))
    with pytest.raises(InvalidDescription, match="3 values for 2 joints"):
        Robot("arm", _mjcf_spec(path, velocity_limits=(1.0, 1.0, 1.0)))


@pytest.mark.parametrize("bad", [(0.0, 1.0), (-1.0, 1.0), (np.inf, 1.0)])
def test_impossible_velocity_limits_are_refused_in_the_spec(tmp_path, bad):
    with pytest.raises(robots.InvalidSpec, match="velocity_limits"):
        _mjcf_spec(tmp_path / "arm.xml", velocity_limits=bad)


def test_a_scene_with_include_is_refused(tmp_path):
    _write(tmp_path, "arm.xml", ARM.format(actuators=""))
    scene = _write(tmp_path, "scene.xml", '<mujoco><include file="arm.xml"/></mujoco>')
    with pytest.raises(InvalidDescription, match="<include file='arm.xml'>.*robot's own file"):
        Robot("scene", _mjcf_spec(scene, velocity_limits=(1.0, 1.0)))


def test_pinocchio_dropping_a_rotated_first_body_pose_is_caught(tmp_path):
    # pinocchio 4.1.0's MJCF parser drops the pose of a first jointless body with a rotation:
    # the arm would sit 0.2 m lower and turned in pinocchio than in MuJoCo.
    rotated = ARM.format(actuators="").replace(
        '<body name="base">', '<body name="base" pos="0 0 0.2" quat="0.7071068 0.7071068 0 0">'
    )
    path = _write(tmp_path, "rotated.xml", rotated)
    try:
        Robot("rotated", _mjcf_spec(path, velocity_limits=(1.0, 1.0)))
    except InvalidDescription as exc:
        assert "MuJoCo and pinocchio disagree on frame" in str(exc) and "\n" not in str(exc)
    else:  # a pinocchio with the upstream fix: then both libraries really agree
        arm = robots.Robot("rotated", _mjcf_spec(path, velocity_limits=(1.0, 1.0)))
        np.testing.assert_allclose(arm.frame_position(np.zeros(2), "base"), [0.0, 0.0, 0.2], atol=1e-12)


def test_a_prismatic_joint_is_refused(tmp_path):
    slider = ARM.format(actuators="").replace(
        '<joint name="j2" axis="0 1 0"', '<joint name="j2" type="slide" axis="0 1 0"'
    )
    path = _write(tmp_path, "slider.xml", slider)
    with pytest.raises(InvalidDescription, match="joint 'j2' is JointModelP.*only revolute"):
        Robot("slider", _mjcf_spec(path, velocity_limits=(1.0, 1.0)))


INERTIAL = '<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'
CYLINDER = '<origin xyz="0.15 0 0" rpy="0 1.5708 0"/><geometry><cylinder radius="0.03" length="0.3"/></geometry>'
URDF = """<?xml version="1.0"?>
<robot name="two_link">
  <link name="base">INERTIAL</link>
  <link name="link1">INERTIAL<collision>CYLINDER</collision></link>
  <link name="link2">INERTIAL</link>
  <link name="tip"/>
  <joint name="j1" type="{type1}"><parent link="base"/><child link="link1"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="10" {velocity1}/></joint>
  <joint name="j2" type="revolute"><parent link="link1"/><child link="link2"/>
    <origin xyz="0.3 0 0" rpy="0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="10" velocity="2.5"/>
  </joint>
  <joint name="tip_joint" type="fixed"><parent link="link2"/><child link="tip"/><origin xyz="0.25 0 0"/></joint>
</robot>
""".replace("INERTIAL", INERTIAL).replace("CYLINDER", CYLINDER)


def _urdf_spec(path: Path, **kw: object) -> RobotSpec:
    return RobotSpec(description=path, ee_frame="tip", control_points=("link2",), home=(0.3, -0.4), **kw)


def test_urdf_velocity_limits_are_its_limit_velocity(tmp_path):
    path = _write(tmp_path, "arm.urdf", URDF.format(type1="revolute", velocity1='velocity="1.5"'))
    arm = Robot("arm", _urdf_spec(path))
    np.testing.assert_array_equal(arm.v_max, [1.5, 2.5])
    # The spec overrides the description.
    np.testing.assert_array_equal(Robot("arm", _urdf_spec(path, velocity_limits=(0.5, 0.6))).v_max, [0.5, 0.6])
    # Every link is a frame, fixed ones included (MuJoCo would fuse "tip" into link2 by default).
    assert {"base", "link1", "link2", "tip"} <= set(arm.frame_names)
    assert "tip" in [arm.mj_model.body(b).name for b in range(arm.mj_model.nbody)]


def test_urdf_joint_without_limit_velocity_is_named(tmp_path):
    # (urdfdom itself refuses a <limit> without velocity; velocity="0" parses and means none.)
    path = _write(tmp_path, "arm.urdf", URDF.format(type1="revolute", velocity1='velocity="0"'))
    with pytest.raises(InvalidDescription, match="joint 'j1' has no <limit velocity>"):
        Robot("arm", _urdf_spec(path))


def test_urdf_continuous_joint_is_refused(tmp_path):
    path = _write(tmp_path, "arm.urdf", URDF.format(type1="continuous", velocity1='velocity="1.5"'))
    with pytest.raises(InvalidDescription, match="joint 'j1' is a continuous joint"):
        Robot("arm", _urdf_spec(path))


def test_home_outside_the_limits_is_refused(tmp_path):
    path = _write(tmp_path, "arm.urdf", URDF.format(type1="revolute", velocity1='velocity="1.5"'))
    spec = RobotSpec(description=path, ee_frame="tip", control_points=("link2",), home=(0.3, -1.6))
    with pytest.raises(InvalidDescription, match=r"home q2 = -1.6 rad is outside \[-1.5, 1.5\]"):
        Robot("arm", spec)


def test_spec_frames_must_exist(tmp_path):
    path = _write(tmp_path, "arm.urdf", URDF.format(type1="revolute", velocity1='velocity="1.5"'))
    spec = RobotSpec(description=path, ee_frame="tool0", control_points=("link2",), home=(0.0, 0.0))
    with pytest.raises(InvalidDescription, match="spec frame 'tool0' is not in the description; frames: .*tip"):
        Robot("arm", spec)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("not xml <", "not valid XML"),
        ("<sdf version='1.7'/>", "neither <mujoco>"),
    ],
)
def test_unreadable_descriptions_are_one_line_errors(tmp_path, text, match):
    path = _write(tmp_path, "arm.xml", text)
    with pytest.raises(RobotError, match=match) as err:
        Robot("arm", _mjcf_spec(path, velocity_limits=(1.0, 1.0)))
    assert "\n" not in str(err.value)


def test_missing_description_file(tmp_path):
    with pytest.raises(InvalidDescription, match="no such description file"):
        Robot("arm", _mjcf_spec(tmp_path / "nowhere.xml", velocity_limits=(1.0, 1.0)))
