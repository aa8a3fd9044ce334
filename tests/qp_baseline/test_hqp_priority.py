"""Strict priority: a lower level never changes what a higher level achieved, even in conflict."""

from __future__ import annotations

import math

import numpy as np
import pytest

from qp_baseline.hqp import HqpSolver
from tests.conftest import random_configuration
from tests.qp_baseline.helpers import DT, SOLVERS, set_task
from tpik.hierarchy import Hierarchy, Level
from tpik.tasks import ObstacleDistanceTask, OrientationTask, PositionTask, Thresholds


def _tolerance(hqp: HqpSolver) -> float:
    """What a level's optimum may move by: the backend's accepted violation, at least 1e-6."""
    return max(1e-6, 10.0 * hqp.tolerance)


def _conflicting(kin: object, rng: np.random.Generator) -> tuple[Hierarchy, Hierarchy]:
    """EE position far away (saturates the box) > elbow position far the other way > orientation."""
    p_ee = kin.frame_position("end_effector")  # type: ignore[attr-defined]
    p_4 = kin.frame_position("link_4")  # type: ignore[attr-defined]
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    top = Level("ee", (PositionTask("ee", "end_effector", 1.0, p_ee + 0.6 * direction),))
    lower = [
        Level("elbow", (PositionTask("elbow", "link_4", 1.0, p_4 - 0.6 * direction),)),
        Level("ori", (OrientationTask("ori", "end_effector", 1.0, np.eye(3)),)),
    ]
    return Hierarchy([top]), Hierarchy([top, *lower])


@pytest.mark.parametrize("solver", SOLVERS)
def test_lower_levels_leave_the_top_level_unchanged(jaco, solver):
    hqp = HqpSolver(jaco, solver)
    rng = np.random.default_rng(7)
    saturated = 0
    for _ in range(6):
        kin = jaco.kinematics(random_configuration(jaco, rng, inset=0.2))
        alone, full = _conflicting(kin, rng)
        J = kin.position_jacobian("end_effector")
        r_alone = hqp.solve(alone, kin, DT)
        r_full = hqp.solve(full, kin, DT)
        assert r_alone.ok and r_full.ok, (r_alone.message, r_full.message)
        # J₁q̇ is unique (strictly convex in J₁q̇), so it must not move when levels are added.
        diff = np.max(np.abs(J @ r_full.qdot - J @ r_alone.qdot))
        assert diff < _tolerance(hqp), f"{solver}: J1 q̇ moved by {diff:.2e}"
        assert np.all(np.abs(r_full.qdot) <= jaco.v_max + 1e-12)
        saturated += bool(np.any(np.isclose(np.abs(r_full.qdot), jaco.v_max)))
    assert saturated, "the conflict should drive some joint to its velocity limit"


def _infeasible_obstacle(kin: object, gain: float) -> ObstacleDistanceTask:
    """Obstacle 0.30 m from the wrist (safety 0.35 m): with K = 1/dt, σ̇ ≥ 5 m/s is impossible."""
    task = ObstacleDistanceTask("obstacle_link_6", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05), gain)
    p6 = kin.frame_position("link_6")  # type: ignore[attr-defined]
    task.set_obstacle(p6 + 0.30 * np.array([0.0, 0.6, 0.8]))
    return task


@pytest.mark.parametrize("solver", SOLVERS)
def test_slack_of_a_level_is_never_increased_by_lower_levels(jaco, solver):
    hqp = HqpSolver(jaco, solver)
    kin = jaco.kinematics(jaco.home)
    obstacle = _infeasible_obstacle(kin, gain=100.0)
    p_ee = kin.frame_position("end_effector")
    # The EE task pulls toward the obstacle, the orientation task anywhere.
    pull = PositionTask("ee", "end_effector", 1.0, p_ee + 0.5 * np.array([0.0, 0.6, 0.8]))
    alone = Hierarchy([Level("safety", (obstacle,))])
    full = Hierarchy(
        [Level("safety", (obstacle,)), Level("ee", (pull,)), Level("ori", (OrientationTask("o", target=np.eye(3)),))]
    )
    r_alone = hqp.solve(alone, kin, DT)
    r_full = hqp.solve(full, kin, DT)
    for r in (r_alone, r_full):
        assert r.status.value == "degraded", r.message
        assert "obstacle_link_6" in r.active_set
    slack_alone = r_alone.extras["slacks"]["safety"]["obstacle_link_6"]
    slack_full = r_full.extras["slacks"]["safety"]["obstacle_link_6"]
    assert slack_alone > 1.0
    assert slack_full == pytest.approx(slack_alone, abs=_tolerance(hqp))
    # And the final velocity keeps that slack: σ̇ ≥ σ̇_min − w*.
    task = set_task(full, "obstacle_link_6")
    state = task.compute_state(kin)
    lo, _ = task.velocity_bounds(state, DT)
    sigma_dot = float(state.jacobian[0] @ r_full.qdot)
    assert lo - sigma_dot <= slack_alone + _tolerance(hqp)


@pytest.mark.parametrize("solver", SOLVERS)
def test_equality_levels_below_a_set_level_cannot_break_it(jaco, solver):
    """A feasible set level (slack 0) stays satisfied whatever the EE task below asks."""
    hqp = HqpSolver(jaco, solver)
    kin = jaco.kinematics(jaco.home)
    obstacle = _infeasible_obstacle(kin, gain=1.0)  # σ̇ ≥ 0.05 m/s: feasible
    toward = PositionTask("ee", "end_effector", 5.0, obstacle.obstacle)
    hierarchy = Hierarchy([Level("safety", (obstacle,)), Level("ee", (toward,))])
    result = hqp.solve(hierarchy, kin, DT)
    assert result.status.value == "ok", result.message
    state = obstacle.compute_state(kin)
    lo, _ = obstacle.velocity_bounds(state, DT)
    assert float(state.jacobian[0] @ result.qdot) >= lo - _tolerance(hqp)
    assert result.extras["slacks"]["safety"]["obstacle_link_6"] <= hqp.slack_tolerance
