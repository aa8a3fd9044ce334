"""An infeasible higher-level request: minimal slack, DEGRADED, a valid velocity, no exception."""

from __future__ import annotations

import math

import numpy as np
import pytest

from qp_baseline.hqp import HqpSolver
from tests.qp_baseline.helpers import DT, SOLVERS, joint_limit_level, position_level
from tpik.hierarchy import Hierarchy, Level
from tpik.limits import compose_box
from tpik.tasks import ObstacleDistanceTask, Thresholds, VirtualWallTask


def _max_over_box(g: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> float:
    return float(np.sum(np.maximum(g * lb, g * ub)))


@pytest.mark.parametrize("solver", SOLVERS)
def test_infeasible_obstacle_request_gets_the_minimal_slack(jaco, solver):
    hqp = HqpSolver(jaco, solver)
    kin = jaco.kinematics(jaco.home)
    task = ObstacleDistanceTask("obstacle", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05), gain=100.0)
    task.set_obstacle(kin.frame_position("link_6") + np.array([0.0, 0.18, 0.24]))  # 0.30 m away
    hierarchy = Hierarchy([Level("safety", (task,)), position_level(kin.frame_position("end_effector"))])
    result = hqp.solve(hierarchy, kin, DT)  # must not raise
    assert result.status.value == "degraded"
    assert "obstacle" in result.message and "obstacle" in result.active_set
    # Minimal slack: lo − max over the hard box of J q̇ (the QP's best effort).
    state = task.compute_state(kin)
    lo, _ = task.velocity_bounds(state, DT)
    lb, ub = compose_box(hqp.limits, kin.q, DT)
    expected = lo - _max_over_box(state.jacobian[0], lb, ub)
    assert expected > 1.0
    assert result.extras["slacks"]["safety"]["obstacle"] == pytest.approx(expected, abs=max(1e-6, 10 * hqp.tolerance))
    assert np.all(np.isfinite(result.qdot))
    assert np.all(np.abs(result.qdot) <= jaco.v_max + 1e-12)


@pytest.mark.parametrize("solver", SOLVERS)
def test_opposite_walls_that_cannot_both_hold_share_the_violation(jaco, solver):
    """Two walls 2 cm apart with the EE outside both by 1 cm (K = 1/dt): the least-squares slacks."""
    hqp = HqpSolver(jaco, solver)
    kin = jaco.kinematics(jaco.home)
    x = float(kin.frame_position("end_effector")[0])
    th = Thresholds(-1.0, 0.0, math.inf, math.inf, 0.005)
    walls = (
        VirtualWallTask("x_min", "end_effector", np.array([1.0, 0.0, 0.0]), x + 0.01, th, gain=100.0),
        VirtualWallTask("x_max", "end_effector", np.array([-1.0, 0.0, 0.0]), -(x - 0.01), th, gain=100.0),
    )
    hierarchy = Hierarchy([joint_limit_level(jaco), Level("walls", walls)])
    result = hqp.solve(hierarchy, kin, DT)
    assert result.status.value == "degraded", result.message
    slacks = result.extras["slacks"]["walls"]
    # Rows ẋ ≥ 1 m/s and −ẋ ≥ 1 m/s: least squares splits the violation equally (1 m/s each).
    assert slacks["x_min"] == pytest.approx(1.0, abs=1e-4)
    assert slacks["x_max"] == pytest.approx(1.0, abs=1e-4)
    assert set(result.active_set) >= {"x_min", "x_max"}


def test_level_above_a_failure_is_kept_and_the_caller_gets_no_exception(jaco, monkeypatch):
    """A backend that fails on the second QP: DEGRADED with the first level's velocity."""
    hqp = HqpSolver(jaco, "daqp", {"unconstrained_first": False})
    kin = jaco.kinematics(jaco.home)
    hierarchy = Hierarchy([joint_limit_level(jaco), position_level(kin.frame_position("end_effector") + 0.1)])
    calls = {"n": 0}
    real = hqp._call_backend

    def flaky(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] > 1:
            raise RuntimeError("backend exploded")
        return real(*args, **kwargs)

    monkeypatch.setattr(hqp, "_call_backend", flaky)
    result = hqp.solve(hierarchy, kin, DT)
    assert result.status.value == "degraded"
    assert "priority level 1" in result.message and "backend exploded" in result.message
    assert np.all(np.isfinite(result.qdot))
