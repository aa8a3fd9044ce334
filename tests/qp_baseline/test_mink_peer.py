"""The mink peer: same hierarchy, mink's weighted QP; limits from our set tasks hold in closed loop."""

from __future__ import annotations

import math

import mink
import numpy as np
import pytest

from qp_baseline.mink_peer import MinkSolver, SetTaskLimit
from tests.qp_baseline.helpers import (
    DT,
    joint_limit_level,
    obstacle_level,
    position_level,
    rollout,
    wall_box_level,
)
from tpik.hierarchy import Hierarchy, Level
from tpik.tasks import ManipulabilityTask, ObstacleDistanceTask, OrientationTask, PoseTask, Thresholds

CARTESIAN_TOLERANCE = 1e-4  # m, second-order term of one 10 ms step


def test_end_effector_reaches_a_free_target(jaco):
    ee = jaco.kinematics(jaco.home).frame_position("end_effector")
    target = ee + np.array([-0.10, 0.15, 0.10])
    hierarchy = Hierarchy([joint_limit_level(jaco), position_level(target, gain=5.0)])
    run = rollout(MinkSolver(jaco), hierarchy, jaco, jaco.home, steps=300)
    assert all(s.value == "ok" for s in run.statuses)
    assert np.linalg.norm(jaco.kinematics(run.q).frame_position("end_effector") - target) < 1e-3
    assert run.max_speed_ratio <= 1.0 + 1e-9


def test_velocity_is_what_mink_solve_ik_returns_for_the_same_problem(jaco):
    """Our adapter equals a hand-built mink problem: FrameTask (position only), joint limits."""
    kin = jaco.kinematics(jaco.home)
    target = kin.frame_position("end_effector") + np.array([0.02, -0.01, 0.03])
    hierarchy = Hierarchy([position_level(target, gain=2.0)])
    ours = MinkSolver(jaco).solve(hierarchy, kin, DT)

    configuration = mink.Configuration(jaco.mj_model, jaco.home)
    frame = mink.FrameTask("j2s7s300_end_effector", "body", position_cost=1.0, orientation_cost=0.0, gain=2.0 * DT)
    pose = configuration.get_transform_frame_to_world("j2s7s300_end_effector", "body").as_matrix()
    pose[:3, 3] = target
    frame.set_target(mink.SE3.from_matrix(pose))
    velocities = {name: float(v) for name, v in zip(jaco.joint_names, jaco.v_max, strict=True)}
    limits = [mink.ConfigurationLimit(jaco.mj_model), mink.VelocityLimit(jaco.mj_model, velocities)]
    theirs = mink.solve_ik(configuration, [frame], DT, "daqp", damping=1e-12, limits=limits)
    np.testing.assert_allclose(ours.qdot, theirs, atol=1e-9)
    # A per-second velocity: ṗ = K (p_d − p), up to mink's SE(3)-log Jacobian (second order in the
    # 4 cm error: ~1e-6 m/s here).
    J = kin.position_jacobian("end_effector")
    np.testing.assert_allclose(J @ ours.qdot, 2.0 * (target - kin.frame_position("end_effector")), atol=1e-5)


def test_walls_hold_in_closed_loop(jaco):
    ee = jaco.kinematics(jaco.home).frame_position("end_effector")
    target = np.array([0.8, ee[1], 0.1])
    hierarchy = Hierarchy(
        [joint_limit_level(jaco, gain=10.0), wall_box_level(gain=10.0), position_level(target, gain=2.0)]
    )
    run = rollout(MinkSolver(jaco), hierarchy, jaco, jaco.home, steps=150)
    assert min(run.worst_margin.values()) >= -CARTESIAN_TOLERANCE, run.worst_margin
    assert run.worst_margin["wall_x_max"] < 0.01
    assert all(s.value == "ok" for s in run.statuses)


