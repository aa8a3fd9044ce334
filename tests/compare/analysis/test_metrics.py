"""Metrics on hand-built per-step tables whose answers are known."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pandas as pd
import pytest

from compare.analysis.metrics import (
    MetricsError,
    RunMeta,
    SetTaskInfo,
    compute_summary,
    margins,
    misses_cell,
    rising_edges,
    set_tasks_from_summary,
    to_jsonable,
)

DT = 0.01
CONTROL_POINTS = ("link_4", "link_6", "link_7")
REQUIRED_KEYS = {
    "solve_time_us",
    "realtime_factor",
    "joint_limits",
    "walls",
    "obstacles",
    "min_obstacle_distance_m",
    "ee_error_m",
    "failures",
    "fallbacks",
    "activation_toggles_per_s",
    # One accounting for every method (docs/design.md §7).
    "status_steps",
    "fallback_steps",
    "time_below_physical_s",
    "deadline_misses",
    "warmup_steps",
}
GROUP_KEYS = {"safety_margin_min", "physical_margin_min", "violations", "violation_time_s"}

JOINT_2 = SetTaskInfo("joint_limit_2", "joint_limits", -2.0, -1.9, 1.9, 2.0)
JOINT_4 = SetTaskInfo("joint_limit_4", "joint_limits", -2.5, -2.4, 2.4, 2.5)
WALL_X_MAX = SetTaskInfo("wall_x_max", "walls", -0.05, 0.0, math.inf, math.inf)
OBSTACLE_7 = SetTaskInfo("obstacle_link_7", "obstacles", 0.1, 0.35, math.inf, math.inf)
ALL_TASKS = (JOINT_2, JOINT_4, WALL_X_MAX, OBSTACLE_7)


def make_steps(n: int = 1000, tasks: tuple[SetTaskInfo, ...] = ALL_TASKS, seed: int = 0) -> pd.DataFrame:
    """A quiet run: every task well inside its safety set, no person, EE settled on a target."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    cols: dict[str, object] = {"t": t}
    for j in range(1, 8):
        cols[f"q_{j}"] = np.full(n, 0.1 * j)
        cols[f"qdot_{j}"] = np.zeros(n)
    ee = np.array([0.3, 0.4, 0.7])
    for k, axis in enumerate("xyz"):
        cols[f"ee_{axis}"] = np.full(n, ee[k])
        cols[f"target_{axis}"] = np.full(n, ee[k])
    cols["ee_error_m"] = np.zeros(n)
    cols["waypoint"] = np.zeros(n, dtype=np.int32)
    for task in tasks:
        if task.group == "joint_limits":
            sigma = np.full(n, 1.0)
        elif task.group == "walls":
            sigma = 0.5 - np.asarray(cols["ee_x"])
        else:
            sigma = np.full(n, np.inf)
        cols[f"sigma:{task.name}"] = sigma
        cols[f"active:{task.name}"] = np.zeros(n, dtype=bool)
        if task.group == "obstacles":
            cols[f"truth:{task.name}"] = np.full(n, np.inf)
    for cp in CONTROL_POINTS:
        cols[f"dist_meas:{cp}"] = np.full(n, np.inf)
        cols[f"dist_true:{cp}"] = np.full(n, np.inf)
    cols["solve_time_us"] = rng.uniform(10.0, 20.0, n)
    cols["status"] = np.array(["ok"] * n, dtype=object)
    cols["fallback"] = np.zeros(n, dtype=bool)
    cols["blind"] = np.zeros(n, dtype=bool)
    return pd.DataFrame(cols)


def make_meta(n: int = 1000, tasks: tuple[SetTaskInfo, ...] = ALL_TASKS, wall_time_s: float = 2.0) -> RunMeta:
    return RunMeta(
        scenario="synthetic",
        seed=7,
        method="tpik",
        dt=DT,
        sim_time_s=n * DT,
        wall_time_s=wall_time_s,
        sensing="geometric",
        set_tasks=tasks,
        control_points=CONTROL_POINTS,
    )


def assert_strict_json(obj: object) -> None:
    """JSON without NaN/inf and without numpy types (json.dumps refuses both)."""
    json.dumps(obj, allow_nan=False)


