"""Jaco² forward kinematics against its facts, MuJoCo and finite differences.

The reference poses are those of ``robots/kinova_j2s7s300/README.md`` ("Kinematic facts", from
kinova-ros 924781d3); :func:`test_reference_poses_are_the_model_readme_s` keeps the two equal.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

import robots
from tests.conftest import random_configuration

PI = np.pi
FRAMES = ("link_4", "link_6", "link_7", "end_effector")
README = Path(robots.__file__).parent / "kinova_j2s7s300" / "README.md"

# Reference poses of robots/kinova_j2s7s300/README.md (forward kinematics of the kinova-ros URDF).
REFERENCE = [
    (
        np.zeros(7),
        {"link_4": (0, 0.0016, -0.1345), "link_6": (0, -0.0098, 0.17655), "end_effector": (0, -0.0098, -0.0872)},
    ),
    (
        np.full(7, PI),
        {"link_4": (0, -0.0016, 0.6855), "link_6": (0, -0.013, 0.99655), "end_effector": (0, -0.013, 1.2603)},
    ),
    (np.array([0, PI / 2, PI, PI, PI, PI, PI]), {"end_effector": (0.9848, 0.013, 0.2755)}),
    (np.array([4.71, 2.84, 0, 0.75, 4.62, 4.48, 4.88]), {"end_effector": (0.2659, -0.2121, 0.5031)}),
]


def _readme_number(value: float) -> str:
    text = f"{value:g}"
    return text.replace("-", "−")


@pytest.mark.parametrize(("q", "expected"), REFERENCE)
def test_reference_poses_are_the_model_readme_s(q, expected):
    readme = README.read_text(encoding="utf-8")
    for position in expected.values():
        cell = "(" + ", ".join(_readme_number(v) for v in position) + ")"
        assert cell in readme, f"{cell} not in {README.name}"


@pytest.mark.parametrize(("q", "expected"), REFERENCE)
def test_fk_matches_fact_sheet_reference_poses(jaco, q, expected):
    for frame, position in expected.items():
        np.testing.assert_allclose(jaco.frame_position(q, frame), position, atol=1e-4)


def test_ee_rotation_at_zero_and_candle(jaco):
    np.testing.assert_allclose(
        jaco.frame_pose(np.zeros(7), "end_effector")[:3, :3], [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=1e-9
    )
    np.testing.assert_allclose(
        jaco.frame_pose(np.full(7, PI), "end_effector")[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-9
    )


def test_hand_computed_elbow_bend(jaco):
    # Candle with joint 2 at π/2: the whole arm lies along +x at shoulder height 0.2755 m.
    # Elbow (link_4 origin) = 0.41 m out; lateral offsets −0.0016 (link_1) on y.
    q = np.array([0, PI / 2, PI, PI, PI, PI, PI])
    np.testing.assert_allclose(jaco.frame_position(q, "link_4"), (0.41, 0.0016, 0.2755), atol=1e-9)
    # Wrist (link_6): + 0.2073 + 0.10375 further out, offsets 0.0016 + 0.0114 on y.
    np.testing.assert_allclose(jaco.frame_position(q, "link_6"), (0.72105, 0.013, 0.2755), atol=1e-9)


def test_mujoco_and_pinocchio_agree_on_random_configurations(jaco):
    rng = np.random.default_rng(0)
    data = mujoco.MjData(jaco.mj_model)
    for _ in range(50):
        q = rng.uniform(-2 * PI, 2 * PI, size=7)
        data.qpos[:] = q
        mujoco.mj_kinematics(jaco.mj_model, data)
        kin = jaco.kinematics(q)
        for frame in FRAMES:
            body = jaco.mj_model.body("j2s7s300_" + frame)
            np.testing.assert_allclose(kin.frame_position(frame), data.xpos[body.id], atol=1e-9)
            np.testing.assert_allclose(kin.frame_rotation(frame), data.xmat[body.id].reshape(3, 3), atol=1e-9)


def _numeric_jacobian(jaco, q, frame, eps=1e-6):
    cols = []
    for k in range(7):
        dq = np.zeros(7)
        dq[k] = eps
        plus, minus = jaco.frame_pose(q + dq, frame), jaco.frame_pose(q - dq, frame)
        lin = (plus[:3, 3] - minus[:3, 3]) / (2 * eps)
        # angular velocity: (dR Rᵀ)^∨
        d_rot = (plus[:3, :3] - minus[:3, :3]) / (2 * eps) @ jaco.frame_pose(q, frame)[:3, :3].T
        ang = np.array([d_rot[2, 1], d_rot[0, 2], d_rot[1, 0]])
        cols.append(np.concatenate([lin, ang]))
    return np.array(cols).T


@pytest.mark.parametrize("frame", FRAMES)
def test_frame_jacobian_matches_finite_differences(jaco, frame):
    rng = np.random.default_rng(1)
    for _ in range(10):
        q = random_configuration(jaco, rng)
        np.testing.assert_allclose(jaco.frame_jacobian(q, frame), _numeric_jacobian(jaco, q, frame), atol=1e-6)


@pytest.mark.parametrize(("frame", "joint"), [("link_4", 4), ("link_6", 6), ("link_7", 7)])
def test_partial_jacobian_zeroes_columns_from_control_joint(jaco, frame, joint):
    rng = np.random.default_rng(2)
    q = random_configuration(jaco, rng)
    partial = jaco.partial_position_jacobian(q, frame)
    full = jaco.position_jacobian(q, frame)
    assert np.all(partial[:, joint - 1 :] == 0.0)
    np.testing.assert_allclose(partial[:, : joint - 1], full[:, : joint - 1])
    # The first j−1 columns are the velocity of P caused by joints 1..j−1 alone.
    eps = 1e-6
    dq = np.zeros(7)
    dq[: joint - 1] = rng.normal(size=joint - 1)
    moved = (jaco.frame_position(q + eps * dq, frame) - jaco.frame_position(q - eps * dq, frame)) / (2 * eps)
    np.testing.assert_allclose(partial @ dq, moved, atol=1e-6)


@pytest.mark.parametrize("name", ["jaco2", "panda", "ur5"])
def test_fill_frames_matches_the_per_frame_queries(name):
    """The one-pass frame origins and position Jacobians (compiled chain FK) equal pinocchio's per frame."""
    robot = robots.load(name)
    assert robot.revolute_chain() is not None  # the compiled path is the one tested
    frames = list(robot.frame_names)
    out = np.full((len(frames), 4, robot.nq), np.nan)
    rng = np.random.default_rng(7)
    for _ in range(20):
        kin = robot.kinematics(random_configuration(robot, rng))
        for compiled in (True, False):
            kin.fill_frames(frames, out, compiled_origins=compiled)
            for f, frame in enumerate(frames):
                np.testing.assert_allclose(out[f, 0, :3], kin.frame_position(frame), rtol=0.0, atol=1e-12)
                np.testing.assert_allclose(out[f, 1:4], kin.position_jacobian(frame), rtol=0.0, atol=1e-12)