def test_obstacle_distances_hold_in_closed_loop(jaco):
    kin = jaco.kinematics(jaco.home)
    ee = kin.frame_position("end_effector")
    level = obstacle_level(gain=10.0)
    for task in level.tasks:
        assert isinstance(task, ObstacleDistanceTask)
        task.set_obstacle(ee + np.array([0.2, 0.5, -0.05]))
    hierarchy = Hierarchy(
        [joint_limit_level(jaco, gain=10.0), level, position_level(ee + np.array([0.0, 0.8, 0.1]), gain=2.0)]
    )
    run = rollout(MinkSolver(jaco), hierarchy, jaco, jaco.home, steps=150)
    distances = {k: v for k, v in run.worst_margin.items() if k.startswith("obstacle_")}
    assert min(distances.values()) >= -CARTESIAN_TOLERANCE, distances
    assert min(distances.values()) < 0.01


def test_binding_limit_is_reported_in_the_active_set(jaco):
    kin = jaco.kinematics(jaco.home)
    task = ObstacleDistanceTask("obstacle", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05), gain=10.0)
    p6 = kin.frame_position("link_6")
    task.set_obstacle(p6 + 0.37 * np.array([0.0, 0.6, 0.8]))
    hierarchy = Hierarchy([Level("safety", (task,)), position_level(task.obstacle, gain=5.0)])
    result = MinkSolver(jaco).solve(hierarchy, kin, DT)
    assert result.status.value == "ok"
    assert result.active_set == ("obstacle",)
    state = task.compute_state(kin)
    lo, _ = task.velocity_bounds(state, DT)
    assert float(state.jacobian[0] @ result.qdot) == pytest.approx(lo, abs=1e-6)
    assert result.build_time_s > 0.0 and result.solve_time_s > 0.0


def test_infeasible_hard_limits_give_a_failed_step_with_zero_velocity(jaco):
    kin = jaco.kinematics(jaco.home)
    task = ObstacleDistanceTask("obstacle", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05), gain=100.0)
    task.set_obstacle(kin.frame_position("link_6") + np.array([0.0, 0.18, 0.24]))  # 0.30 m: σ̇ ≥ 5 m/s
    hierarchy = Hierarchy([Level("safety", (task,)), position_level(kin.frame_position("end_effector"))])
    result = MinkSolver(jaco).solve(hierarchy, kin, DT)
    assert result.status.value == "failed"
    assert "mink" in result.message
    assert np.array_equal(result.qdot, np.zeros(jaco.nq))


def test_orientation_pose_and_other_equality_tasks_are_handled(jaco):
    kin = jaco.kinematics(jaco.home)
    pose = kin.frame_pose("end_effector")
    pose[:3, 3] += np.array([0.03, 0.0, 0.0])
    rot = kin.frame_rotation("end_effector")
    for hierarchy in (
        Hierarchy([Level("pose", (PoseTask("pose", target=pose),))]),
        Hierarchy([Level("p", (PoseTask("pose", target=pose),)), Level("m", (ManipulabilityTask("m", target=0.5),))]),
        Hierarchy([Level("o", (OrientationTask("o", target=rot.T @ rot @ rot),))]),
    ):
        run = rollout(MinkSolver(jaco), hierarchy, jaco, jaco.home, steps=50)
        assert all(s.value == "ok" for s in run.statuses)
    # The pose task converges (gain 1/s, 0.5 s: error × e^-0.5, twice the weighted compromise).
    hierarchy = Hierarchy([Level("pose", (PoseTask("pose", gain=5.0, target=pose),))])
    run = rollout(MinkSolver(jaco), hierarchy, jaco, jaco.home, steps=150)
    assert np.linalg.norm(jaco.kinematics(run.q).frame_position("end_effector") - pose[:3, 3]) < 1e-3


def test_set_task_limit_is_a_mink_limit_producing_g_dq_le_h(jaco):
    limit = SetTaskLimit(jaco.nq)
    configuration = mink.Configuration(jaco.mj_model, jaco.home)
    assert limit.compute_qp_inequalities(configuration, DT).inactive
    G = np.ones((1, jaco.nq))
    limit.set_rows(G, np.array([0.3]), ["wall"])
    constraint = limit.compute_qp_inequalities(configuration, DT)
    assert isinstance(limit, mink.Limit)
    np.testing.assert_array_equal(constraint.G, G)
    np.testing.assert_allclose(constraint.h, [0.3 * DT])  # Δq = q̇ dt