def test_quiet_run_has_exact_design_keys_and_strict_json():
    summary = compute_summary(make_steps(), make_meta())
    assert REQUIRED_KEYS <= set(summary)
    assert set(summary["solve_time_us"]) == {"median", "p95", "p99", "max"}
    for group in ("joint_limits", "walls", "obstacles"):
        assert GROUP_KEYS <= set(summary[group])
    assert set(summary["ee_error_m"]) == {"final", "mean"}
    assert len(summary["min_obstacle_distance_m"]) == 3
    assert_strict_json(summary)
    assert summary["realtime_factor"] == pytest.approx(10.0 / 2.0)
    assert summary["joint_limits"]["safety_margin_min"] == pytest.approx(0.9)
    assert summary["joint_limits"]["physical_margin_min"] == pytest.approx(1.0)
    assert summary["joint_limits"]["violations"] == 0
    assert summary["walls"]["safety_margin_min"] == pytest.approx(0.2)
    assert summary["walls"]["physical_margin_min"] == pytest.approx(0.25)


def test_step_accounting_counts_status_fallbacks_deadlines_and_time_below_physical():
    """A hand-built table: 30 degraded, 12 failed (all fallbacks), 7 deadline misses; the person below
    the 0.10 m physical threshold for 25 steps, a joint past its physical limit for 15, 10 of them
    the same steps: 30 steps below a physical threshold."""
    steps = make_steps()
    status = steps["status"].to_numpy().copy()
    status[100:130] = "degraded"
    status[500:512] = "failed"
    steps["status"] = status
    fallback = np.zeros(len(steps), dtype=bool)
    fallback[500:512] = True
    steps["fallback"] = fallback
    miss = np.zeros(len(steps), dtype=bool)
    miss[[3, 50, 51, 52, 600, 601, 999]] = True
    steps["deadline_miss"] = miss
    truth = steps["truth:obstacle_link_7"].to_numpy().copy()
    truth[200:225] = 0.099  # below the physical 0.1 m (and the 1 mm violation tolerance does not apply)
    steps["truth:obstacle_link_7"] = truth
    sigma = steps["sigma:joint_limit_2"].to_numpy().copy()
    sigma[215:230] = 2.0005  # past σ_M = 2.0 for 15 steps, 10 of them within the person's 25
    steps["sigma:joint_limit_2"] = sigma
    summary = compute_summary(steps, dataclasses.replace(make_meta(), warmup_steps=3))
    assert summary["status_steps"] == {"ok": 958, "degraded": 30, "failed": 12}
    assert summary["failures"] == 12 and summary["fallback_steps"] == summary["fallbacks"] == 12
    assert summary["deadline_misses"] == 7
    assert summary["time_below_physical_s"] == pytest.approx((25 + 15 - 10) * DT)
    assert summary["warmup_steps"] == 3


def test_joint_crossing_safety_threshold_twice_counts_two_episodes_and_their_time():
    steps = make_steps()
    sigma = steps["sigma:joint_limit_2"].to_numpy().copy()
    sigma[100:105] = 1.95  # 5 steps = 0.05 s past σ_s,u = 1.9, inside σ_M = 2.0
    sigma[300:305] = 1.95
    steps["sigma:joint_limit_2"] = sigma
    group = compute_summary(steps, make_meta())["joint_limits"]
    assert group["violations"] == 2
    assert group["violation_time_s"] == pytest.approx(0.1, abs=DT)
    assert group["safety_margin_min"] == pytest.approx(-0.05)
    assert group["physical_margin_min"] == pytest.approx(0.05)
    assert group["physical_violations"] == 0
    assert group["worst_task"] == "joint_limit_2"


def test_violation_time_counts_each_step_once_when_several_tasks_violate():
    steps = make_steps()
    for name, value in (("joint_limit_2", 1.95), ("joint_limit_4", -2.45)):
        sigma = steps[f"sigma:{name}"].to_numpy().copy()
        sigma[200:210] = value
        steps[f"sigma:{name}"] = sigma
    group = compute_summary(steps, make_meta())["joint_limits"]
    assert group["violations"] == 2  # one episode per task
    assert group["violation_time_s"] == pytest.approx(0.10, abs=1e-9)
    assert group["safety_margin_min"] == pytest.approx(-0.05)


def test_run_starting_in_violation_counts_as_an_episode():
    assert rising_edges(np.array([True, True, False, True])) == 2
    assert rising_edges(np.array([], dtype=bool)) == 0


def test_wall_crossing_is_a_signed_negative_margin_in_metres():
    steps = make_steps()
    x = steps["ee_x"].to_numpy().copy()
    x[500:510] = 0.52
    steps["ee_x"] = x
    steps["sigma:wall_x_max"] = 0.5 - x
    walls = compute_summary(steps, make_meta())["walls"]
    assert walls["safety_margin_min"] == pytest.approx(-0.02)
    assert walls["physical_margin_min"] == pytest.approx(0.03)
    assert walls["violations"] == 1
    assert walls["violation_time_s"] == pytest.approx(0.1, abs=1e-9)


