"""The mink peers (mink, mink-hard): same hierarchy, mink's weighted QP; limits hold in closed loop."""

from __future__ import annotations

import math

import mink
import numpy as np
import pytest

from qp_baseline.mink_kinematics import MinkKinematics
from qp_baseline.mink_peer import MinkSolver, SetTaskLimit
from tests.qp_baseline.helpers import (
    DT,
    joint_limit_level,
    obstacle_level,
    position_level,
    rollout,
    wall_behind_ee,
    wall_box_level,
)
from tpik.hierarchy import Hierarchy, Level
from tpik.tasks import (
    ManipulabilityTask,
    ObstacleDistanceTask,
    OrientationTask,
    PoseTask,
    Thresholds,
)

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


@pytest.mark.parametrize("formulation", ["soft_return", "hard"])
def test_walls_hold_in_closed_loop(jaco, formulation):
    ee = jaco.kinematics(jaco.home).frame_position("end_effector")
    target = np.array([0.8, ee[1], 0.1])
    hierarchy = Hierarchy(
        [joint_limit_level(jaco, gain=10.0), wall_box_level(gain=10.0), position_level(target, gain=2.0)]
    )
    run = rollout(MinkSolver(jaco, formulation=formulation), hierarchy, jaco, jaco.home, steps=150)
    assert min(run.worst_margin.values()) >= -CARTESIAN_TOLERANCE, run.worst_margin
    assert run.worst_margin["wall_x_max"] < 0.01
    assert all(s.value == "ok" for s in run.statuses)


@pytest.mark.parametrize("formulation", ["soft_return", "hard"])
def test_obstacle_distances_hold_in_closed_loop(jaco, formulation):
    kin = jaco.kinematics(jaco.home)
    ee = kin.frame_position("end_effector")
    level = obstacle_level(gain=10.0)
    for task in level.tasks:
        assert isinstance(task, ObstacleDistanceTask)
        task.set_obstacle(ee + np.array([0.2, 0.5, -0.05]))
    hierarchy = Hierarchy(
        [joint_limit_level(jaco, gain=10.0), level, position_level(ee + np.array([0.0, 0.8, 0.1]), gain=2.0)]
    )
    run = rollout(MinkSolver(jaco, formulation=formulation), hierarchy, jaco, jaco.home, steps=150)
    distances = {k: v for k, v in run.worst_margin.items() if k.startswith("obstacle_")}
    assert min(distances.values()) >= -CARTESIAN_TOLERANCE, distances
    assert min(distances.values()) < 0.01


@pytest.mark.parametrize("formulation", ["soft_return", "hard"])
def test_binding_limit_is_reported_in_the_active_set(jaco, formulation):
    kin = jaco.kinematics(jaco.home)
    task = ObstacleDistanceTask("obstacle", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05), gain=10.0)
    p6 = kin.frame_position("link_6")
    task.set_obstacle(p6 + 0.37 * np.array([0.0, 0.6, 0.8]))
    hierarchy = Hierarchy([Level("safety", (task,)), position_level(task.obstacle, gain=5.0)])
    result = MinkSolver(jaco, formulation=formulation).solve(hierarchy, kin, DT)
    assert result.status.value == "ok"
    assert result.active_set == ("obstacle",)
    state = task.compute_state(kin)
    lo, _ = task.velocity_bounds(state, DT)
    assert float(state.jacobian[0] @ result.qdot) == pytest.approx(lo, abs=1e-6)
    assert result.build_time_s > 0.0 and result.solve_time_s > 0.0


def _person_too_close(jaco, gain=100.0):
    """An obstacle 0.30 m from link_6 (safety 0.35 m): the return rate K(0.35 − 0.30) = 5 m/s."""
    kin = jaco.kinematics(jaco.home)
    task = ObstacleDistanceTask("obstacle", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05), gain=gain)
    task.set_obstacle(kin.frame_position("link_6") + np.array([0.0, 0.18, 0.24]))
    hierarchy = Hierarchy([Level("safety", (task,)), position_level(kin.frame_position("end_effector"))])
    return kin, task, hierarchy


