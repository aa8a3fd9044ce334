"""Closed-loop behaviour of the set-based logic (pure kinematics, q += q̇ dt at 100 Hz).

A set-based task driven toward its threshold stops at the safety threshold, and lets go when
the lower task pulls away (deactivation, eqs. 8–9): the same for a joint limit, a virtual wall,
an obstacle distance and a corner where three of them are active at once.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.bench.solver_cases import apply_state, case2_hierarchy, case2_states
from tests.tpik.conftest import JointTargetTask, one_level_each, simulate
from tpik.hierarchy import Hierarchy, Level
from tpik.solver import TpikSettings, TpikSolver
from tpik.tasks import JointLimitTask, ObstacleDistanceTask, PositionTask, SetTask, Thresholds, VirtualWallTask

TOL = 1e-3  # [rad] or [m]
WALL = Thresholds(-0.05, 0.0, math.inf, math.inf, 0.03)


def _sigma(task):
    return lambda kin: task.compute_value_and_jacobian(kin)[0]


def test_joint_driven_to_its_limit_stops_at_the_safety_threshold_then_leaves(jaco, solver):
    limit = JointLimitTask.from_robot(jaco, 4, safety_margin=0.1, activation_margin=0.05)
    safety = limit.thresholds.safety_lower
    drive = JointTargetTask("drive_q4", 4, jaco.nq, target=jaco.q_lower[3] - 0.5)
    h = one_level_each(limit, drive)
    q0 = jaco.home.copy()
    q0[3] = 1.0
    q, results, q4 = simulate(jaco, h, solver, q0, 600, watch=lambda kin: float(kin.q[3]))
    assert q4.min() >= safety - TOL
    assert abs(q4[-1] - safety) <= TOL
    assert results[-1].active_set == ("joint_limit_4",)
    assert all(np.all(np.abs(r.qdot) <= jaco.v_max * (1 + 1e-9)) for r in results)
    # The lower task now pulls away: the limit is released and the joint leaves it.
    drive.target = 2.0
    _, results, q4 = simulate(jaco, h, solver, q, 300, watch=lambda kin: float(kin.q[3]))
    assert q4.min() >= safety - TOL
    assert q4[-1] > 1.8
    assert results[-1].active_set == ()


def test_end_effector_stops_at_a_wall_then_leaves(jaco, solver):
    kin = jaco.kinematics(jaco.home)
    ee = kin.frame_position("end_effector")
    wall = VirtualWallTask("wall", "end_effector", np.array([-1.0, 0.0, 0.0]), -(ee[0] + 0.1), WALL)
    target = PositionTask("ee", target=ee + np.array([0.3, 0.0, 0.0]))
    h = one_level_each(wall, target)
    q, results, sigma = simulate(jaco, h, solver, jaco.home, 500, watch=_sigma(wall))
    assert sigma.min() >= -TOL
    assert abs(sigma[-1]) <= TOL
    assert results[-1].active_set == ("wall",)
    target.set_target(ee - np.array([0.1, 0.0, 0.0]))
    _, results, sigma = simulate(jaco, h, solver, q, 300, watch=_sigma(wall))
    assert sigma.min() >= -TOL
    assert sigma[-1] > 0.15
    assert results[-1].active_set == ()


def test_control_point_keeps_the_safety_distance_then_leaves(jaco, solver):
    kin = jaco.kinematics(jaco.home)
    p = kin.frame_position("link_7")
    ee = kin.frame_position("end_effector")
    obstacle = p + np.array([0.5, 0.0, 0.0])
    task = ObstacleDistanceTask("obstacle_link_7", "link_7", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05))
    task.set_obstacle(obstacle)
    reach = PositionTask("ee", target=ee + np.array([0.4, 0.0, 0.0]))
    h = one_level_each(task, reach)
    q, results, dist = simulate(jaco, h, solver, jaco.home, 600, watch=_sigma(task))
    assert dist.min() >= 0.35 - TOL
    assert abs(dist[-1] - 0.35) <= TOL
    assert results[-1].active_set == ("obstacle_link_7",)
    reach.set_target(ee - np.array([0.1, 0.0, 0.0]))
    q, results, dist = simulate(jaco, h, solver, q, 500, watch=_sigma(task))
    assert dist.min() >= 0.35 - TOL
    assert dist[-1] > 0.40  # back above the activation threshold
    assert results[-1].active_set == ()
    assert np.linalg.norm(jaco.kinematics(q).frame_position("end_effector") - reach.target) < 0.01


def test_corner_of_two_walls_and_a_joint_limit_none_is_crossed(jaco, solver):
    kin = jaco.kinematics(jaco.home)
    ee = kin.frame_position("end_effector")
    q2 = float(jaco.home[1])
    limit = JointLimitTask("joint_limit_2", 2, jaco.nq, Thresholds(q2 - 0.2, q2 - 0.06, q2 + 0.06, q2 + 0.2, 0.03))
    wall_x = VirtualWallTask("wall_x_max", "end_effector", np.array([-1.0, 0.0, 0.0]), -(ee[0] + 0.06), WALL)
    wall_z = VirtualWallTask("wall_z_min", "end_effector", np.array([0.0, 0.0, 1.0]), ee[2] - 0.06, WALL)
    target = PositionTask("ee", target=ee + np.array([0.4, 0.1, -0.4]))
    h = Hierarchy([Level("joint_limits", (limit,)), Level("walls", (wall_x, wall_z)), Level("operational", (target,))])

    def margins(kin):
        return [limit.margins(limit.compute_value_and_jacobian(kin)[0])[0]] + [
            w.compute_value_and_jacobian(kin)[0] for w in (wall_x, wall_z)
        ]

    _, results, m = simulate(jaco, h, solver, jaco.home, 500, watch=margins)
    assert m.min() >= -TOL, f"crossed: worst margins {m.min(axis=0)}"
    assert max(len(r.active_set) for r in results) >= 2
    assert {name for r in results for name in r.active_set} == {"joint_limit_2", "wall_x_max", "wall_z_min"}


@pytest.mark.parametrize("variant", ["nsb", "ss"])
def test_case2_hierarchy_from_the_benchmark_states_stays_safe(jaco, variant):
    solver = TpikSolver(jaco, TpikSettings(variant=variant))
    h = case2_hierarchy(jaco)
    for state in case2_states(jaco):
        apply_state(h, state)
        # Push the EE outward toward the walls and beyond.
        for task in h.tasks:
            if isinstance(task, PositionTask):
                task.set_target(np.array([0.9, 0.9, 1.2]))

        def margins(kin):
            out = []
            for t in h.set_tasks:
                sigma = t.compute_value_and_jacobian(kin)[0]
                out.append(t.margins(sigma)[0] if math.isfinite(sigma) else 1.0)
            return out

        _, results, m = simulate(jaco, h, solver, state.q, 300, watch=margins)
        assert m.min() >= -TOL, f"{state.name}: worst safety margins {m.min(axis=0)}"
        assert all(r.ok for r in results)


class _JointSumTask(SetTask):
    """σ = q_1 + q_2 [rad] with an upper safety threshold: a set task coupled to joint 1."""

    def __init__(self, nq: int, upper: float) -> None:
        super().__init__("q1_plus_q2", Thresholds(-math.inf, -math.inf, upper, upper + 0.1, 0.05), gain=2.0)
        self._row = np.zeros((1, nq))
        self._row[0, :2] = 1.0

    def compute_value_and_jacobian(self, kin):
        return float(kin.q[0] + kin.q[1]), self._row


@pytest.mark.parametrize("compensate", [True, False])
def test_inserted_set_task_holds_although_a_higher_level_pushes_it_out(jaco, compensate):
    """Level 1 drives q1 up; level 2 keeps q1 + q2 ≤ 0.5 rad.

    Eq. 4 alone gives the inserted task σ̇ = q̇1 + x₂/2 (its own term is projected off joint 1),
    so it is dragged past its threshold at the speed of level 1; compensated, σ̇ = x₂ and it
    stays. The pure form must cross (else this test could not detect the difference).
    """
    coupled = _JointSumTask(jaco.nq, upper=0.5)
    drive = JointTargetTask("drive_q1", 1, jaco.nq, target=1.5, gain=1.0)
    solver = TpikSolver(jaco, TpikSettings(compensate_set_tasks=compensate))
    q0 = jaco.home.copy()
    q0[:2] = [0.0, 0.3]
    _, results, sigma = simulate(jaco, one_level_each(drive, coupled), solver, q0, 300, watch=coupled.compute_value)
    if compensate:
        assert sigma.max() <= 0.5 + TOL
        assert results[-1].active_set == ("q1_plus_q2",)
    else:
        assert sigma.max() > 0.5 + 0.2


@pytest.mark.parametrize("selection", ["fewest_active", "largest_norm"])
def test_a_task_the_lower_level_pulls_inward_is_released_not_pulled_to_its_threshold(jaco, selection):
    """Joint 4 starts in its upper activation band; level 2 pulls it 1 cm inward, slowly.

    Inserted, the limit's reference K(σ_s − σ) drives q4 *toward* the safety threshold, faster
    than the weak inward pull: the mode that holds it has the larger norm. The default rule
    releases it (the solution without it is admissible, eqs. 8–9) and q4 reaches its target.
    The largest-norm rule pulls it outward until holding and releasing have equal norms, then
    flips between the two every step or two (seed 838 of the hard campaign: the same chatter at a wall).
    """
    limit = JointLimitTask.from_robot(jaco, 4, safety_margin=0.1, activation_margin=0.05)
    s_u = limit.thresholds.safety_upper
    q0 = jaco.home.copy()
    q0[3] = s_u - 0.02
    pull = JointTargetTask("q4_inward", 4, jaco.nq, target=q0[3] - 0.01, gain=1.0)
    solver = TpikSolver(jaco, TpikSettings(selection=selection))
    q, results, _ = simulate(jaco, one_level_each(limit, pull), solver, q0, 500)
    if selection == "fewest_active":
        assert q[3] == pytest.approx(q0[3] - 0.01, abs=TOL)
        assert all(r.active_set == () for r in results)
    else:  # pulled outward to where holding and releasing have equal norms, then flips between them
        assert q[3] > q0[3] + 0.003
        held = [r.active_set == (limit.name,) for r in results[-100:]]
        assert sum(a != b for a, b in zip(held, held[1:], strict=False)) > 20