def test_infinite_sigma_is_ignored_and_obstacle_metrics_use_ground_truth():
    steps = make_steps()
    summary = compute_summary(steps, make_meta())
    obstacles = summary["obstacles"]
    assert obstacles["safety_margin_min"] is None  # nobody was ever in range
    assert obstacles["violations"] == 0 and obstacles["violation_time_s"] == 0.0
    assert summary["min_obstacle_distance_m"] == [None, None, None]

    truth = np.full(len(steps), np.inf)
    truth[400:420] = 0.30  # ground truth inside the safety distance (0.35 m) for 0.2 s
    steps["truth:obstacle_link_7"] = truth
    sigma = np.full(len(steps), np.inf)
    sigma[400:420] = 0.40  # the sensor over-estimated: sigma alone would say "safe"
    steps["sigma:obstacle_link_7"] = sigma
    steps["dist_true:link_7"] = truth
    obstacles = compute_summary(steps, make_meta())["obstacles"]
    assert obstacles["safety_margin_min"] == pytest.approx(-0.05)
    assert obstacles["physical_margin_min"] == pytest.approx(0.20)
    assert obstacles["violations"] == 1
    assert obstacles["violation_time_s"] == pytest.approx(0.2, abs=1e-9)

    steps = steps.drop(columns=["truth:obstacle_link_7"])  # no ground truth: sigma is used
    summary = compute_summary(steps, make_meta())
    assert summary["obstacles"]["safety_margin_min"] == pytest.approx(0.05)
    assert summary["obstacles"]["violations"] == 0
    assert summary["min_obstacle_distance_m"] == [None, None, pytest.approx(0.30)]


def test_groups_absent_from_the_scenario_are_null():
    tasks = (JOINT_2, JOINT_4)
    summary = compute_summary(make_steps(tasks=tasks), make_meta(tasks=tasks))
    assert summary["walls"] is None
    assert summary["obstacles"] is None
    assert summary["joint_limits"] is not None
    assert_strict_json(summary)


def test_activation_toggles_failures_fallbacks_and_blind_steps():
    steps = make_steps()
    active = np.zeros(len(steps), dtype=bool)
    active[100:200] = True  # on, off: 2 toggles
    active[500:510] = True  # 2 more
    steps["active:joint_limit_2"] = active
    steps["active:wall_x_max"] = active  # the same 4 on another task
    status = steps["status"].to_numpy().copy()
    status[[3, 4, 5]] = "failed"
    status[6] = "degraded"
    steps["status"] = status
    fb = np.zeros(len(steps), dtype=bool)
    fb[[3, 4, 5, 50]] = True
    steps["fallback"] = fb
    blind = np.zeros(len(steps), dtype=bool)
    blind[700:730] = True
    steps["blind"] = blind
    summary = compute_summary(steps, make_meta())
    assert summary["activation_toggles"] == 8
    assert summary["activation_toggles_per_s"] == pytest.approx(8 / 10.0)
    assert summary["failures"] == 3
    assert summary["degraded_steps"] == 1
    assert summary["fallbacks"] == 4
    assert summary["blind_steps"] == 30
    by_active = summary["solve_time_us_by_active_count"]
    assert by_active["0"]["steps"] == 890 and by_active["2"]["steps"] == 110


def test_solve_time_percentiles_and_realtime_factor():
    steps = make_steps()
    steps["solve_time_us"] = np.arange(1, len(steps) + 1, dtype=float)  # 1..1000 µs
    summary = compute_summary(steps, make_meta(wall_time_s=20.0))
    st = summary["solve_time_us"]
    assert st["median"] == pytest.approx(500.5)
    assert st["p95"] == pytest.approx(np.percentile(np.arange(1, 1001), 95))
    assert st["p99"] == pytest.approx(np.percentile(np.arange(1, 1001), 99))
    assert st["max"] == 1000.0
    assert summary["realtime_factor"] == pytest.approx(0.5)


