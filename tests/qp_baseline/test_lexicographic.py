"""The independent lexicographic reference against closed-form optima and the Siciliano–Slotine cascade."""

from __future__ import annotations

import math

import numpy as np
import pytest

from qp_baseline.lexicographic import (
    LevelRows,
    joint_box,
    level_objectives,
    level_rows,
    lexicographic_reference,
    solve_reference,
)
from tests.conftest import random_configuration
from tests.qp_baseline.helpers import DT, joint_limit_level, position_level, reference_rows, ss_reference
from tpik.hierarchy import Hierarchy, Level
from tpik.tasks import ObstacleDistanceTask, Thresholds, VirtualWallTask


def test_equality_levels_give_the_siciliano_slotine_solution(jaco):
    """Equality levels only, box inactive: the reference is the minimum-norm lexicographic least squares."""
    rng = np.random.default_rng(4)
    checked = 0
    while checked < 5:
        q = random_configuration(jaco, rng, inset=0.3)
        kin = jaco.kinematics(q)
        hierarchy = Hierarchy(
            [
                position_level(kin.frame_position("link_4") + rng.normal(size=3) * 0.01, frame="link_4"),
                position_level(kin.frame_position("end_effector") + rng.normal(size=3) * 0.01),
            ]
        )
        ref_ss = ss_reference(reference_rows(hierarchy, kin), jaco.nq)
        if np.any(np.abs(ref_ss) > 0.5 * jaco.v_max):
            continue
        ref, _ = lexicographic_reference(hierarchy, jaco, kin, DT, regularization=0.0)
        np.testing.assert_allclose(ref.qdot, ref_ss, atol=1e-7)
        assert ref.worst_kkt < 1e-9
        checked += 1


def test_infeasible_obstacle_request_gets_the_minimal_slack(jaco):
    """lo − max over the box of J q̇: the least violation any velocity in the box reaches."""
    kin = jaco.kinematics(jaco.home)
    task = ObstacleDistanceTask("obstacle", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05), gain=100.0)
    task.set_obstacle(kin.frame_position("link_6") + np.array([0.0, 0.18, 0.24]))  # 0.30 m away
    hierarchy = Hierarchy([Level("safety", (task,)), position_level(kin.frame_position("end_effector"))])
    ref, rows = lexicographic_reference(hierarchy, jaco, kin, DT)
    state = task.compute_state(kin)
    lo, _ = task.velocity_bounds(state, DT)
    lb, ub = joint_box(jaco, kin.q, DT)
    g = state.jacobian[0]
    expected = lo - float(np.sum(np.maximum(g * lb, g * ub)))
    assert expected > 1.0
    assert ref.slacks[0][0] == pytest.approx(expected, abs=1e-8)
    assert level_objectives(rows, ref.qdot)[0] == pytest.approx(expected**2, rel=1e-8)


def test_opposite_walls_that_cannot_both_hold_share_the_violation(jaco):
    """Rows ẋ ≥ 1 m/s and −ẋ ≥ 1 m/s: least squares splits the violation, 1 m/s each."""
    kin = jaco.kinematics(jaco.home)
    x = float(kin.frame_position("end_effector")[0])
    th = Thresholds(-1.0, 0.0, math.inf, math.inf, 0.005)
    walls = (
        VirtualWallTask("x_min", "end_effector", np.array([1.0, 0.0, 0.0]), x + 0.01, th, gain=100.0),
        VirtualWallTask("x_max", "end_effector", np.array([-1.0, 0.0, 0.0]), -(x - 0.01), th, gain=100.0),
    )
    ref, _ = lexicographic_reference(Hierarchy([joint_limit_level(jaco), Level("walls", walls)]), jaco, kin, DT)
    np.testing.assert_allclose(ref.slacks[1], [1.0, 1.0], atol=1e-8)


def test_a_fixed_slack_binds_the_levels_below():
    """Two 1-D levels on one joint: level 0 wants q̇ ≥ 2 but the box stops at 1 (slack 1); level 1 wants
    q̇ = −1. The reference keeps level 0's best (q̇ = 1): level 1 gets nothing."""
    rows = [
        LevelRows("first", np.zeros((0, 1)), np.zeros(0), np.array([[-1.0]]), np.array([-2.0]), ("a",)),
        LevelRows("second", np.array([[1.0]]), np.array([-1.0]), np.zeros((0, 1)), np.zeros(0), ()),
    ]
    ref = solve_reference(rows, np.array([-1.0]), np.array([1.0]), regularization=0.0)
    assert ref.qdot[0] == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(ref.objectives, [1.0, 4.0], atol=1e-8)


def test_level_rows_follow_the_set_task_velocity_bounds(jaco):
    kin = jaco.kinematics(jaco.home)
    task = ObstacleDistanceTask("obstacle", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05), gain=2.0)
    task.set_obstacle(kin.frame_position("link_6") + np.array([0.0, 0.3, 0.3]))
    rows = level_rows(Hierarchy([Level("safety", (task,))]), kin, DT)
    lo, hi = task.velocity_bounds(task.compute_state(kin), DT)
    assert math.isinf(hi) and rows[0].h.tolist() == [-lo] and rows[0].owners == ("obstacle",)
    np.testing.assert_array_equal(rows[0].G[0], -task.compute_state(kin).jacobian[0])
