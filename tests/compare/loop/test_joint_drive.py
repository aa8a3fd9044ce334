"""The decoupled joint drive (compare/loop/joint_drive.py) against its equation and against the servos.

τ = M(q) λ (q̇_c − q̇) + c(q, q̇) + D q̇ is checked term by term against pinocchio (an independent
implementation of M and c); the closed-loop properties it exists for — one first-order lag per
joint, no coupling between joints, no steady-state error — are checked in simulation, with the
MJCF's P-only servos as the counter-example that shows each check can fail.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

import robots
from compare.loop.joint_drive import MAX_BANDWIDTH_TIMESTEP, DecoupledVelocityDrive
from compare.loop.sim_io import SimRobotIO
from tests.conftest import random_configuration

DT = 0.01  # control period [s]


def _io(jaco: robots.Robot, drive: str, q0: np.ndarray | None = None, bandwidth: float = 100.0) -> SimRobotIO:
    return SimRobotIO(
        jaco.mj_model, jaco.nq, DT, jaco.home if q0 is None else q0, drive=drive, drive_bandwidth_rad_s=bandwidth
    )


def _torque(drive: DecoupledVelocityDrive, model: mujoco.MjModel, data: mujoco.MjData, cmd: np.ndarray) -> np.ndarray:
    """τ the drive applies at ``data``'s state: one sub-step, then the state put back (``mj_step1`` redone)."""
    qpos, qvel, time = data.qpos.copy(), data.qvel.copy(), data.time
    drive.step(model, data, cmd, 1)
    tau = data.qfrc_applied[: drive.nq].copy()
    data.qpos[:], data.qvel[:], data.time = qpos, qvel, time
    mujoco.mj_step1(model, data)
    return tau


def test_torque_is_the_inverse_dynamics_law_computed_by_pinocchio(jaco: robots.Robot) -> None:
    """(M + hD) λ (q̇_c − q̇) + c + D q̇, M = CRBA (with armature), c = RNEA(q, q̇, 0) − g(q) of pinocchio.

    Velocities small enough that no torque limit is reached.
    """
    model = mujoco.MjModel.from_xml_path(str(jaco.spec.description))
    drive = DecoupledVelocityDrive(model, jaco.nq, 100.0)
    data = mujoco.MjData(model)
    pm, pd = jaco.pin_model, jaco.pin_model.createData()
    rng = np.random.default_rng(4)
    for _ in range(20):
        q = random_configuration(jaco, rng)
        qd = rng.uniform(-0.5, 0.5, jaco.nq)
        cmd = qd + rng.uniform(-0.1, 0.1, jaco.nq)
        data.qpos[:] = q
        data.qvel[:] = qd
        tau = _torque(drive, model, data, cmd)
        M = pin.crba(pm, pd, q)
        M = np.triu(M) + np.triu(M, 1).T  # pinocchio fills the upper triangle
        coriolis = pin.rnea(pm, pd, q, qd, np.zeros(jaco.nq)) - pin.computeGeneralizedGravity(pm, pd, q)
        M += np.diag(model.opt.timestep * pm.damping)
        expected = M @ (100.0 * (cmd - qd)) + coriolis + pm.damping * qd
        assert np.all(np.abs(expected) < np.abs(model.jnt_actfrcrange[: jaco.nq, 1]))
        np.testing.assert_allclose(tau, expected, rtol=1e-6, atol=1e-6)


def test_at_a_torque_limit_the_acceleration_is_scaled_for_all_joints(jaco: robots.Robot) -> None:
    """τ = M s a + c + D q̇ with one s: the joint at its limit gets exactly its limit, the others the same s."""
    model = mujoco.MjModel.from_xml_path(str(jaco.spec.description))
    drive = DecoupledVelocityDrive(model, jaco.nq, 250.0)
    data = mujoco.MjData(model)
    limit = np.abs(model.jnt_actfrcrange[: jaco.nq, 1])
    cmd = 0.9 * jaco.v_max * np.array([1, -1, 1, -1, 1, -1, 1])
    data.qpos[:] = jaco.home
    data.qvel[:] = -cmd  # a reversal
    unlimited = DecoupledVelocityDrive(mujoco.MjModel.from_xml_path(str(jaco.spec.description)), jaco.nq, 250.0)
    unlimited._tau_max = np.full(jaco.nq, np.inf)
    qvel = data.qvel.copy()
    tau, free = _torque(drive, model, data, cmd), _torque(unlimited, model, data, cmd)
    assert np.any(np.abs(free) > limit), "the command must saturate a joint for this test"
    hold = data.qfrc_bias[: jaco.nq] - data.qfrc_gravcomp[: jaco.nq] + model.dof_damping[: jaco.nq] * qvel
    scale = (tau - hold) / (free - hold)
    np.testing.assert_allclose(scale, scale[0], rtol=1e-9)
    assert 0.0 < scale[0] < 1.0
    assert np.all(np.abs(tau) <= limit + 1e-9)
    assert np.isclose(np.max(np.abs(tau) / limit), 1.0)


