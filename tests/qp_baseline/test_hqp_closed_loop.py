"""Closed-loop kinematic integration (q ← q + q̇ dt): set-based tasks never leave their safety set.

Tolerances on the safety margins (signed, > 0 inside):

* joint limits [rad]: σ = q_j is linear and K ≤ 1/dt, so one Euler step lands at most on the
  threshold: only the backend's accepted violation (``tolerance`` · dt) remains, 1e-6 rad covers
  every backend;
* walls and obstacle distances [m]: σ is nonlinear in q, the second-order term of one 10 ms step
  adds up to ~1e-5 m: 1e-4 m for every backend.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from qp_baseline.hqp import HqpSolver
from tests.qp_baseline.helpers import (
    SOLVERS,
    joint_limit_level,
    obstacle_level,
    position_level,
    rollout,
    wall_box_level,
)
from tpik.hierarchy import Hierarchy, Level
from tpik.tasks import JointLimitTask, ObstacleDistanceTask, Thresholds

JOINT_TOLERANCE = 1e-6  # rad
CARTESIAN_TOLERANCE = 1e-4  # m


@pytest.mark.parametrize("solver", SOLVERS)
def test_walls_hold_while_the_target_is_outside_the_box(jaco, solver):
    ee = jaco.kinematics(jaco.home).frame_position("end_effector")
    target = np.array([0.8, ee[1], 0.1])  # beyond x_max = 0.5 m and below z_min = 0.2 m
    hierarchy = Hierarchy(
        [joint_limit_level(jaco, gain=10.0), wall_box_level(gain=10.0), position_level(target, gain=2.0)]
    )
    run = rollout(HqpSolver(jaco, solver), hierarchy, jaco, jaco.home, steps=150)
    for name in ("wall_x_max", "wall_z_min"):
        assert run.worst_margin[name] >= -CARTESIAN_TOLERANCE, (name, run.worst_margin[name])
        assert run.worst_margin[name] < 0.01, f"{name} never approached: the test exercises nothing"
    assert min(run.worst_margin.values()) >= -CARTESIAN_TOLERANCE
    final = jaco.kinematics(run.q).frame_position("end_effector")
    assert final[0] == pytest.approx(0.5, abs=5e-3)  # pressed against x_max
    assert final[2] == pytest.approx(0.2, abs=5e-3)  # and against z_min
    assert run.max_speed_ratio <= 1.0 + 1e-12


@pytest.mark.parametrize("solver", SOLVERS)
def test_obstacle_distances_hold_while_the_target_is_behind_the_obstacle(jaco, solver):
    kin = jaco.kinematics(jaco.home)
    ee = kin.frame_position("end_effector")
    level = obstacle_level(gain=10.0)
    obstacle = ee + np.array([0.2, 0.5, -0.05])  # 0.54–0.63 m from the control points at the start
    for task in level.tasks:
        assert isinstance(task, ObstacleDistanceTask)
        task.set_obstacle(obstacle)
    target = position_level(ee + np.array([0.0, 0.8, 0.1]), gain=2.0)
    hierarchy = Hierarchy([joint_limit_level(jaco, gain=10.0), level, target])
    run = rollout(HqpSolver(jaco, solver), hierarchy, jaco, jaco.home, steps=150)
    distances = {k: v for k, v in run.worst_margin.items() if k.startswith("obstacle_")}
    assert min(distances.values()) >= -CARTESIAN_TOLERANCE, distances
    assert min(distances.values()) < 0.01, f"no control point came near the obstacle: {distances}"
    assert all(s.value != "failed" for s in run.statuses)


@pytest.mark.parametrize("solver", SOLVERS)
def test_joint_limits_hold_while_the_target_needs_more_range(jaco, solver):
    q0 = jaco.home
    # Narrow safety ranges (±0.1 rad around the start) on joints 2, 4, 6.
    limits = tuple(
        JointLimitTask(
            f"joint_limit_{j}",
            j,
            jaco.nq,
            Thresholds(q0[j - 1] - 0.3, q0[j - 1] - 0.1, q0[j - 1] + 0.1, q0[j - 1] + 0.3, 0.05),
            gain=10.0,
        )
        for j in (2, 4, 6)
    )
    ee = jaco.kinematics(q0).frame_position("end_effector")
    hierarchy = Hierarchy([Level("joint_limits", limits), position_level(ee + np.array([-0.3, 0.3, 0.2]), gain=2.0)])
    run = rollout(HqpSolver(jaco, solver), hierarchy, jaco, q0, steps=120)
    worst = min(run.worst_margin.values())
    assert worst >= -JOINT_TOLERANCE, run.worst_margin
    assert worst < 1e-3, f"no joint reached its safety threshold: {run.worst_margin}"
    assert all(s.value == "ok" for s in run.statuses)


def test_no_obstacle_means_no_row_and_no_effect(jaco):
    """Set tasks with a non-finite σ (no obstacle in range) add nothing."""
    ee = jaco.kinematics(jaco.home).frame_position("end_effector")
    target = position_level(ee + 0.05)
    with_obstacles = Hierarchy([obstacle_level(), target])
    without = Hierarchy([target])
    kin = jaco.kinematics(jaco.home)
    hqp = HqpSolver(jaco, "daqp")
    a = hqp.solve(with_obstacles, kin, 0.01)
    b = HqpSolver(jaco, "daqp").solve(without, kin, 0.01)
    np.testing.assert_allclose(a.qdot, b.qdot, atol=1e-12)
    assert a.extras["slacks"] == {} and a.active_set == ()
    assert math.isinf(next(iter(with_obstacles.set_tasks)).compute_state(kin).value[0])
