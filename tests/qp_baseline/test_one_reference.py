"""One control reference (docs/design.md §3): TPIK, HQP and mink receive the same r for the same hierarchy and state.

The references are :class:`tpik.reference.ControlReference`'s formulas; TPIK and the QP methods'
set rows compute them in compiled code from the shared task evaluation (:mod:`tpik.evaluation`).
The tests check the numbers in each method's rows against ControlReference evaluated in Python
from each task's own ``compute_state``: the equality reference σ̇_d + Kσ̃ of the EE task (gain
500 /s, 1 mm: 0.1 m/s with the gain cap, 0.5 m/s without) and the rates K(σ_s − σ) of every set
task. Then the EE velocity each one commands, which is what the reference is for.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.methods import make_method
from tests.qp_baseline.helpers import DT, joint_limit_level, obstacle_level, position_level, wall_box_level
from tpik.hierarchy import Hierarchy
from tpik.reference import ControlReference
from tpik.step_rows import assemble_rows
from tpik.tasks import ObstacleDistanceTask

SOLVERS = ("tpik", "hqp-daqp", "mink", "mink-hard", "mink-posture")


def _hierarchy(jaco, kin, gain: float, feedforward: float = 0.0, growth: float = 0.0) -> Hierarchy:
    """Case 2's levels; obstacles in the activation band of link 6 and 7 (σ = 0.37 m); EE task 1 mm off.

    With a prediction the obstacle is ``growth`` farther and closes in at ``feedforward``.
    """
    obstacles = obstacle_level(gain=2.0)
    for task in obstacles.tasks:
        assert isinstance(task, ObstacleDistanceTask)
        if task.frame != "link_4":
            point = kin.frame_position(task.frame) + (0.37 + growth) * np.array([0.0, 0.6, 0.8])
            task.set_obstacle(point, feedforward, growth)
    target = kin.frame_position("end_effector") + np.array([0.001, 0.0, 0.0])
    return Hierarchy(
        [joint_limit_level(jaco, gain=2.0), wall_box_level(gain=2.0), obstacles, position_level(target, gain=gain)]
    )


def _python_reference(hierarchy: Hierarchy, kin, gain_cap: bool):  # type: ignore[no-untyped-def]
    """ControlReference's numbers for every task, from each task's own compute_state (the Python path)."""
    ref = ControlReference(gain_cap=gain_cap)
    equality, rates = {}, {}
    for task in hierarchy.tasks:
        state = task.compute_state(kin)
        if task.is_set_based:
            rates[task.name] = ref.set_rates(task, float(state.value[0]), DT)  # type: ignore[arg-type]
        else:
            equality[task.name] = ref.equality(task, state, DT)
    return equality, rates


EE = "position_end_effector"


PREDICTIONS = [(0.0, 0.0), (0.3, 0.0), (0.0, 0.13), (0.3, 0.13)]
"""(feed-forward f [m/s], growth g [m]) of the obstacle tasks: none, each alone, both."""


@pytest.mark.parametrize(("feedforward", "growth"), PREDICTIONS)
@pytest.mark.parametrize(("gain_cap", "expected_mps"), [(True, 0.1), (False, 0.5)])
def test_tpik_rows_carry_the_reference(jaco, gain_cap, expected_mps, feedforward, growth):
    """TPIK's compiled rows (shared evaluation, eq. 2 and eq. 7) hold ControlReference's numbers."""
    solver = make_method("tpik", jaco, {"gain_cap": gain_cap})
    kin = jaco.kinematics(jaco.home)
    hierarchy = _hierarchy(jaco, kin, gain=500.0, feedforward=feedforward, growth=growth)
    solver.solve(hierarchy, kin, DT)
    ev = solver._plan.evaluation  # type: ignore[attr-defined]
    _, x, _, _, side, cand, _ = assemble_rows(
        ev.set_i, ev.set_in, ev.set_out, ev.eq_i, ev.eq_in, ev.eq_out, ev.eq_level, len(hierarchy.levels), DT, gain_cap
    )
    equality, rates = _python_reference(hierarchy, kin, gain_cap)
    # TPIK's frame origins come from compiled FK: pinocchio's to ~3e-16 m, × 500 /s.
    np.testing.assert_allclose(x[side == 0.0], equality[EE], rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(x[side == 0.0], [expected_mps, 0.0, 0.0], rtol=1e-9, atol=1e-10)
    names = [ev.set_tasks[c].name for c in cand]
    assert {"obstacle_link_6", "obstacle_link_7"} <= set(names)
    for name, xr, sd in zip(names, x[side != 0.0], side[side != 0.0], strict=True):
        lo, hi = rates[name]
        assert xr == pytest.approx(hi if sd > 0.0 else lo, rel=1e-12)
    lo, hi = rates["obstacle_link_6"]
    assert lo == pytest.approx(2.0 * (0.35 - 0.37) + feedforward, rel=1e-9) and hi == math.inf


@pytest.mark.parametrize(("feedforward", "growth"), PREDICTIONS)
@pytest.mark.parametrize("gain_cap", [True, False])
@pytest.mark.parametrize("name", SOLVERS[1:])
def test_qp_rows_carry_the_reference(jaco, name, gain_cap, feedforward, growth):
    """HQP's and mink's set rows (and HQP's EE reference) hold ControlReference's numbers."""
    solver = make_method(name, jaco, {"gain_cap": gain_cap})
    kin = jaco.kinematics(jaco.home)
    hierarchy = _hierarchy(jaco, kin, gain=500.0, feedforward=feedforward, growth=growth)
    solver.solve(hierarchy, kin, DT)
    kin = jaco.kinematics(jaco.home)
    equality, rates = _python_reference(hierarchy, kin, gain_cap)
    builder = solver._layout.rows if name.startswith("hqp-") else solver._rows  # type: ignore[attr-defined]
    rows = builder.build(kin, DT)
    hold = builder.hold_at_zero
    assert len(rows.h) >= 2 * 3 + 6  # both limits of 3 joints, 6 walls, obstacles in range
    for g, h, owner in zip(rows.G, rows.h, rows.owner, strict=True):
        task = builder.tasks[owner]
        lo, hi = rates[task.name]
        upper = np.allclose(g, task.compute_jacobian(kin)[0], rtol=0.0, atol=1e-15)
        want = (max(hi, 0.0) if hold else hi) if upper else (-min(lo, 0.0) if hold else -lo)
        assert h == pytest.approx(want, rel=1e-9, abs=1e-12), task.name
    if name.startswith("hqp-"):
        np.testing.assert_allclose(solver._layout.levels[-1].r, equality[EE], rtol=1e-12)  # type: ignore[attr-defined]
    lo, _ = rates["obstacle_link_6"]
    assert lo == pytest.approx(2.0 * (0.35 - 0.37) + feedforward, rel=1e-9)


@pytest.mark.parametrize("name", SOLVERS)
def test_every_method_cancels_a_predicted_approach(jaco, name):
    """An obstacle task at its safety threshold with a predicted approach f: every method retreats at f.

    Without the feed-forward the reference rate at σ = σ_s is 0 (the arm holds still while the
    person closes in); with it, J q̇ = f: the control point moves away as fast as the person comes.
    """
    kin = jaco.kinematics(jaco.home)
    f = 0.2
    obstacles = obstacle_level(gain=2.0)
    task = next(t for t in obstacles.tasks if isinstance(t, ObstacleDistanceTask) and t.frame == "link_7")
    task.set_obstacle(kin.frame_position("link_7") + 0.35 * np.array([0.0, 0.6, 0.8]), f, 0.0)
    hierarchy = Hierarchy([obstacles])
    result = make_method(name, jaco).solve(hierarchy, kin, DT)
    rate = float(task.compute_jacobian(kin)[0] @ result.qdot)
    assert rate == pytest.approx(f, abs=2e-3)


@pytest.mark.parametrize("name", SOLVERS)
def test_every_method_acts_on_a_predicted_approach_before_the_activation_threshold(jaco, name):
    """σ = 0.45 m, past σ_s + ε = 0.40 m, closing at f = 0.4 m/s: the reference K(σ_s − σ) + f = 0.2 m/s.

    HQP's and mink's rows hold it at every σ; TPIK's task is a candidate from
    σ_s + ε + f/K = 0.60 m on (:meth:`tpik.tasks.SetTask.activation_bounds`), so every method
    moves the control point away at least at 0.2 m/s instead of waiting for the static threshold.
    """
    kin = jaco.kinematics(jaco.home)
    f = 0.4
    obstacles = obstacle_level(gain=2.0)
    task = next(t for t in obstacles.tasks if isinstance(t, ObstacleDistanceTask) and t.frame == "link_7")
    task.set_obstacle(kin.frame_position("link_7") + 0.45 * np.array([0.0, 0.6, 0.8]), f, 0.0)
    assert task.activation_bounds()[0] == pytest.approx(0.35 + 0.05 + f / 2.0)
    result = make_method(name, jaco).solve(Hierarchy([obstacles]), kin, DT)
    rate = float(task.compute_jacobian(kin)[0] @ result.qdot)
    assert rate >= 2.0 * (0.35 - 0.45) + f - 2e-3


@pytest.mark.parametrize("name", SOLVERS)
def test_every_method_commands_the_capped_ee_velocity_with_gain_500(jaco, name):
    """1 mm error, gain 500: the commanded EE velocity is 0.100 m/s for every method."""
    kin = jaco.kinematics(jaco.home)
    target = kin.frame_position("end_effector") + np.array([0.001, 0.0, 0.0])
    hierarchy = Hierarchy([position_level(target, gain=500.0)])
    result = make_method(name, jaco).solve(hierarchy, kin, DT)
    ee_velocity = kin.position_jacobian("end_effector") @ result.qdot
    # HQP: its ε-regularisation (1e-9); mink: second order in the 1 mm error (SE(3) log), ~2e-6 m/s;
    # mink-posture: its damping 1e-3 and posture cost shorten the step by ~2 % (0.098 m/s).
    atol = {"tpik": 1e-12, "hqp-daqp": 1e-8, "mink-posture": 3e-3}.get(name, 1e-5)
    np.testing.assert_allclose(ee_velocity, [0.1, 0.0, 0.0], atol=atol)