def test_mink_hard_fails_where_the_return_rate_cannot_be_met(jaco):
    kin, _, hierarchy = _person_too_close(jaco)
    result = MinkSolver(jaco, name="mink-hard", formulation="hard").solve(hierarchy, kin, DT)
    assert result.status.value == "failed"
    assert "mink-hard" in result.message
    assert np.array_equal(result.qdot, np.zeros(jaco.nq))


def test_mink_moves_away_at_what_the_joints_allow_where_mink_hard_fails(jaco):
    """Δq = 0 is feasible for mink's limits: the arm retreats as fast as it can, and says DEGRADED."""
    kin, task, hierarchy = _person_too_close(jaco)
    result = MinkSolver(jaco).solve(hierarchy, kin, DT)
    assert result.status.value == "degraded" and "obstacle" in result.message
    rate = float(task.compute_state(kin).jacobian[0] @ result.qdot)
    assert 0.05 < rate < 5.0  # away from the person, slower than the unreachable 5 m/s
    assert np.all(np.abs(result.qdot) <= jaco.v_max + 1e-12)
    assert result.extras["returning"] == ["obstacle"]


def test_return_task_is_weighted_above_the_operational_task(jaco):
    """Past its threshold a wall comes back at its reference rate although the EE target is beyond it."""
    kin = jaco.kinematics(jaco.home)
    ee = kin.frame_position("end_effector")
    wall = wall_behind_ee(ee, 0.01, gain=2.0)
    hierarchy = Hierarchy([Level("walls", (wall,)), position_level(ee - np.array([0.2, 0.0, 0.0]), gain=2.0)])
    result = MinkSolver(jaco).solve(hierarchy, kin, DT)
    rate = float(wall.compute_state(kin).jacobian[0] @ result.qdot)
    # K (σ_s − σ) = 2 · 0.01 m = 0.02 m/s against the target's −0.4 m/s: a weighted compromise,
    # min 10² (a − 0.02)² + (a + 0.4)², i.e. a ≈ 0.0158 m/s for ρ = 10, ≈ 0.01996 for ρ = 100.
    assert rate == pytest.approx((100 * 0.02 - 0.4) / 101, rel=0.02)
    strict = MinkSolver(jaco, {"level_cost_ratio": 100.0}).solve(hierarchy, kin, DT)
    assert float(wall.compute_state(kin).jacobian[0] @ strict.qdot) == pytest.approx(
        (1e4 * 0.02 - 0.4) / 10001, rel=1e-3
    )
    hard = MinkSolver(jaco, formulation="hard").solve(hierarchy, kin, DT)
    assert float(wall.compute_state(kin).jacobian[0] @ hard.qdot) == pytest.approx(0.02, abs=1e-6)


def test_zero_step_satisfies_every_soft_formulation_limit(jaco):
    """Random states, tasks on both sides of their thresholds: G·0 ≤ h for mink, not always for mink-hard."""
    rng = np.random.default_rng(3)
    soft, hard = MinkSolver(jaco), MinkSolver(jaco, formulation="hard")
    hard_infeasible_at_zero = 0
    for _ in range(30):
        q = jaco.home + rng.uniform(-0.4, 0.4, size=jaco.nq)
        kin = jaco.kinematics(q)
        level = obstacle_level(gain=2.0)
        for t in level.tasks:
            t.set_obstacle(kin.frame_position(t.frame) + rng.uniform(0.2, 0.45) * rng.normal(size=3) / 1.7)
        hierarchy = Hierarchy([joint_limit_level(jaco, gain=2.0), wall_box_level(gain=2.0), level])
        for solver in (soft, hard):
            solver.solve(hierarchy, kin, DT)
        assert np.all(soft._limit_rows._h >= 0.0)
        hard_infeasible_at_zero += bool(np.any(hard._limit_rows._h < 0.0))
    assert hard_infeasible_at_zero > 0  # the states do put tasks past their thresholds


