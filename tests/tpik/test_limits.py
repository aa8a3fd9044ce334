"""The limit objects of tpik.limits: boxes and rows by hand, composition, TPIK under an acceleration limit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.conftest import random_configuration
from tpik.exceptions import InvalidSettings
from tpik.hierarchy import Hierarchy
from tpik.limits import (
    AccelerationLimit,
    Box,
    PositionLimit,
    VelocityLimit,
    compose_box,
    scale_into_box,
    stack_inequalities,
)
from tpik.solver import TpikSolver
from tpik.step_result import SolveStatus
from tpik.tasks import PositionTask

Q = np.array([0.5, -1.0, 2.0])
DT = 0.02


def test_velocity_limit_rows_are_the_symmetric_box():
    limit = VelocityLimit(np.array([1.0, 2.0, 3.0]))
    G, h = limit.compute_qp_inequalities(Q, DT)
    np.testing.assert_array_equal(G, np.vstack([np.eye(3), -np.eye(3)]))
    np.testing.assert_array_equal(h, [1.0, 2.0, 3.0, 1.0, 2.0, 3.0])


def test_position_limit_rows_skip_unlimited_joints_and_scale_by_the_gain():
    # Joint 2 (index 1) is continuous: no row. Upper rows: 0.5·(1 − 0.5)/0.02 = 12.5 and 0.5·(2.5 − 2)/0.02 = 12.5;
    # lower rows −q̇ ≤ 0.5·(q − q_min)/dt: 0.5·(0.5 + 1)/0.02 = 37.5 and 0.5·(2 − 1)/0.02 = 25.
    limit = PositionLimit(np.array([-1.0, -math.inf, 1.0]), np.array([1.0, math.inf, 2.5]), gain=0.5)
    G, h = limit.compute_qp_inequalities(Q, DT)
    e = np.eye(3)
    np.testing.assert_array_equal(G, np.vstack([e[0], e[2], -e[0], -e[2]]))
    np.testing.assert_allclose(h, [12.5, 12.5, 37.5, 25.0], rtol=1e-14)


def test_acceleration_limit_box_follows_the_observed_velocity():
    limit = AccelerationLimit(10.0, n=3)
    lower, upper = limit.compute_box(Q, DT)
    np.testing.assert_allclose(lower, -0.2 * np.ones(3))  # 10 rad/s² · 0.02 s around zero
    limit.observe(np.array([1.0, 0.0, -1.0]))
    G, h = limit.compute_qp_inequalities(Q, DT)
    np.testing.assert_allclose(h, [1.2, 0.2, -0.8, -0.8, 0.2, 1.2])
    np.testing.assert_array_equal(G, np.vstack([np.eye(3), -np.eye(3)]))


@pytest.mark.parametrize(
    "build",
    [
        lambda: VelocityLimit(np.array([1.0, 0.0])),
        lambda: VelocityLimit(np.array([1.0, math.inf])),
        lambda: PositionLimit(np.array([1.0]), np.array([0.0])),
        lambda: PositionLimit(np.zeros(1), np.ones(1), gain=1.5),
        lambda: AccelerationLimit(-1.0, n=2),
        lambda: AccelerationLimit(1.0),
    ],
)
def test_bad_limits_are_refused(build):
    with pytest.raises(InvalidSettings):
        build()


def test_composition_clips_a_later_box_into_the_earlier_ones():
    # Velocity ±1; position box at q = 0.5 with limits [-1, 0.49], dt = 0.02: lower −75 → −1, upper
    # (0.49 − 0.5)/0.02 = −0.5 (inside); a joint 0.1 rad past its upper limit: (−0.1/0.02) = −5 → clipped to −1
    # and its lower bound −∞ → −1: the box is the single point −1 (drive back at full speed), never empty.
    velocity = VelocityLimit(np.array([1.0, 1.0]))
    position = PositionLimit(np.array([-1.0, -1.0]), np.array([0.49, 0.4]))
    lower, upper = compose_box([velocity, position], np.array([0.5, 0.5]), DT)
    np.testing.assert_allclose(lower, [-1.0, -1.0])
    np.testing.assert_allclose(upper, [-0.5, -1.0])
    with pytest.raises(ValueError, match="at least one limit"):
        compose_box([], Q, DT)


def test_stacked_rows_are_every_limits_rows_in_order():
    velocity = VelocityLimit(np.ones(3))
    accel = AccelerationLimit(np.array([1.0, 2.0, 3.0]))
    G, h = stack_inequalities([velocity, accel], Q, DT)
    assert G.shape == (12, 3)
    np.testing.assert_allclose(h[6:], [0.02, 0.04, 0.06, 0.02, 0.04, 0.06])


def test_scaling_keeps_the_direction_when_the_box_holds_zero():
    qdot, s = scale_into_box(np.array([2.0, -0.5, 0.1]), Box(-np.ones(3), np.ones(3)))
    assert s == pytest.approx(0.5)
    np.testing.assert_allclose(qdot, [1.0, -0.25, 0.05])
    same, s1 = scale_into_box(np.array([0.5, 0.0, -0.5]), Box(-np.ones(3), np.ones(3)))
    assert s1 == 1.0 and same[0] == 0.5


def test_scaling_starts_from_the_point_nearest_zero_when_the_box_excludes_it():
    # Box [0.9, 1.1] × [−1, 1]: anchor (0.9, 0); q̇ = (2, 0.5) → s with 0.9 + 1.1 s = 1.1, s = 2/11.
    qdot, s = scale_into_box(np.array([2.0, 0.5]), Box(np.array([0.9, -1.0]), np.array([1.1, 1.0])))
    assert s == pytest.approx(0.2 / 1.1)
    np.testing.assert_allclose(qdot, [1.1, 0.5 * 0.2 / 1.1])


def rollout_changes(solver, robot, steps, accel_max, dt=0.01):
    """Largest per-joint change of q̇ between consecutive steps, in units of a_max·dt.

    Joint limits > EE position, at random configurations with targets up to 0.3 m away: every
    step jumps, so unlimited velocities change by far more than a_max·dt.
    """
    hierarchy = Hierarchy.from_description(
        [
            {"name": "limits", "tasks": [{"type": "joint_limit", "joints": [2, 4, 6], "safety_margin": 0.1}]},
            {"name": "ee", "tasks": [{"type": "position", "frame": robot.ee_frame, "gain": 20.0}]},
        ],
        robot,
    )
    rng = np.random.default_rng(17)
    worst, previous = 0.0, np.zeros(robot.nq)
    for _ in range(steps):
        kin = robot.kinematics(random_configuration(robot, rng))
        for task in hierarchy.tasks:
            if isinstance(task, PositionTask):
                task.set_target(kin.frame_position(robot.ee_frame) + rng.uniform(-0.3, 0.3, size=3))
        result = solver.solve(hierarchy, kin, dt)
        if result.status != SolveStatus.FAILED:
            worst = max(worst, float(np.max(np.abs(result.qdot - previous) / (accel_max * dt))))
        previous = result.qdot
    return worst


def test_tpik_respects_an_acceleration_limit(jaco):
    """Random states jump: unlimited TPIK changes q̇ by far more than a·dt; with the limit it never does."""
    a_max = 5.0  # rad/s²
    free = rollout_changes(TpikSolver(jaco), jaco, 40, a_max)
    limits = (VelocityLimit.from_robot(jaco), AccelerationLimit(a_max, n=jaco.nq))
    limited = rollout_changes(TpikSolver(jaco, limits=limits), jaco, 40, a_max)
    assert free > 2.0  # the limit binds on this sequence
    assert limited <= 1.0 + 1e-9


def test_tpik_default_limits_are_the_robot_velocity_limits(jaco):
    solver = TpikSolver(jaco)
    assert len(solver.limits) == 1 and isinstance(solver.limits[0], VelocityLimit)
    np.testing.assert_array_equal(solver.limits[0].v_max, jaco.v_max)