def test_fill_frames_of_a_stale_snapshot_raises(jaco):
    kin = jaco.kinematics(jaco.home)
    jaco.kinematics(jaco.home)
    with pytest.raises(robots.StaleKinematics):
        kin.fill_frames(["link_4"], np.zeros((1, 4, 7)))


@pytest.mark.parametrize("name", ["jaco2", "panda", "ur5"])
def test_chain_frames_matches_fill_frames_from_pinocchio(name):
    """The compiled frames from q alone (TPIK's step) equal fill_frames' from pinocchio's joint Jacobians."""
    from robots.kinematics import chain_frames

    robot = robots.load(name)
    chain = robot.revolute_chain()
    assert chain is not None
    frames = list(robot.frame_names)
    parent, offset = robot.frame_placements(frames)
    _, support = robot.frame_support(frames)
    want, got = np.zeros((2, len(frames), 4, robot.nq))
    rng = np.random.default_rng(11)
    for _ in range(50):
        kin = robot.kinematics(random_configuration(robot, rng))
        kin.fill_frames(frames, want, compiled_origins=True)
        got[:] = np.nan
        chain_frames(kin.q, chain[0], chain[1], parent, offset, support, got)
        np.testing.assert_allclose(got[:, 0, :3], want[:, 0, :3], rtol=0.0, atol=1e-15)
        np.testing.assert_allclose(got[:, 1:4], want[:, 1:4], rtol=0.0, atol=1e-12)


def test_a_snapshot_computes_pinocchio_at_its_first_query_bit_for_bit(jaco):
    """robot.kinematics defers pinocchio to the first query; the numbers are those of the eager calls."""
    import pinocchio as pin

    rng = np.random.default_rng(3)
    data = jaco.pin_model.createData()
    for _ in range(10):
        q = random_configuration(jaco, rng)
        kin = jaco.kinematics(q)
        pin.computeJointJacobians(jaco.pin_model, data, q)
        pin.updateFramePlacements(jaco.pin_model, data)
        for frame in FRAMES:
            fid = jaco.frame_id(frame)
            assert np.array_equal(kin.frame_position(frame), data.oMf[fid].translation)
            want = pin.getFrameJacobian(jaco.pin_model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            assert np.array_equal(kin.frame_jacobian(frame), want)


def test_check_current_raises_on_a_stale_snapshot_without_computing(jaco):
    kin = jaco.kinematics(jaco.home)
    kin.check_current()
    jaco.kinematics(jaco.home)
    with pytest.raises(robots.StaleKinematics):
        kin.check_current()


def test_frame_positions_are_the_per_frame_positions_bit_for_bit(jaco):
    """Frames read before (cached) and not yet read alike; a stale snapshot raises."""
    rng = np.random.default_rng(9)
    out = np.full((len(FRAMES), 3), np.nan)
    for _ in range(5):
        kin = jaco.kinematics(random_configuration(jaco, rng))
        kin.frame_position(FRAMES[0])
        kin.frame_positions(FRAMES, out)
        for f, frame in enumerate(FRAMES):
            assert np.array_equal(out[f], kin.frame_position(frame))
    jaco.kinematics(jaco.home)
    with pytest.raises(robots.StaleKinematics):
        kin.frame_positions(FRAMES, out)


def test_an_origin_view_shows_the_latest_computation_and_a_copied_robot_has_its_own(jaco):
    import copy

    view = jaco.origin_view("link_4")
    assert not view.flags.writeable
    for q in (jaco.home, jaco.home + 0.2):
        assert np.array_equal(view, jaco.frame_position(q, "link_4"))
    twin = copy.deepcopy(jaco)
    twin_view = twin.origin_view("link_4")
    twin.frame_position(jaco.home, "link_4")
    jaco.frame_position(jaco.home + 0.2, "link_4")
    assert np.array_equal(twin_view, twin.frame_position(jaco.home, "link_4"))
    assert not np.array_equal(twin_view, view)


def test_a_renewed_snapshot_is_a_fresh_one_of_the_same_q(jaco):
    kin = jaco.kinematics(jaco.home + 0.1)
    kin.frame_position("link_6")
    fresh = jaco.renew(kin)
    assert fresh.q is kin.q and fresh.is_current and not kin.is_current
    with pytest.raises(robots.StaleKinematics):
        kin.frame_position("link_6")
    assert np.array_equal(fresh.frame_position("link_6"), jaco.frame_position(jaco.home + 0.1, "link_6"))