def test_returned_step_is_checked_in_delta_q_units_at_the_backend_tolerance(jaco):
    """A step within DAQP's 1e-6 of its constraints (in Δq, = 1e-4 rad/s) is accepted; 1e-5 is not."""
    import qpsolvers

    kin = jaco.kinematics(jaco.home)
    target = kin.frame_position("end_effector") + np.array([0.3, 0.0, 0.0])
    hierarchy = Hierarchy([position_level(target, gain=50.0)])
    solver = MinkSolver(jaco)
    exact = solver.solve(hierarchy, kin, DT)
    assert solver.tolerance == 1e-6
    problem = mink.build_ik(solver.configuration, solver._tasks, DT, 1e-12, solver._limits)
    x = exact.qdot * DT
    row = int(np.argmax(problem.G @ x - problem.h))  # the binding velocity limit
    rows = solver._rows.build(MinkKinematics(jaco, solver.configuration, {}), DT)
    for excess, status in ((5e-7, "ok"), (1e-5, "failed")):
        bumped = x + excess * problem.G[row] / float(problem.G[row] @ problem.G[row])
        solution = qpsolvers.Solution(problem)
        solution.x, solution.found = bumped, True
        assert solver._finish(solution, problem, rows, [], DT).status.value == status


def test_mink_kinematics_agree_with_pinocchio(jaco):
    rng = np.random.default_rng(4)
    configuration = mink.Configuration(jaco.mj_model)
    for _ in range(10):
        q = jaco.home + rng.uniform(-1.0, 1.0, size=jaco.nq)
        configuration.update(q)
        mkin, kin = MinkKinematics(jaco, configuration, {}), jaco.kinematics(q)
        for frame in ("end_effector", "link_4", "j2s7s300_link_6", "link_7"):
            np.testing.assert_allclose(mkin.frame_position(frame), kin.frame_position(frame), atol=1e-12)
            np.testing.assert_allclose(mkin.frame_pose(frame), kin.frame_pose(frame), atol=1e-12)
            np.testing.assert_allclose(mkin.frame_jacobian(frame), kin.frame_jacobian(frame), atol=1e-12)
            np.testing.assert_allclose(mkin.position_jacobian(frame), kin.position_jacobian(frame), atol=1e-12)
            np.testing.assert_allclose(
                mkin.partial_position_jacobian(frame), kin.partial_position_jacobian(frame), atol=1e-12
            )
        np.testing.assert_allclose(mkin.joint_origins(), kin.joint_origins(), atol=1e-12)


def test_mink_kinematics_fill_frames_gives_the_per_frame_numbers_bit_for_bit(jaco):
    """The one-pass frames of the shared evaluation are MuJoCo's xpos and mj_jacBody, as the per-frame methods."""
    rng = np.random.default_rng(5)
    configuration = mink.Configuration(jaco.mj_model)
    names = ("end_effector", "link_4", "j2s7s300_link_6", "link_7")
    for _ in range(10):
        configuration.update(jaco.home + rng.uniform(-1.0, 1.0, size=jaco.nq))
        out = np.full((len(names), 4, jaco.nq), np.nan)
        MinkKinematics(jaco, configuration, {}).fill_frames(names, out)
        mkin = MinkKinematics(jaco, configuration, {})
        for f, frame in enumerate(names):
            np.testing.assert_array_equal(out[f, 0, :3], mkin.frame_position(frame))
            np.testing.assert_array_equal(out[f, 1:4], mkin.position_jacobian(frame))


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
    limit.set_rows(G, np.array([0.3]))
    constraint = limit.compute_qp_inequalities(configuration, DT)
    assert isinstance(limit, mink.Limit)
    np.testing.assert_array_equal(constraint.G, G)
    np.testing.assert_allclose(constraint.h, [0.3 * DT])  # Δq = q̇ dt
