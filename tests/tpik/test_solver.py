"""The paper's TPIK solver: exactness, priority, damping, limits, mode selection, bad inputs."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from compare.methods import UnknownMethod, available_methods, make_method
from robots.exceptions import InvalidConfiguration
from tests.conftest import random_configuration
from tests.tpik.conftest import (
    BadShapeTask,
    MatrixTask,
    RowSetTask,
    one_level_each,
    reference_cascade,
)
from tpik.exceptions import EmptyHierarchy, InvalidTaskState, TpikError
from tpik.hierarchy import Hierarchy, Level
from tpik.solver import InvalidSettings, TpikSettings, TpikSolver, solve_tpik
from tpik.step_result import SolveStatus
from tpik.tasks import ObstacleDistanceTask, PositionTask, Thresholds

DT = 0.01


def _random_levels(rng: np.random.Generator, n: int, dims: list[int], scale: float = 0.05):
    return [(rng.normal(size=(m, n)), scale * rng.normal(size=m)) for m in dims]


def _hierarchy(levels) -> Hierarchy:
    return one_level_each(*(MatrixTask(f"t{i}", J, x) for i, (J, x) in enumerate(levels)))


# --------------------------------------------------------------------------- equality tasks


def test_single_full_rank_task_gives_the_pseudo_inverse_solution(jaco):
    rng = np.random.default_rng(1)
    solver = TpikSolver(jaco)
    for _ in range(10):
        q = random_configuration(jaco, rng)
        kin = jaco.kinematics(q)
        ee = kin.frame_position("end_effector")
        task = PositionTask("ee", target=ee + rng.uniform(-0.02, 0.02, 3), gain=2.0)
        qdot, report = solver.solve(one_level_each(task), kin, DT)
        J = kin.position_jacobian("end_effector")
        expected = np.linalg.pinv(J) @ (2.0 * (task.target - ee))
        np.testing.assert_allclose(qdot, expected, atol=1e-10)
        assert report.status is SolveStatus.OK
        assert report.damping == {"level_0": 0.0}


def test_zero_velocity_when_every_task_is_satisfied(jaco):
    kin = jaco.kinematics(jaco.home)
    task = PositionTask("ee", target=kin.frame_position("end_effector"))
    qdot, report = TpikSolver(jaco).solve(one_level_each(task), kin, DT)
    np.testing.assert_allclose(qdot, 0.0, atol=1e-12)
    assert report.ok


def test_near_a_singularity_the_velocity_stays_bounded_and_damped(jaco):
    rng = np.random.default_rng(2)
    n = jaco.nq
    U, _, Vt = np.linalg.svd(rng.normal(size=(3, n)), full_matrices=False)
    solver = TpikSolver(jaco)
    for sigma_min in (1e-3, 1e-6, 1e-9, 0.0):
        J = U @ np.diag([1.0, 0.5, sigma_min]) @ Vt
        task = MatrixTask("nearly_singular", J, np.array([0.1, 0.1, 0.1]))
        qdot, report = solver.solve(one_level_each(task), jaco.kinematics(jaco.home), DT)
        assert np.all(np.isfinite(qdot))
        assert np.all(np.abs(qdot) <= jaco.v_max * (1 + 1e-12))
        assert report.damping["level_0"] > 0.0
        assert report.status is SolveStatus.DEGRADED


def test_stretched_arm_reaching_out_is_bounded(jaco):
    q = jaco.home.copy()
    q[1], q[3] = np.pi, np.pi  # shoulder up, elbow straight: the position Jacobian loses rank
    kin = jaco.kinematics(q)
    far = kin.frame_position("end_effector") + np.array([0.0, 0.0, 0.5])
    qdot, report = TpikSolver(jaco).solve(one_level_each(PositionTask("ee", target=far)), kin, DT)
    assert np.all(np.isfinite(qdot)) and np.all(np.abs(qdot) <= jaco.v_max * (1 + 1e-12))
    assert report.damping["level_0"] > 0.0


def test_dynamic_damping_bounds_each_level_by_the_velocity_norm(jaco):
    rng = np.random.default_rng(3)
    vnorm = 0.05  # small, so that the bound bites before the joint limits do
    solver = TpikSolver(jaco, TpikSettings(velocity_norm_max=vnorm))
    for _ in range(20):
        J = rng.normal(size=(3, jaco.nq)) * rng.uniform(0.01, 1.0)
        x = rng.normal(size=3)
        qdot, _ = solver.solve(one_level_each(MatrixTask("t", J, x)), jaco.kinematics(jaco.home), DT)
        assert np.linalg.norm(qdot) <= vnorm * (1 + 1e-9)


def test_velocity_limits_scale_the_whole_vector_and_keep_its_direction(jaco):
    rng = np.random.default_rng(4)
    J = rng.normal(size=(2, jaco.nq))
    x = np.array([30.0, -20.0])
    big = TpikSolver(jaco, TpikSettings(velocity_norm_max=1e6))
    qdot, report = big.solve(one_level_each(MatrixTask("t", J, x)), jaco.kinematics(jaco.home), DT)
    unscaled = np.linalg.pinv(J) @ x
    assert np.max(np.abs(qdot) / jaco.v_max) == pytest.approx(1.0)
    np.testing.assert_allclose(qdot / np.linalg.norm(qdot), unscaled / np.linalg.norm(unscaled), atol=1e-12)
    assert report.extras["velocity_scale"] < 1.0
    assert report.status is SolveStatus.DEGRADED


# --------------------------------------------------------------------------- priority


@pytest.mark.parametrize("variant", ["nsb", "ss"])
def test_highest_level_is_met_exactly_whatever_lower_levels_ask(jaco, variant):
    rng = np.random.default_rng(5)
    solver = TpikSolver(jaco, TpikSettings(variant=variant))
    for _ in range(30):
        kin = jaco.kinematics(random_configuration(jaco, rng))
        levels = _random_levels(rng, jaco.nq, [int(rng.integers(1, 4)), 2, int(rng.integers(1, 4))])
        J1, x1 = levels[0]
        qdot, report = solver.solve(_hierarchy(levels), kin, DT)
        assert report.extras["velocity_scale"] == 1.0 and report.damping["level_0"] == 0.0
        np.testing.assert_allclose(J1 @ qdot, x1, atol=1e-9)
        # Whatever the lower levels ask, levels 1..k keep their task velocities.
        for k in (1, 2):
            other = levels[:k] + _random_levels(rng, jaco.nq, [3, 2][: 3 - k], scale=0.05)
            qdot2, report2 = solver.solve(_hierarchy(other), kin, DT)
            scale = report2.extras["velocity_scale"]  # the joint-limit scaling is uniform
            for J, _x in levels[:k]:
                np.testing.assert_allclose(J @ qdot2, scale * (J @ qdot), atol=1e-9)


def test_ss_meets_every_feasible_level_exactly(jaco):
    rng = np.random.default_rng(6)
    solver = TpikSolver(jaco, TpikSettings(variant="ss"))
    for _ in range(30):
        levels = _random_levels(rng, jaco.nq, [2, 2, 2], scale=0.02)  # 6 rows ≤ 7 joints: all feasible
        qdot, report = solver.solve(_hierarchy(levels), jaco.kinematics(jaco.home), DT)
        if any(lam > 0.0 for lam in report.damping.values()):
            continue  # a damped level is not exact by construction
        for J, x in levels:
            np.testing.assert_allclose(J @ qdot, x, atol=1e-9)


def test_a_level_stacks_its_tasks(jaco):
    rng = np.random.default_rng(7)
    (J1, x1), (J2, x2) = _random_levels(rng, jaco.nq, [2, 3])
    level = Level("both", (MatrixTask("a", J1, x1), MatrixTask("b", J2, x2)))
    qdot, _ = TpikSolver(jaco).solve(Hierarchy([level]), jaco.kinematics(jaco.home), DT)
    np.testing.assert_allclose(qdot, np.linalg.pinv(np.vstack([J1, J2])) @ np.concatenate([x1, x2]), atol=1e-10)


@pytest.mark.parametrize("variant", ["nsb", "ss"])
def test_cascade_matches_a_textbook_svd_implementation(jaco, variant):
    """Random levels, some rank-deficient or tall, some damped: same q̇ and λ as plain SVD code."""
    rng = np.random.default_rng(8)
    n = jaco.nq
    solver = TpikSolver(jaco, TpikSettings(variant=variant, velocity_norm_max=1e3))
    for trial in range(60):
        dims = [int(d) for d in rng.integers(1, 5, size=int(rng.integers(1, 5)))]
        levels = []
        for m in dims:
            J = rng.normal(size=(m, n))
            if rng.random() < 0.3 and m > 1:  # rank-deficient level
                J[-1] = J[0] * rng.normal()
            if rng.random() < 0.2:  # a row in the span of the levels above
                if levels:
                    J[0] = levels[0][0][0] * 0.5
            levels.append((J, rng.normal(size=m) * (0.01 if trial % 2 else 1.0)))
        expected, lams = reference_cascade(levels, variant, 1e3)
        qdot, report = solver.solve(_hierarchy(levels), jaco.kinematics(jaco.home), DT)
        scale = report.extras["velocity_scale"]
        np.testing.assert_allclose(qdot, expected * scale, atol=1e-8 * max(1.0, np.abs(expected).max()))
        np.testing.assert_allclose(list(report.damping.values()), lams, atol=1e-9)


# --------------------------------------------------------------------------- set-based modes


def _th(lo: float = -1.0, hi: float = 1.0, eps: float = 0.1) -> Thresholds:
    return Thresholds(lo - 0.5, lo, hi, hi + 0.5, eps)


def test_set_task_inside_its_activation_thresholds_is_left_out(jaco):
    row = np.eye(jaco.nq)[0]
    task = RowSetTask("s", 0.0, row, _th())
    push = MatrixTask("push", row[None, :], np.array([0.3]))
    qdot, report = TpikSolver(jaco).solve(one_level_each(task, push), jaco.kinematics(jaco.home), DT)
    assert report.active_set == () and report.extras["candidates"] == 0
    assert qdot[0] == pytest.approx(0.3)


def test_obstacle_without_obstacle_is_inactive(jaco):
    th = Thresholds(0.1, 0.35, math.inf, math.inf, 0.05)
    task = ObstacleDistanceTask("obs", "link_6", th)
    task.set_obstacle(None)
    kin = jaco.kinematics(jaco.home)
    ee = PositionTask("ee", target=kin.frame_position("end_effector") + 0.01)
    _, report = TpikSolver(jaco).solve(one_level_each(task, ee), kin, DT)
    assert report.active_set == () and report.extras["candidates"] == 0


@pytest.mark.parametrize("push", [0.3, -0.3])
def test_a_task_past_its_upper_threshold_is_held_only_when_pushed_out(jaco, solver, push):
    row = np.eye(jaco.nq)[2]
    task = RowSetTask("s", 0.95, row, _th())  # σ_{a,u} = 0.9 ≤ σ < σ_{s,u} = 1
    lower = MatrixTask("lower", row[None, :], np.array([push]))
    qdot, report = solver.solve(one_level_each(task, lower), jaco.kinematics(jaco.home), DT)
    if push > 0:  # would move further out: inserted with σ_d = σ_{s,u}, K = 1 → σ̇ = 0.05
        assert report.active_set == ("s",)
        assert qdot[2] == pytest.approx(0.05)
    else:  # the solution without it moves it back in (eq. 8): released
        assert report.active_set == ()
        assert qdot[2] == pytest.approx(-0.3)


@pytest.mark.parametrize("pull", [0.0, -0.01, -0.3])
def test_a_task_past_its_safety_threshold_is_released_only_when_brought_back_as_fast(jaco, solver, pull):
    """σ = 1.05 > σ_{s,u} = 1 (an obstacle walked in): its reference is K(σ_s − σ) = −0.05.

    Eqs. 8–9 alone would release it whenever the rest of the hierarchy does not push it
    further out, so an arm holding still would never react to a person walking into it.
    """
    row = np.eye(jaco.nq)[2]
    task = RowSetTask("s", 1.05, row, _th())
    lower = MatrixTask("lower", row[None, :], np.array([pull]))
    qdot, report = solver.solve(one_level_each(task, lower), jaco.kinematics(jaco.home), DT)
    if pull > -0.05:  # still, or back too slowly: held, back at the reference rate
        assert report.active_set == ("s",)
        assert qdot[2] == pytest.approx(-0.05)
    else:
        assert report.active_set == ()
        assert qdot[2] == pytest.approx(pull)


def test_largest_norm_and_fewest_active_rules_differ_as_documented(jaco):
    """In the activation band, holding σ_d = σ_s pulls outward: larger norm than a weak release."""
    row = np.eye(jaco.nq)[2]
    task = RowSetTask("s", 0.9, row, _th())  # at σ_{a,u}: the active reference is +0.1
    lower = MatrixTask("lower", row[None, :], np.array([-0.02]))  # weak inward pull
    h = one_level_each(task, lower)
    kin = jaco.kinematics(jaco.home)
    _, largest = TpikSolver(jaco, TpikSettings(selection="largest_norm")).solve(h, kin, DT)
    _, fewest = TpikSolver(jaco, TpikSettings(selection="fewest_active")).solve(h, kin, DT)
    assert largest.active_set == ("s",) and largest.extras["selection"] == "largest_norm"
    assert fewest.active_set == () and fewest.extras["selection"] == "fewest_active"


@pytest.mark.parametrize(
    ("settings", "rule"),
    [
        ({}, "fewest_active"),
        ({"variant": "ss"}, "fewest_active"),
        ({"compensate_set_tasks": False}, "fewest_active"),
        ({"selection": "largest_norm"}, "largest_norm"),
    ],
)
def test_selection_is_one_setting_independent_of_the_others(jaco, settings, rule):
    """Each deviation from the paper is one setting: switching compensation off keeps the rule."""
    row = np.eye(jaco.nq)[2]
    h = one_level_each(RowSetTask("s", 0.9, row, _th()), MatrixTask("lower", row[None, :], np.array([-0.02])))
    _, report = TpikSolver(jaco, TpikSettings(**settings)).solve(h, jaco.kinematics(jaco.home), DT)
    assert TpikSettings(**settings).selection == rule and report.extras["selection"] == rule


@pytest.mark.parametrize("max_exhaustive", [6, 0])
def test_chosen_mode_never_moves_a_left_out_task_further_out(jaco, max_exhaustive):
    """Eqs. 8–9 on random rows: every candidate left out moves inward (or not at all)."""
    rng = np.random.default_rng(9)
    n = jaco.nq
    for variant in ("nsb", "ss"):
        solver = TpikSolver(jaco, TpikSettings(variant=variant, max_exhaustive_candidates=max_exhaustive))
        for _ in range(25):
            tasks = []
            for i in range(int(rng.integers(1, 6))):
                side = rng.choice([-1.0, 1.0])
                sigma = 0.95 * side  # inside the activation band of one side
                tasks.append(RowSetTask(f"s{i}", sigma, rng.normal(size=n), _th()))
            lower = MatrixTask("lower", rng.normal(size=(3, n)), rng.normal(size=3) * 0.2)
            levels = [Level("safety", tuple(tasks[:2]))]
            if len(tasks) > 2:
                levels.append(Level("more", tuple(tasks[2:])))
            levels.append(Level("lower", (lower,)))
            qdot, report = solver.solve(Hierarchy(levels), jaco.kinematics(jaco.home), DT)
            assert np.all(np.isfinite(qdot))
            for t in tasks:
                if t.name not in report.active_set:
                    assert np.sign(t.sigma) * float(t.row[0] @ qdot) <= 1e-9
            expected_search = "exhaustive" if len(tasks) <= max_exhaustive else "greedy"
            assert report.extras["search"] == expected_search


def test_greedy_release_is_used_above_the_threshold_and_reported(jaco):
    n = jaco.nq
    rows = np.eye(n)
    tasks = [RowSetTask(f"j{i}", 0.95, rows[i], _th()) for i in range(5)]
    lower = MatrixTask("lower", rows[:5], np.array([-0.2, -0.2, 0.3, 0.3, -0.2]))
    h = Hierarchy([Level("safety", tuple(tasks)), Level("lower", (lower,))])
    kin = jaco.kinematics(jaco.home)
    qdot, greedy = TpikSolver(jaco, TpikSettings(max_exhaustive_candidates=2)).solve(h, kin, DT)
    qdot_ex, exhaustive = TpikSolver(jaco).solve(h, kin, DT)
    assert greedy.extras["search"] == "greedy" and exhaustive.extras["search"] == "exhaustive"
    assert greedy.extras["modes_evaluated"] < exhaustive.extras["modes_evaluated"] == 32
    # Decoupled rows: releasing the inward-pulled joints is optimal, and greedy finds it.
    assert set(greedy.active_set) == set(exhaustive.active_set) == {"j2", "j3"}
    np.testing.assert_allclose(qdot, qdot_ex, atol=1e-12)
    assert "greedy" in greedy.message


# --------------------------------------------------------------------------- report, registry


def test_step_result_unpacks_and_reports(jaco):
    kin = jaco.kinematics(jaco.home)
    task = PositionTask("ee", target=kin.frame_position("end_effector") + 0.01)
    qdot, report = TpikSolver(jaco, name="tpik").solve(one_level_each(task), kin, DT)
    assert qdot is report.qdot and qdot.shape == (jaco.nq,)
    assert report.build_time_s > 0.0 and report.solve_time_s > 0.0
    assert report.extras["modes_evaluated"] == 1 and report.extras["variant"] == "nsb"
    assert solve_tpik(one_level_each(task), jaco.kinematics(jaco.home), DT).qdot == pytest.approx(qdot)


def test_registry_builds_both_variants(jaco):
    names = available_methods()
    assert {"tpik", "tpik-paper", "tpik-ss"} <= set(names)
    assert "tpik-nsb" not in names  # it was tpik under another name
    assert TpikSolver.VARIANTS[0] == "nsb"
    ss = make_method("tpik-ss", jaco, {"selection": "fewest_active"})
    assert ss.name == "tpik-ss" and ss.settings.variant == "ss" and ss.settings.selection == "fewest_active"
    assert make_method("tpik", jaco).settings.variant == "nsb"
    with pytest.raises(UnknownMethod, match="tpik-foo"):
        make_method("tpik-foo", jaco)


@pytest.mark.parametrize(
    ("values", "match"),
    [
        ({"damping": 1.0}, "unknown TPIK setting 'damping'"),
        ({"variant": "qp"}, "variant: unknown TPIK variant 'qp'"),
        ({"selection": "random"}, "selection: unknown rule"),
        ({"max_exhaustive_candidates": -1}, "max_exhaustive_candidates"),
        ({"max_exhaustive_candidates": 2.5}, "max_exhaustive_candidates: must be an integer"),
        ({"velocity_norm_max": 0.0}, "velocity_norm_max"),
        ({"rank_tolerance": "small"}, "rank_tolerance: must be a number"),
        ({"admissibility_tolerance": math.nan}, "admissibility_tolerance"),
    ],
)
def test_bad_settings_name_the_key(values, match):
    with pytest.raises(InvalidSettings, match=match):
        TpikSettings.from_dict(values)
    assert issubclass(InvalidSettings, TpikError) and issubclass(InvalidSettings, ValueError)


# --------------------------------------------------------------------------- bad inputs


def test_nan_configuration_is_rejected_before_the_solver(jaco):
    q = jaco.home.copy()
    q[2] = np.nan
    with pytest.raises(InvalidConfiguration, match="non-finite"):
        jaco.kinematics(q)


def test_wrong_jacobian_shape_raises_invalid_task_state(jaco):
    with pytest.raises(InvalidTaskState, match="'bad': jacobian has shape"):
        TpikSolver(jaco).solve(one_level_each(BadShapeTask()), jaco.kinematics(jaco.home), DT)
    row = RowSetTask("short_row", 0.95, np.ones(jaco.nq - 1), _th())
    with pytest.raises(InvalidTaskState, match="'short_row'"):
        TpikSolver(jaco).solve(one_level_each(row), jaco.kinematics(jaco.home), DT)


def test_non_finite_jacobian_raises_invalid_task_state(jaco):
    J = np.ones((2, jaco.nq))
    J[1, 3] = np.inf
    with pytest.raises(InvalidTaskState, match="'inf_jac': jacobian has non-finite"):
        TpikSolver(jaco).solve(one_level_each(MatrixTask("inf_jac", J, np.zeros(2))), jaco.kinematics(jaco.home), DT)
    row = np.ones(jaco.nq)
    row[0] = np.nan
    with pytest.raises(InvalidTaskState, match="'nan_row'"):
        TpikSolver(jaco).solve(one_level_each(RowSetTask("nan_row", 0.95, row, _th())), jaco.kinematics(jaco.home), DT)


def test_non_finite_reference_fails_with_zero_velocity(jaco):
    task = MatrixTask("nan_ref", np.eye(jaco.nq)[:2], np.array([np.nan, 0.1]))
    qdot, report = TpikSolver(jaco).solve(one_level_each(task), jaco.kinematics(jaco.home), DT)
    assert report.status is SolveStatus.FAILED and not report.ok
    np.testing.assert_array_equal(qdot, np.zeros(jaco.nq))
    assert "non-finite" in report.message


def test_empty_hierarchy_is_rejected(jaco):
    with pytest.raises(EmptyHierarchy):
        Hierarchy([])
    with pytest.raises(EmptyHierarchy):
        Level("empty", ())


@pytest.mark.parametrize("dt", [0.0, -0.01, math.inf, math.nan])
def test_bad_dt_is_rejected(jaco, dt):
    task = MatrixTask("t", np.eye(jaco.nq)[:1], np.array([0.1]))
    with pytest.raises(TpikError, match="dt must be"):
        TpikSolver(jaco).solve(one_level_each(task), jaco.kinematics(jaco.home), dt)


def test_only_inactive_set_tasks_give_zero_velocity(jaco):
    task = RowSetTask("s", 0.0, np.ones(jaco.nq), _th())
    qdot, report = TpikSolver(jaco).solve(one_level_each(task), jaco.kinematics(jaco.home), DT)
    np.testing.assert_array_equal(qdot, 0.0)
    assert report.status is SolveStatus.OK


def test_building_a_solver_loads_the_compiled_search_the_first_step_uses():
    """The compiled search is loaded when the solver is built, not at the first control step.

    Loading it from numba's cache takes ~0.5 s: on the hardware path that first step used to
    arrive half a second late, and the whole run lagged the person's motion. The solver passes
    its Jacobian rows read-only, a signature of its own (~40 ms to load): the first step then
    missed the solver time limit. Checked in a fresh process (in this one, earlier tests have
    loaded both already): the first solve loads nothing more.
    """
    code = (
        "import numpy as np, robots, tpik.cascade as c; from tpik.solver import TpikSolver; "
        "from tpik.hierarchy import Hierarchy, Level; from tpik.tasks import PositionTask; "
        "assert not c.search_modes.signatures; jaco = robots.load('jaco2'); solver = TpikSolver(jaco); "
        "built = len(c.search_modes.signatures); kin = jaco.kinematics(jaco.home); "
        "task = PositionTask('ee', target=kin.frame_position('end_effector') + np.array([0.05, 0.0, 0.0])); "
        "assert solver.solve(Hierarchy([Level('operational', [task])]), kin, 0.01).ok; "
        "print(built, len(c.search_modes.signatures))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.split() == ["2", "2"]


def test_frames_from_q_in_the_compiled_step_match_the_snapshot_path():
    """TPIK's frames computed from q in its step (pinocchio never run) give the snapshot path's velocities."""
    import robots
    from compare.bench.solver_cases import apply_state, case2_hierarchy, case2_states

    class _PerFrame(robots.Kinematics):  # a subclass: TPIK reads its frames through the snapshot
        __slots__ = ()

    robot = robots.load(robots.DEFAULT_ROBOT)
    for state in case2_states(robot):
        h = case2_hierarchy(robot)
        apply_state(h, state)
        solver = TpikSolver(robot)
        kin = robot.kinematics(state.q)
        own = solver.solve(h, kin, 0.01)
        assert kin._pending  # type: ignore[attr-defined]
        snap = robot.kinematics(state.q)
        via = solver.solve(h, _PerFrame(robot, snap.q, robot._pin_data, robot._generation, pending=True), 0.01)
        np.testing.assert_allclose(own.qdot, via.qdot, rtol=0.0, atol=1e-9)
        assert own.active_set == via.active_set and own.damping.keys() == via.damping.keys()
