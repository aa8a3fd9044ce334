"""The step's σ, status check and table: each set task's own value, the one status rule, the columns as recorded."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from compare.bench.solver_cases import apply_state, case2_hierarchy, case2_states
from compare.loop.recorder import StepRecorder
from compare.loop.set_task_watch import SetTaskWatch
from tests.conftest import random_configuration
from tpik.reference import ControlReference, unmet_set_rates
from tpik.tasks import ObstacleDistanceTask

DT = 0.01


def test_sigma_of_built_in_tasks_is_each_tasks_own_value(jaco):
    """Joint limits, six walls, obstacle distances with and without a point: the compute_value numbers."""
    hierarchy = case2_hierarchy(jaco)
    apply_state(hierarchy, case2_states(jaco)[2])  # obstacle points on two of the three control points
    watch = SetTaskWatch(hierarchy.set_tasks)
    rng = np.random.default_rng(4)
    for _ in range(30):
        kin = jaco.kinematics(random_configuration(jaco, rng))
        got = watch.measure(kin)
        want = [t.compute_value(kin) for t in hierarchy.set_tasks]
        assert any(math.isinf(w) for w in want)  # the control point without an obstacle point
        assert got == want and watch.sigmas == want


@pytest.mark.parametrize("gain_cap", [True, False])
def test_the_status_check_is_the_one_rule_of_tpik_reference(jaco, gain_cap):
    """Rows taken before the solve, the command checked after: unmet_set_rates' verdict on every state."""
    hierarchy = case2_hierarchy(jaco)
    reference = ControlReference(gain_cap=gain_cap)
    rng = np.random.default_rng(7)
    checked = 0
    for state in case2_states(jaco):
        apply_state(hierarchy, state)
        watch = SetTaskWatch(hierarchy.set_tasks, predicting=True)
        for _ in range(20):
            q = random_configuration(jaco, rng)
            kin = jaco.kinematics(q)
            sigmas = watch.measure(kin)
            qdot = rng.normal(scale=0.5, size=jaco.nq)
            kin_after = jaco.kinematics(q)  # the method's snapshot: the loop's own is stale by then
            want = unmet_set_rates(hierarchy.set_tasks, sigmas, kin_after, qdot, DT, reference)
            assert watch.unmet(qdot, DT, reference) == bool(want)
            checked += bool(want)
    assert checked > 0


def _recorder(jaco, steps: int, predicted: bool) -> tuple[StepRecorder, list[str], tuple[str, ...]]:
    hierarchy = case2_hierarchy(jaco)
    obstacles = [t for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)]
    cps = tuple(t.frame for t in obstacles)
    names = [t.name for t in hierarchy.set_tasks]
    return StepRecorder(steps, jaco.nq, hierarchy.set_tasks, obstacles, cps, predicted), names, cps


def test_the_table_holds_each_rows_values_and_the_defaults_of_a_row_not_recorded(jaco):
    """Row 1 is skipped (no joint reading): NaN, False and "" there; a reading lasts until replaced."""
    recorder, names, cps = _recorder(jaco, 4, predicted=True)
    k = len(cps)
    first = ((0.4,) * k, ((False, "cam"),) * k, ((0.5, 0.1),) * k)
    second = ((0.3,) * k, ((True, ""),) * k, ((math.inf, 0.0),) * k)
    q = np.arange(jaco.nq, dtype=float)
    for i, sensed in ((0, first), (2, first), (3, second)):
        recorder.motion(i, 0.01 * i, [1.0, 2.0, 3.0], [1.0, 2.0, 3.5], q + i, -q)
        recorder.set_tasks(i, [float(i)] * len(names), [names[0], "position"])
        recorder.distances(i, sensed, {cps[0]: 0.2} if i else {})
        recorder.outcome(i, 5.0, i == 3, i, "solver failed" if i == 2 else None, i == 3, None, "ok")
    steps = recorder.frame()
    assert len(steps) == 4 and steps["ee_error_m"].iloc[0] == pytest.approx(0.5)
    assert np.isnan(steps["t"].iloc[1]) and pd.isna(steps["status"].iloc[1])
    assert list(steps[f"sigma:{names[1]}"].iloc[[0, 2, 3]]) == [0.0, 2.0, 3.0]
    assert list(steps[f"active:{names[0]}"]) == [True, False, True, True]
    assert not steps[f"active:{names[1]}"].any()
    cp = cps[0]
    assert list(steps[f"dist_meas:{cp}"].iloc[[0, 2, 3]]) == [0.4, 0.4, 0.3] and np.isnan(steps[f"dist_meas:{cp}"][1])
    assert list(steps[f"camera:{cp}"]) == ["cam", "", "cam", ""]
    assert list(steps[f"occluded:{cp}"]) == [False, False, False, True]
    assert list(steps[f"dist_pred:{cp}"].iloc[[0, 3]]) == [0.5, math.inf]
    assert list(steps[f"dist_true:{cp}"].iloc[[0, 2]]) == [math.inf, 0.2]
    assert steps[f"dist_true:{cps[1]}"].iloc[2] == math.inf
    assert list(steps["reason"]) == ["", "", "fallback: solver failed", ""]
    assert list(steps["fallback"]) == [False, False, True, False]
    assert list(steps["deadline_miss"]) == [False, False, False, True]
    assert steps["waypoint"].dtype == np.int32 and steps["q_2"].iloc[3] == 4.0 and steps["qdot_2"].iloc[3] == -1.0


def test_the_tables_columns_are_in_the_documented_order(jaco):
    recorder, names, cps = _recorder(jaco, 1, predicted=False)
    columns = list(recorder.frame().columns)
    head = ["t", "ee_x", "ee_y", "ee_z", "target_x", "target_y", "target_z", "ee_error_m", "solve_time_us"]
    per_task = [c for name in names for c in (f"sigma:{name}", f"active:{name}")]
    per_cp = [f"{kind}:{cp}" for cp in cps for kind in ("dist_meas", "dist_true", "occluded", "camera")]
    assert columns[: len(head) + len(per_task)] == head + per_task
    rest = columns[len(head) + len(per_task) + len(cps) :]
    assert rest[: len(per_cp)] == per_cp
    assert rest[len(per_cp) : len(per_cp) + 6] == ["waypoint", "status", "reason", "fallback", "blind", "deadline_miss"]
    assert rest[-2:] == [f"q_{jaco.nq}", f"qdot_{jaco.nq}"]
