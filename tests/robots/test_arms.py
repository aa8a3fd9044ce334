"""Every shipped arm: MuJoCo = pinocchio on every frame, published kinematics, Jacobians, frames by name.

Independent references: MuJoCo's own forward kinematics of the same file; Franka's published
modified Denavit–Hartenberg table of the Panda; Universal Robots' published DH table of the UR5;
finite differences.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import robots
from tests.conftest import random_configuration

ARMS = ("jaco2", "panda", "ur5")


@pytest.fixture(scope="module", params=ARMS)
def arm(request) -> robots.Robot:
    return robots.load(request.param)


def test_mujoco_and_pinocchio_agree_on_every_frame(arm):
    rng = np.random.default_rng(10)
    data = mujoco.MjData(arm.mj_model)
    bodies = {arm.mj_model.body(b).name for b in range(1, arm.mj_model.nbody)}
    full = {name: arm.spec.prefix + name if arm.spec.prefix + name in bodies else name for name in arm.frame_names}
    # Every body frame of pinocchio is a MuJoCo body (URDF links are kept: fusestatic off), but
    # the URDF's "world" link, which MuJoCo merges into its world body.
    compared = [n for n in arm.frame_names if full[n] in bodies]
    assert set(arm.frame_names) - set(compared) <= {"world"}
    assert len(compared) >= arm.nq + 2
    for _ in range(30):
        q = random_configuration(arm, rng, inset=0.0)
        data.qpos[:] = q
        mujoco.mj_kinematics(arm.mj_model, data)
        kin = arm.kinematics(q)
        for name in compared:
            body = arm.mj_model.body(full[name]).id
            np.testing.assert_allclose(kin.frame_position(name), data.xpos[body], atol=1e-9, err_msg=name)
            np.testing.assert_allclose(kin.frame_rotation(name), data.xmat[body].reshape(3, 3), atol=1e-9)


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _tx(a: float) -> np.ndarray:
    out = np.eye(4)
    out[0, 3] = a
    return out


def _tz(d: float) -> np.ndarray:
    out = np.eye(4)
    out[2, 3] = d
    return out


# Franka Emika, "Robot and interface specifications", Denavit–Hartenberg parameters (Craig's
# modified convention: T_i = RotX(alpha) TransX(a) RotZ(theta_i) TransZ(d)): (a [m], d [m], alpha [rad]).
PANDA_MDH = (
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -np.pi / 2),
    (0.0, 0.316, np.pi / 2),
    (0.0825, 0.0, np.pi / 2),
    (-0.0825, 0.384, -np.pi / 2),
    (0.0, 0.0, np.pi / 2),
    (0.088, 0.0, np.pi / 2),
)
PANDA_FLANGE_D = 0.107  # "Flange" row: a = 0, d = 0.107 m, alpha = 0, theta = 0


def panda_flange(q: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    for (a, d, alpha), theta in zip(PANDA_MDH, q, strict=True):
        pose = pose @ _rx(alpha) @ _tx(a) @ _rz(theta) @ _tz(d)
    return pose @ _tz(PANDA_FLANGE_D)


def test_panda_link8_is_franka_s_published_flange_kinematics():
    panda = robots.load("panda")
    rng = np.random.default_rng(0)
    for _ in range(200):
        q = rng.uniform(panda.q_lower, panda.q_upper)
        pose = panda.frame_pose(q, "panda_link8")
        reference = panda_flange(q)
        np.testing.assert_allclose(pose[:3, 3], reference[:3, 3], atol=1e-6)
        np.testing.assert_allclose(pose[:3, :3], reference[:3, :3], atol=1e-6)


# Universal Robots, "DH parameters for calculations of kinematics and dynamics", UR5 (standard DH:
# T_i = RotZ(theta_i) TransZ(d) TransX(a) RotX(alpha)): (a [m], d [m], alpha [rad]). Frames of the
# UR controller: base = the URDF's "base" link, flange with zero TCP = "tool0".
UR5_DH = (
    (0.0, 0.089159, np.pi / 2),
    (-0.425, 0.0, 0.0),
    (-0.39225, 0.0, 0.0),
    (0.0, 0.10915, np.pi / 2),
    (0.0, 0.09465, -np.pi / 2),
    (0.0, 0.0823, 0.0),
)


def ur5_tool(q: np.ndarray) -> np.ndarray:
    pose = np.eye(4)
    for (a, d, alpha), theta in zip(UR5_DH, q, strict=True):
        pose = pose @ _rz(theta) @ _tz(d) @ _tx(a) @ _rx(alpha)
    return pose


def test_ur5_tool0_is_universal_robots_published_kinematics():
    ur5 = robots.load("ur5")
    rng = np.random.default_rng(1)
    for _ in range(200):
        q = rng.uniform(-np.pi, np.pi, 6)
        pose = np.linalg.inv(ur5.frame_pose(q, "base")) @ ur5.frame_pose(q, "tool0")
        reference = ur5_tool(q)
        # 1e-9: the URDF writes pi/2 as 1.57079632679
        np.testing.assert_allclose(pose[:3, 3], reference[:3, 3], atol=1e-9)
        np.testing.assert_allclose(pose[:3, :3], reference[:3, :3], atol=1e-9)


def _numeric_jacobian(arm: robots.Robot, q: np.ndarray, frame: str, eps: float = 1e-6) -> np.ndarray:
    cols = []
    rot = arm.frame_pose(q, frame)[:3, :3]
    for k in range(arm.nq):
        dq = np.zeros(arm.nq)
        dq[k] = eps
        plus, minus = arm.frame_pose(q + dq, frame), arm.frame_pose(q - dq, frame)
        lin = (plus[:3, 3] - minus[:3, 3]) / (2 * eps)
        d_rot = (plus[:3, :3] - minus[:3, :3]) / (2 * eps) @ rot.T
        cols.append(np.concatenate([lin, [d_rot[2, 1], d_rot[0, 2], d_rot[1, 0]]]))
    return np.array(cols).T


def test_ee_and_control_point_jacobians_match_finite_differences(arm):
    rng = np.random.default_rng(2)
    for frame in (arm.ee_frame, *arm.control_points):
        for _ in range(5):
            q = random_configuration(arm, rng)
            np.testing.assert_allclose(arm.frame_jacobian(q, frame), _numeric_jacobian(arm, q, frame), atol=1e-6)


def test_control_point_partial_jacobian_uses_the_joints_before_it(arm):
    rng = np.random.default_rng(3)
    q = random_configuration(arm, rng)
    for frame in arm.control_points:
        j = arm.frame_joint(frame)
        partial = arm.partial_position_jacobian(q, frame)
        assert np.all(partial[:, j - 1 :] == 0.0)
        np.testing.assert_allclose(partial[:, : j - 1], arm.position_jacobian(q, frame)[:, : j - 1])


@pytest.mark.parametrize(
    ("name", "frames"),
    [
        ("panda", ("panda_link0", "panda_link4", "panda_link8", "panda_hand", "panda_hand_tcp", "panda_leftfinger")),
        ("ur5", ("base_link", "base", "shoulder_link", "forearm_link", "wrist_3_link", "ee_link", "tool0")),
        ("jaco2", ("link_base", "j2s7s300_link_4", "end_effector", "j2s7s300_end_effector")),
    ],
)
def test_frames_are_reachable_by_their_description_names(name, frames):
    arm = robots.load(name)
    for frame in frames:
        assert np.all(np.isfinite(arm.frame_position(arm.home, frame)))
    assert len({arm.frame_id(f) for f in frames}) == len(frames) - (name == "jaco2")  # two spellings of one


def test_velocity_limits_are_the_descriptions(arm):
    expected = {
        # franka_ros URDF <limit velocity>: 2.175 rad/s (joints 1-4), 2.61 rad/s (5-7)
        "panda": [2.175] * 4 + [2.61] * 3,
        # ur_description URDF: 3.15 rad/s (joints 1-3), 3.2 rad/s (4-6)
        "ur5": [3.15] * 3 + [3.2] * 3,
        # kinova-ros URDF (robots/kinova_j2s7s300/README.md), given in the spec: an MJCF has none
        "jaco2": [0.6283] * 4 + [0.8378] * 3,
    }[arm.name]
    np.testing.assert_array_equal(arm.v_max, expected)


def test_home_is_inside_the_limits_and_above_the_table(arm):
    assert np.all(arm.home > arm.q_lower) and np.all(arm.home < arm.q_upper)
    kin = arm.kinematics(arm.home)
    assert all(kin.frame_position(f)[2] > 0.1 for f in (arm.ee_frame, *arm.control_points))
