"""The Panda and UR5 description files are the example-robot-data package's, changed only as their READMEs say."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import robots
from robots.description import package_search_path, resolve_package_uri

PACKAGE = "package://example-robot-data/robots/"


def _package_file(rest: str):
    return resolve_package_uri(PACKAGE + rest, package_search_path())


def test_ur5_urdf_is_the_package_file_verbatim():
    ours = robots.load("ur5").spec.description
    assert ours.read_bytes() == _package_file("ur_description/urdf/ur5_robot.urdf").read_bytes()


def test_panda_urdf_has_the_package_kinematics_with_the_fingers_closed():
    ours = robots.load("panda")
    theirs = pin.buildModelFromUrdf(str(_package_file("panda_description/urdf/panda.urdf")))
    data = theirs.createData()
    assert theirs.nq == ours.nq + 2  # the two prismatic finger joints, fixed in ours
    assert list(theirs.names[1:8]) == list(ours.joint_names)
    np.testing.assert_array_equal(theirs.velocityLimit[:7], ours.v_max)
    np.testing.assert_array_equal(theirs.lowerPositionLimit[:7], ours.q_lower)
    np.testing.assert_array_equal(theirs.upperPositionLimit[:7], ours.q_upper)
    rng = np.random.default_rng(0)
    frames = [f.name for f in theirs.frames if f.type == pin.FrameType.BODY]
    assert set(frames) == set(ours.frame_names)
    for _ in range(20):
        q = rng.uniform(ours.q_lower, ours.q_upper)
        pin.framesForwardKinematics(theirs, data, np.concatenate([q, [0.0, 0.0]]))
        kin = ours.kinematics(q)
        for name in frames:
            np.testing.assert_allclose(kin.frame_pose(name), data.oMf[theirs.getFrameId(name)].homogeneous, atol=1e-12)


@pytest.mark.parametrize("folder", ["franka_panda", "universal_robots_ur5", "workcell"])
def test_model_folders_have_a_readme_and_the_robot_ones_a_license_and_changelog(folder):
    root = robots.load("panda").spec.description.parent.parent / folder
    assert (root / "README.md").is_file()
    if folder != "workcell":
        assert (root / "LICENSE").is_file() and (root / "CHANGELOG.md").is_file()