def test_every_joint_follows_its_command_as_one_first_order_lag(jaco: robots.Robot) -> None:
    """A step of 0.2 rad/s on all joints: after m physics steps h, q̇ = 0.2 (1 − (1 − λh)^m) on each.

    (The discrete form of 1 − e^{−λt}; within 1 % of the step, the rest is the implicit damping.)
    """
    io = _io(jaco, "decoupled")
    h = io.model.opt.timestep
    cmd = np.full(jaco.nq, 0.2)
    io.send_velocity(cmd)
    for k in range(1, 6):
        io.wait()
        expected = 0.2 * (1.0 - (1.0 - 100.0 * h) ** round(k * DT / h))
        np.testing.assert_allclose(io.read_joints().qdot, expected, atol=0.01 * 0.2)


@pytest.mark.parametrize("drive, coupled", [("decoupled", False), ("servo", True)])
def test_a_moving_joint_does_not_drag_the_others(jaco: robots.Robot, drive: str, coupled: bool) -> None:
    """Joint 2 reversed between ±v_max; the still-commanded joints stay still only with the drive.

    The reversals saturate joint 2's torque: the drive scales the acceleration, not each torque.
    The servos need a velocity error τ/k_v to resist the inertial and Coriolis torques of the
    moving link: the held joints move by several mrad/s (what pushes a held constraint past its
    threshold in the servo campaign).
    """
    io = _io(jaco, drive)
    v = float(jaco.v_max[1])
    worst = 0.0
    for k in range(60):
        cmd = np.zeros(jaco.nq)
        cmd[1] = v if (k // 20) % 2 == 0 else -v
        io.send_velocity(cmd)
        io.wait()
        worst = max(worst, float(np.max(np.abs(np.delete(io.read_joints().qdot, 1)))))
    if coupled:
        assert worst > 5e-3, f"servo: still joints moved only {worst:.2e} rad/s"
    else:
        assert worst < 1e-6, f"decoupled drive: still joints moved at {worst:.2e} rad/s"


@pytest.mark.parametrize("drive, exact", [("decoupled", True), ("servo", False)])
def test_steady_velocity_has_no_tracking_error(jaco: robots.Robot, drive: str, exact: bool) -> None:
    """After 0.3 s at a constant command the drive tracks it exactly; the servos run k_v/(k_v + d) slow."""
    io = _io(jaco, drive)
    cmd = np.array([0.2, -0.15, 0.2, 0.15, -0.3, 0.3, 0.3])
    io.send_velocity(cmd)
    for _ in range(30):
        io.wait()
    error = float(np.max(np.abs(io.read_joints().qdot - cmd) / np.abs(cmd)))
    if exact:
        assert error < 1e-4
    else:
        assert error > 5e-3


def test_torque_limits_hold_and_a_reversal_settles_without_overshoot(jaco: robots.Robot) -> None:
    """±v_max reversals on every joint at once saturate the torque; the drive never exceeds it."""
    io = _io(jaco, "decoupled")
    limit = np.abs(io.model.jnt_actfrcrange[: jaco.nq, 1])
    for sign in (1.0, -1.0):
        cmd = sign * jaco.v_max
        io.send_velocity(cmd)
        for _ in range(25):
            io.wait()
            assert np.all(np.abs(io.data.qfrc_applied[: jaco.nq]) <= limit + 1e-9)
            assert np.all(sign * io.read_joints().qdot <= sign * cmd + 1e-3 * jaco.v_max)
        np.testing.assert_allclose(io.read_joints().qdot, cmd, atol=1e-3)


def test_the_callers_model_keeps_its_actuators(jaco: robots.Robot) -> None:
    """The drive steps a copy with actuation disabled; the cached arm model still has its servos."""
    before = int(jaco.mj_model.opt.disableflags)
    io = _io(jaco, "decoupled")
    assert io.model is not jaco.mj_model
    assert io.model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_ACTUATION
    assert int(jaco.mj_model.opt.disableflags) == before


def test_a_still_command_holds_the_arm_against_gravity(jaco: robots.Robot) -> None:
    """Zero command for 1 s from a random pose: passive gravcomp + drive, drift below 1e-6 rad."""
    q0 = random_configuration(jaco, np.random.default_rng(2))
    io = _io(jaco, "decoupled", q0)
    for _ in range(100):
        io.wait()
    assert float(np.max(np.abs(io.read_joints().q - q0))) < 1e-6


@pytest.mark.parametrize("bandwidth", [0.0, -5.0, 1.01 * MAX_BANDWIDTH_TIMESTEP / 0.002])
def test_a_bandwidth_the_timestep_cannot_integrate_is_refused(jaco: robots.Robot, bandwidth: float) -> None:
    with pytest.raises(ValueError, match="drive bandwidth"):
        _io(jaco, "decoupled", bandwidth=bandwidth)


def test_an_unknown_drive_is_refused(jaco: robots.Robot) -> None:
    with pytest.raises(ValueError, match="drive must be"):
        _io(jaco, "magic")
