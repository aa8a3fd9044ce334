"""The robot folder follows the menagerie layout and the model compiles and steps cleanly."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import robots

FOLDER_FILES = ("j2s7s300.xml", "scene.xml", "README.md", "LICENSE", "CHANGELOG.md")


@pytest.mark.parametrize("filename", FOLDER_FILES)
def test_model_folder_has_menagerie_files(jaco, filename):
    assert (jaco.spec.description.parent / filename).is_file()


def test_scene_includes_robot_and_steps_without_warnings(jaco):
    model = mujoco.MjModel.from_xml_path(str(jaco.spec.description.parent / "scene.xml"))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.keyframe("home").id)
    for _ in range(500):
        mujoco.mj_step(model, data)
    assert np.all(data.warning.number == 0)
    # gravity compensation + zero velocity command: the arm holds the home pose.
    assert np.allclose(data.qpos[: jaco.nq], jaco.home, atol=2e-3)


def test_velocity_limits_and_ranges_match_fact_sheet(jaco):
    np.testing.assert_allclose(jaco.v_max, [0.6283] * 4 + [0.8378] * 3)
    np.testing.assert_allclose(jaco.q_lower[[1, 3, 5]], [0.8203, 0.5236, 1.1345])
    np.testing.assert_allclose(jaco.q_upper[[1, 3, 5]], [5.4629, 5.7596, 5.1487])
    assert np.all(np.isinf(jaco.q_lower[[0, 2, 4, 6]]))


def test_unknown_robot_lists_available():
    with pytest.raises(robots.UnknownRobot, match="available: jaco2, panda, ur5"):
        robots.load("ur10")


def test_unknown_frame_lists_available(jaco):
    with pytest.raises(robots.UnknownFrame, match="link_4"):
        jaco.frame_pose(jaco.home, "elbow")


@pytest.mark.parametrize("bad", [np.zeros(6), np.array([np.nan] * 7)])
def test_bad_configuration_is_rejected(jaco, bad):
    with pytest.raises(robots.InvalidConfiguration):
        jaco.kinematics(bad)


def test_stale_snapshot_is_refused(jaco):
    old = jaco.kinematics(jaco.home)
    jaco.kinematics(np.full(7, np.pi))
    with pytest.raises(robots.StaleKinematics):
        old.frame_position("end_effector")