def test_waypoint_times_ee_error_and_peak_acceleration():
    steps = make_steps()
    t = steps["t"].to_numpy()
    waypoint = np.zeros(len(steps), dtype=np.int32)
    waypoint[400:] = 1
    error = np.where(t < 1.0, 0.5, 0.01)  # waypoint 0 reached at t = 1.0 s
    error[400:] = np.where(t[400:] < 5.5, 0.4, 0.005)  # waypoint 1: switch at 4.0 s, reached at 5.5 s
    error[-1] = 0.003
    steps["waypoint"] = waypoint
    steps["ee_error_m"] = error
    qdot = np.zeros(len(steps))
    qdot[600] = 0.2  # a 0.2 rad/s jump in one step: 20 rad/s² up and down
    steps["qdot_3"] = qdot
    summary = compute_summary(steps, make_meta())
    assert summary["waypoint_sequence"] == [0, 1]
    assert summary["time_to_waypoint_s"] == [pytest.approx(1.0), pytest.approx(1.5)]
    assert summary["waypoints_reached"] == 2
    assert summary["ee_error_m"]["final"] == pytest.approx(0.003)
    assert summary["ee_error_m"]["mean"] == pytest.approx(float(np.mean(error)))
    assert summary["peak_joint_acceleration_rad_s2"] == pytest.approx(20.0)


def test_unreached_waypoint_is_null():
    steps = make_steps()
    steps["ee_error_m"] = 0.1
    summary = compute_summary(steps, make_meta(), waypoint_tolerance_m=0.02)
    assert summary["time_to_waypoint_s"] == [None]
    assert summary["waypoints_reached"] == 0


def test_unfilled_rows_are_dropped_and_nan_solve_times_ignored():
    steps = make_steps()
    steps.loc[10:19, "t"] = np.nan
    steps.loc[10:19, "status"] = None
    steps.loc[30, "solve_time_us"] = np.nan
    summary = compute_summary(steps, make_meta())
    assert summary["steps"] == 990
    assert summary["failures"] == 0
    assert summary["solve_time_us"]["max"] is not None
    assert_strict_json(summary)


def test_missing_sigma_column_is_a_clear_error():
    steps = make_steps().drop(columns=["sigma:joint_limit_4"])
    with pytest.raises(MetricsError, match="sigma:joint_limit_4"):
        compute_summary(steps, make_meta())


def test_set_task_thresholds_round_trip_through_the_summary():
    summary = compute_summary(make_steps(), make_meta())
    stored = {d["name"]: d for d in summary["set_tasks"]}
    assert stored["wall_x_max"]["safety_upper"] is None  # +inf is encoded as null
    assert set_tasks_from_summary(summary) == ALL_TASKS


def test_margins_and_to_jsonable_helpers():
    m = margins(np.array([0.0, 1.0, np.inf, np.nan]), -1.0, 0.5)
    assert m[0] == pytest.approx(0.5) and m[1] == pytest.approx(-0.5)
    assert np.isnan(m[2]) and np.isnan(m[3])
    data = to_jsonable({"a": np.float64(np.nan), "b": np.int64(3), 4: (np.inf, np.bool_(True)), "c": np.ones(2)})
    assert data == {"a": None, "b": 3, "4": [None, True], "c": [1.0, 1.0]}
    assert_strict_json(data)


def test_empty_table_gives_nulls_not_errors():
    steps = make_steps().iloc[:0]
    summary = compute_summary(steps, make_meta())
    assert summary["steps"] == 0
    assert summary["solve_time_us"] == {"median": None, "p95": None, "p99": None, "max": None}
    assert summary["ee_error_m"] == {"final": None, "mean": None}
    assert summary["joint_limits"]["violations"] == 0
    assert summary["time_to_waypoint_s"] == []
    assert_strict_json(summary)


def test_hovering_at_the_threshold_within_tolerance_is_no_violation_but_margin_shows_it():
    steps = make_steps()
    sigma = steps["sigma:joint_limit_2"].to_numpy().copy()
    sigma[100:400:2] = 1.9 + 0.5e-3  # chattering 0.5 mrad past σ_s,u while held there
    steps["sigma:joint_limit_2"] = sigma
    group = compute_summary(steps, make_meta())["joint_limits"]
    assert group["violations"] == 0 and group["violation_time_s"] == 0.0
    assert group["safety_margin_min"] == pytest.approx(-0.5e-3)
    assert group["violation_tolerance"] == pytest.approx(1e-3)


def test_misses_cell_names_the_steal_excused_solves():
    assert misses_cell({"deadline_misses": 3, "deadline_steal_excused": {"steps": 1}}) == "3 (+1 steal)"
    assert misses_cell({"deadline_misses": 0, "deadline_steal_excused": {"steps": 0}}) == "0"
    assert misses_cell({}) == "–"
