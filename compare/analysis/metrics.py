r"""Per-run metrics (docs/design.md §6) computed from the per-step table of the closed loop.

The per-step table is a :class:`pandas.DataFrame` with one row per control step:

========================== ======== ===========================================================
column                     unit     meaning
========================== ======== ===========================================================
``t``                      s        time since the start of the run
``q_1`` .. ``q_7``         rad      measured joint positions
``qdot_1`` .. ``qdot_7``   rad/s    commanded joint velocities (after fallback / safe stop)
``ee_x, ee_y, ee_z``       m        end-effector position (base frame)
``target_x, _y, _z``       m        current EE target
``ee_error_m``             m        ‖target − ee‖
``waypoint``               –        index of the current target
``sigma:N``                task     value σ of set task ``N`` used by the controller
                                    (+inf for an obstacle task with nothing in range)
``active:N``               bool     task ``N`` in the solver's active set this step
``truth:N``                m        obstacle tasks only: ground-truth distance from the geometry
                                    (+inf when no person); used instead of ``sigma:N`` for the
                                    safety metrics of the ``obstacles`` group when present
``dist_meas:F``            m        measured obstacle distance of control point ``F`` (+inf: none)
``dist_true:F``            m        ground-truth obstacle distance of control point ``F``
``occluded:F``             bool     the reading of ``F`` was assumed from space hidden from
                                    every camera, not measured (``compare.sensing.fusion``)
``camera:F``               str      camera whose pixel gave ``F``'s reading ("" : none/geometric)
``solve_time_us``          µs       wall time of the solver call
``status``                 str      ``ok`` | ``degraded`` | ``failed``
``fallback``               bool     the loop replaced the solver output by the safe fallback
``blind``                  bool     sensing reported a blind or stale frame
``deadline_miss``          bool     the solve missed its deadline: no answer within the solver
                                    time limit (``compare.loop.deadline``; the step is FAILED and
                                    the fallback acts), or without a limit a solve longer than
                                    the control period
``reason``                 str      why the command was replaced: ``sensing: <why>`` (safe stop)
                                    and/or ``fallback: <why>``; empty otherwise
``fault:K``                bool     injected fault of kind ``K`` altered this step's data
                                    (``compare.loop.faults``; only with ``[faults]``)
``iso_margin_m:F``         m        ISO/TS 15066 margin d − S_p of control point ``F``
                                    (``compare.analysis.iso15066``; NaN: nothing within range)
``iso_sp_m:F``             m        protective separation distance S_p
``iso_vh_mps:F``           m/s      estimated human speed toward ``F``
``iso_vr_mps:F``           m/s      speed of ``F`` toward the person
========================== ======== ===========================================================

Each metric is a :class:`~compare.analysis.metric.Metric` registered here, in the order of
``summary.json``: what it computes from the table, its columns of ``sweep_runs.csv``, its
aggregates in ``sweep_summary.json`` and its columns in the run table and the sweep report.
``compare.run.run_method`` writes ``faults`` (per fault kind: injected steps, reaction,
latencies; :meth:`compare.loop.faults.FaultInjector.summarize`), ``unsafe_commands``, ``iso15066``
(:func:`compare.analysis.iso15066.summarize`), ``solve_worst_us`` and ``deadline_steal_excused``
itself; they are registered without ``compute``, for their sweep columns and aggregates.

Margins are signed, in the task's unit, positive inside the allowed set:

.. math:: m_k = \min(\sigma_k - \sigma_{k,l},\ \sigma_{k,u} - \sigma_k)

with the safety thresholds :math:`\sigma_{s,l}, \sigma_{s,u}` for the safety margin and the
physical ones :math:`\sigma_m, \sigma_M` for the physical margin. Non-finite σ (no obstacle in
range, or a row the loop could not fill) contributes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np
import pandas as pd

from compare.analysis.metric import (
    Column,
    Entry,
    Metric,
    MetricsError,
    RunMeta,
    RunSteps,
    SetTaskInfo,
    SweepRuns,
    fmt_number,
    fmt_percent,
    no_columns,
    rate_with_ci,
    to_jsonable,
)
from compare.analysis.statistics import bootstrap_median_ci
from tpik.hierarchy import Hierarchy

GROUPS: tuple[str, ...] = ("joint_limits", "walls", "obstacles")
"""The docs/design.md §7 set-task groups, always in ``summary.json`` (``None`` when the run has none).

Every group, these and any other a set task names (:attr:`tpik.tasks.SetTask.group`, e.g. a
new safety task's), is also under ``"groups"``: ``summary["groups"][<group>]`` (:func:`task_groups`).
"""

GROUP_HEADERS = {"joint_limits": "joint margin [rad]", "walls": "wall margin [m]", "obstacles": "obstacle margin [m]"}
"""Run-table headers of the docs/design.md §7 groups (another group: ``<group> margin``)."""

STATUSES = ("ok", "degraded", "failed")
"""Step statuses, the same for every method (docs/design.md §3)."""


def set_task_infos(hierarchy: Hierarchy) -> tuple[SetTaskInfo, ...]:
    """Group (:attr:`tpik.tasks.SetTask.group`) and thresholds of every set-based task, for the metrics."""
    infos = []
    for task in hierarchy.set_tasks:
        th = task.thresholds
        infos.append(
            SetTaskInfo(task.name, task.group, th.physical_lower, th.safety_lower, th.safety_upper, th.physical_upper)
        )
    return tuple(infos)


def margins(sigma: np.ndarray, lower: float, upper: float) -> np.ndarray:
    """Signed margin min(σ − lower, upper − σ) per step; NaN where σ is not finite.

    Args:
        sigma: Task values. Shape (T,).
        lower: Lower threshold (−inf for none).
        upper: Upper threshold (+inf for none).

    Returns:
        Margins, positive inside. Shape (T,).
    """
    sigma = np.asarray(sigma, dtype=float)
    with np.errstate(invalid="ignore"):
        out = np.minimum(sigma - lower, upper - sigma)
    out[~np.isfinite(sigma)] = np.nan
    return out


def rising_edges(flag: np.ndarray) -> int:
    """Number of False → True transitions; a flag already True at the first step counts as one."""
    flag = np.asarray(flag, dtype=bool)
    if flag.size == 0:
        return 0
    return int(flag[0]) + int(np.count_nonzero(flag[1:] & ~flag[:-1]))


def task_groups(set_tasks: Iterable[SetTaskInfo]) -> tuple[str, ...]:
    """Groups summarised for these tasks: :data:`GROUPS`, then every other group in task order."""
    extra = [task.group for task in set_tasks if task.group not in GROUPS]
    return GROUPS + tuple(dict.fromkeys(extra))


def summary_groups(method_summary: Entry) -> tuple[str, ...]:
    """The set-task groups of a method summary (the keys of its ``groups``; :data:`GROUPS` if absent)."""
    return tuple(method_summary.get("groups") or GROUPS)


def group_summary(method_summary: Entry, group: str) -> dict[str, Any] | None:
    """The metrics of one group in a method summary (``None`` when the run has no task of it)."""
    groups = method_summary.get("groups")
    value = groups.get(group) if isinstance(groups, dict) else method_summary.get(group)
    return value if isinstance(value, dict) else None


def _nanmin(x: np.ndarray) -> float | None:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(x.min()) if x.size else None


def _min_finite(values: Iterable[Any]) -> float | None:
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return min(finite) if finite else None


def _max_finite(values: Iterable[Any]) -> float | None:
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return max(finite) if finite else None


def task_sigma_for_safety(run: RunSteps, task: SetTaskInfo) -> np.ndarray:
    """σ used for the safety metrics: ``truth:N`` when recorded (obstacle tasks), else ``sigma:N``."""
    if run.has(f"truth:{task.name}"):
        return run.column(f"truth:{task.name}")
    return run.column(f"sigma:{task.name}")


VIOLATION_TOLERANCE = 1e-3
"""Margin below which a step counts as a violation, in the task's unit (1 mm, 1 mrad).

A set task held at its safety threshold by the controller hovers there within the
discretisation and servo error (~1e-4); counting those as violation *episodes* would report
chattering, not danger. ``safety_margin_min`` stays exact: it shows any undershoot.
"""


def _task_metrics(sigma: np.ndarray, task: SetTaskInfo, dt: float) -> dict[str, Any]:
    safety = margins(sigma, task.safety_lower, task.safety_upper)
    physical = margins(sigma, task.physical_lower, task.physical_upper)
    with np.errstate(invalid="ignore"):
        safety_neg = np.nan_to_num(safety, nan=0.0) < -VIOLATION_TOLERANCE
        physical_neg = np.nan_to_num(physical, nan=0.0) < -VIOLATION_TOLERANCE
    return {
        "safety_margin_min": _nanmin(safety),
        "physical_margin_min": _nanmin(physical),
        "violations": rising_edges(safety_neg),
        "violation_time_s": float(np.count_nonzero(safety_neg) * dt),
        "physical_violations": rising_edges(physical_neg),
        "physical_violation_time_s": float(np.count_nonzero(physical_neg) * dt),
        "_safety_neg": safety_neg,
        "_physical_neg": physical_neg,
    }


def _group_metrics(per_task: dict[str, dict[str, Any]], tasks: list[SetTaskInfo], dt: float) -> dict[str, Any] | None:
    """Combine the task metrics of one group; ``None`` when the group has no task."""
    if not tasks:
        return None
    rows = [per_task[t.name] for t in tasks]
    safety_mins = [(r["safety_margin_min"], t.name) for r, t in zip(rows, tasks, strict=True)]
    finite = [(m, n) for m, n in safety_mins if m is not None]
    any_safety = np.logical_or.reduce([r["_safety_neg"] for r in rows])
    any_physical = np.logical_or.reduce([r["_physical_neg"] for r in rows])
    physical_mins = [r["physical_margin_min"] for r in rows if r["physical_margin_min"] is not None]
    worst = min(finite) if finite else None
    return {
        "safety_margin_min": worst[0] if worst else None,
        "physical_margin_min": min(physical_mins) if physical_mins else None,
        "violations": int(sum(r["violations"] for r in rows)),
        "violation_time_s": float(np.count_nonzero(any_safety) * dt),
        # Extras (not part of the docs/design.md §7 contract).
        "physical_violations": int(sum(r["physical_violations"] for r in rows)),
        "physical_violation_time_s": float(np.count_nonzero(any_physical) * dt),
        "worst_task": worst[1] if worst else None,
        "tasks": len(tasks),
        "violation_tolerance": VIOLATION_TOLERANCE,
    }


def _percentiles_us(x: np.ndarray) -> dict[str, float | None]:
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"median": None, "p95": None, "p99": None, "max": None}
    return {
        "median": float(np.median(x)),
        "p95": float(np.percentile(x, 95)),
        "p99": float(np.percentile(x, 99)),
        "max": float(x.max()),
    }


def waypoint_times(
    t: np.ndarray, waypoint: np.ndarray, ee_error_m: np.ndarray, tolerance_m: float
) -> tuple[list[int], list[float | None]]:
    """Time from each waypoint switch (and from the start) to the first step with error < tolerance.

    Args:
        t: Time [s]. Shape (T,).
        waypoint: Index of the current target. Shape (T,).
        ee_error_m: EE position error [m]. Shape (T,).
        tolerance_m: Error below which the waypoint counts as reached [m].

    Returns:
        The waypoint index of each segment and its time to reach [s] (``None`` if never reached
        before the next switch or the end of the run).
    """
    if t.size == 0:
        return [], []
    starts = np.concatenate([[0], np.flatnonzero(waypoint[1:] != waypoint[:-1]) + 1])
    ends = np.concatenate([starts[1:], [t.size]])
    indices: list[int] = []
    times: list[float | None] = []
    with np.errstate(invalid="ignore"):
        reached = ee_error_m < tolerance_m
    for s, e in zip(starts, ends, strict=True):
        hit = np.flatnonzero(reached[s:e])
        indices.append(int(waypoint[s]))
        times.append(float(t[s + hit[0]] - t[s]) if hit.size else None)
    return indices, times


def peak_joint_acceleration(steps: pd.DataFrame) -> float | None:
    """Largest |Δq̇/Δt| over all joints and steps [rad/s²] (finite differences of ``qdot_*``)."""
    cols = sorted((c for c in steps.columns if c.startswith("qdot_")), key=lambda c: int(c.split("_")[1]))
    if not cols or len(steps) < 2:
        return None
    qdot = steps[cols].to_numpy(dtype=float, na_value=np.nan)
    t = steps["t"].to_numpy(dtype=float)
    dt = np.diff(t)
    with np.errstate(invalid="ignore", divide="ignore"):
        acc = np.abs(np.diff(qdot, axis=0)) / dt[:, None]
    acc[dt <= 0] = np.nan  # repeated time stamps (skipped steps) carry no rate
    acc = acc[np.isfinite(acc)]
    return float(acc.max()) if acc.size else None


# ------------------------------------------------------------------ what several metrics share


def _set_task_results(run: RunSteps) -> tuple[dict[str, dict[str, Any]], dict[str, dict[str, Any] | None]]:
    """Per task (with its violation masks) and per group (:func:`task_groups`): the margin metrics."""
    tasks = run.meta.set_tasks
    per_task = {task.name: _task_metrics(task_sigma_for_safety(run, task), task, run.dt) for task in tasks}
    groups = {
        group: _group_metrics(per_task, [t for t in tasks if t.group == group], run.dt) for group in task_groups(tasks)
    }
    return per_task, groups


def _groups(run: RunSteps) -> dict[str, dict[str, Any] | None]:
    return run.shared(_set_task_results)[1]


def _status(run: RunSteps) -> pd.Series:
    return run.steps["status"].astype("string").fillna("")


def _active(run: RunSteps) -> np.ndarray:
    """Set tasks in the active set per step (the ``active:N`` columns recorded). Shape (T, k)."""
    cols = [f"active:{task.name}" for task in run.meta.set_tasks if run.has(f"active:{task.name}")]
    active = np.zeros((len(run), len(cols)), dtype=bool)
    for k, col in enumerate(cols):
        active[:, k] = run.flag(col)
    return active


def _toggles(run: RunSteps) -> int:
    active = run.shared(_active)
    return int(np.count_nonzero(active[1:] != active[:-1])) if len(run) > 1 else 0


def _waypoints(run: RunSteps) -> tuple[list[int], list[float | None]]:
    waypoint = run.steps["waypoint"].to_numpy(dtype=int) if run.has("waypoint") else np.zeros(len(run), int)
    t = run.steps["t"].to_numpy(dtype=float)
    return waypoint_times(t, waypoint, run.column("ee_error_m"), run.waypoint_tolerance_m)


def _finite_ee_error(run: RunSteps) -> np.ndarray:
    e = run.column("ee_error_m")
    return e[np.isfinite(e)]


def _ee_error(run: RunSteps) -> dict[str, float | None]:
    """The EE error [m] at the last step where it is finite, and its mean."""
    e = run.shared(_finite_ee_error)
    return {"final": float(e[-1]) if e.size else None, "mean": float(e.mean()) if e.size else None}


def _solve_time_us(run: RunSteps) -> dict[str, float | None]:
    return _percentiles_us(run.column("solve_time_us"))


def _by_active_count(run: RunSteps) -> dict[str, Any]:
    """Solve-time median and p99 [µs] per number of active set tasks."""
    solve_us = run.column("solve_time_us")
    n_active = run.shared(_active).sum(axis=1).astype(int)
    out: dict[str, Any] = {}
    for k in np.unique(n_active):
        sel = solve_us[(n_active == k) & np.isfinite(solve_us)]
        if sel.size:
            out[str(int(k))] = {
                "steps": int(sel.size),
                "median": float(np.median(sel)),
                "p99": float(np.percentile(sel, 99)),
            }
    return out


def _time_below_physical_s(run: RunSteps) -> float:
    """Time with any set task past its physical threshold (exact: no tolerance) [s]."""
    below = np.zeros(len(run), dtype=bool)
    for task in run.meta.set_tasks:
        physical = margins(task_sigma_for_safety(run, task), task.physical_lower, task.physical_upper)
        with np.errstate(invalid="ignore"):
            below |= np.nan_to_num(physical, nan=0.0) < 0.0
    return float(np.count_nonzero(below) * run.dt)


def _per_rate(run: RunSteps, value: float) -> float | None:
    sim_time_s = float(run.meta.sim_time_s)
    return value / sim_time_s if sim_time_s > 0 else None


# ------------------------------------------------------------------------------- columns


def _margin_cell(entry: Entry, group: str) -> str:
    g = group_summary(entry, group)
    if g is None:
        return "n/a"
    cell = fmt_number(g.get("safety_margin_min"), "+.3f")
    if g.get("violations"):
        cell += f" ({g['violations']}× {g.get('violation_time_s', 0.0):.2f} s)"
    return cell


def _margin_style(entry: Entry, group: str) -> str | None:
    g = group_summary(entry, group)
    negative = g is not None and g.get("safety_margin_min") is not None and g["safety_margin_min"] < 0
    return "bold red" if negative else None


def _margin_column(group: str) -> Column:
    return Column(
        GROUP_HEADERS.get(group, f"{group} margin"),
        lambda e: _margin_cell(e, group),
        lambda e: _margin_style(e, group),
    )


def _other_groups(entries: Sequence[Entry]) -> list[str]:
    """The set-task groups beyond :data:`GROUPS` of some method summary (a new safety task's)."""
    found = [g for m in entries for g in summary_groups(m)]
    return [g for g in dict.fromkeys(found) if g not in GROUPS]


def misses_cell(m: Entry) -> str:
    """Deadline misses, with the solves kept once the hypervisor's steal was taken out ("+ k steal")."""
    excused = m.get("deadline_steal_excused")
    if isinstance(excused, dict):
        excused = excused.get("steps")
    text = str(m.get("deadline_misses", "–"))
    if isinstance(excused, int) and excused > 0:
        text += f" (+{excused} steal)"
    return text


def _status_counts(entry: Entry) -> str:
    st = entry.get("status_steps") or {}
    return " / ".join(str(st.get(k, "–")) for k in STATUSES)


def _failed_share(entry: Entry) -> str:
    steps = entry.get("steps") or 0
    failed = (entry.get("status_steps") or {}).get("failed", 0)
    return _status_counts(entry) + (f" ({100.0 * failed / steps:.2f} %)" if steps else "")


def _solve_median_ci(entry: Entry) -> str:
    solve = entry.get("solve_time_us") or {}
    ci = solve.get("median_of_medians_ci95")
    return fmt_number(solve.get("median_of_medians"), ".0f") + (f" [{ci[0]:.0f}, {ci[1]:.0f}]" if ci else "")


def _sub(entry: Entry, key: str, sub: str) -> Any:
    return (entry.get(key) or {}).get(sub)


# ---------------------------------------------------------------------------- aggregates


def _violated(runs: SweepRuns, group: str) -> pd.Series:
    return runs.positive(f"{group}_violations")


def _sweep_groups(runs: SweepRuns) -> list[str]:
    """:data:`GROUPS`, then any other set-task group with columns in the sweep's rows."""
    found = [c.removesuffix("_present") for c in runs.rows.columns if c.endswith("_present")]
    return list(dict.fromkeys([*GROUPS, *found]))


def _flatten_groups(entry: Entry) -> dict[str, Any]:
    row: dict[str, Any] = {}
    for group in summary_groups(entry):
        g = group_summary(entry, group)
        row[f"{group}_present"] = g is not None
        g = g or {}
        row[f"{group}_safety_margin_min"] = g.get("safety_margin_min")
        row[f"{group}_physical_margin_min"] = g.get("physical_margin_min")
        row[f"{group}_violations"] = int(g.get("violations") or 0)
        row[f"{group}_violation_time_s"] = float(g.get("violation_time_s") or 0.0)
    return row


def _aggregate_groups(runs: SweepRuns) -> dict[str, Any]:
    """Shares of runs with a violation per kind, and the worst margins of every group."""
    groups = _sweep_groups(runs)
    limits_or_walls = _violated(runs, "joint_limits") | _violated(runs, "walls")
    obstacles = _violated(runs, "obstacles")
    other = pd.Series(False, index=runs.rows.index)
    for group in groups[len(GROUPS) :]:  # a new safety task's group
        other |= _violated(runs, group)
    return {
        "share_runs_limit_or_wall_violation": runs.share(limits_or_walls),
        "share_runs_obstacle_violation": runs.share(obstacles),
        "share_runs_any_violation": runs.share(limits_or_walls | obstacles | other),
        "worst_safety_margin": {g: runs.stat(f"{g}_safety_margin_min", "min") for g in groups},
        "worst_physical_margin": {g: runs.stat(f"{g}_physical_margin_min", "min") for g in groups},
        "share_runs_joint_limit_violation": runs.share(_violated(runs, "joint_limits")),
        "share_runs_wall_violation": runs.share(_violated(runs, "walls")),
    }


def _sweep_group_columns(entries: Sequence[Entry]) -> list[Column]:
    others = list(dict.fromkeys(g for m in entries for g in (m.get("worst_safety_margin") or {}) if g not in GROUPS))

    def worst(group: str) -> Column:
        header = {"joint_limits": "worst joint margin [rad]", "walls": "worst wall margin [m]"}.get(
            group, f"worst {group} margin"
        )
        return Column(header, lambda e: fmt_number(_sub(e, "worst_safety_margin", group), "+.4f"), section="safety")

    return [
        Column(
            "joint-limit or wall violation",
            lambda e: rate_with_ci(e.get("share_runs_limit_or_wall_violation")),
            section="safety",
        ),
        Column("obstacle violation", lambda e: rate_with_ci(e.get("share_runs_obstacle_violation")), section="safety"),
        worst("joint_limits"),
        worst("walls"),
        *[worst(g) for g in others],
    ]


def _flatten_solve_time(entry: Entry) -> dict[str, Any]:
    return {f"solve_{k}_us": _sub(entry, "solve_time_us", k) for k in ("median", "p95", "p99", "max")}


def _aggregate_solve_time(runs: SweepRuns) -> dict[str, Any]:
    return {
        "solve_time_us": {
            "median_of_medians": runs.stat("solve_median_us", "median"),
            "median_of_medians_ci95": bootstrap_median_ci(runs.finite("solve_median_us")),
            "p99_of_medians": runs.stat("solve_median_us", "p99"),
            "median_of_p99": runs.stat("solve_p99_us", "median"),
            "max": runs.stat("solve_max_us", "max"),
            # The worst steady-state step on the time limit's clock (CPU by default; every timed
            # step is after the warm-up): what the deadline misses are counted on.
            "max_on_limit_clock": runs.stat("solve_worst_us", "max"),
        },
        "solve_time_percentiles_us": {
            "p50_of_run_p99": runs.stat("solve_p99_us", "median"),
            "p95_of_run_p99": runs.stat("solve_p99_us", "p95"),
            "max_of_run_p99": runs.stat("solve_p99_us", "max"),
            "p95_of_run_medians": runs.stat("solve_median_us", "p95"),
        },
    }


def _flatten_min_distance(entry: Entry) -> dict[str, Any]:
    dist = entry.get("min_obstacle_distance_m") or []
    cps = entry.get("control_points") or [f"cp{i}" for i in range(len(dist))]
    row: dict[str, Any] = {"min_obstacle_distance_m": _min_finite(dist)}
    for cp, d in zip(cps, dist, strict=False):
        row[f"min_obstacle_distance_m:{cp}"] = d
    return row


def _flatten_iso(entry: Entry) -> dict[str, Any]:
    iso = entry.get("iso15066") or {}
    return {
        "iso_min_margin_m": iso.get("min_margin_m"),
        "iso_time_below_zero_s": iso.get("time_below_zero_s"),
        "iso_human_speed_max_mps": iso.get("human_speed_max_mps"),
    }


def _flatten_faults(entry: Entry) -> dict[str, Any]:
    faults = entry.get("faults") or {}
    kinds = [f for f in faults.values() if isinstance(f, dict)]
    return {
        "fault_injected_steps": int(sum((f.get("injected_steps") or 0) for f in faults.values())),
        "fault_unreacted": int(sum(f.get("reaction") == "none" for f in faults.values())),
        "fault_reaction_latency_s_max": _max_finite(f.get("reaction_latency_s_max") for f in kinds),
    }


def _aggregate_status(runs: SweepRuns) -> dict[str, Any]:
    steps = runs.total("steps")
    status_steps = {k: runs.total(f"status_steps_{k}") for k in STATUSES}
    return {
        "status_steps": status_steps,
        "share_steps_failed": status_steps["failed"] / steps if steps else None,
        "share_steps_degraded": status_steps["degraded"] / steps if steps else None,
    }


def _total(name: str) -> Callable[[SweepRuns], dict[str, Any]]:
    """Aggregate: the integer sum of the column ``name`` over the runs, under ``name``."""
    return lambda runs: {name: runs.total(name)}


# ------------------------------------------------------------------------- the built-ins

_EXTRA = no_columns
"""``flatten`` of an entry kept in ``summary.json`` only."""

BUILTIN_METRICS: tuple[Metric, ...] = (
    Metric(
        "solve_time_us",
        "µs",
        _solve_time_us,
        flatten=_flatten_solve_time,
        aggregate=_aggregate_solve_time,
        run_columns=(
            Column("solve median [µs]", lambda e: fmt_number(_sub(e, "solve_time_us", "median"), ".1f")),
            Column("solve p99 [µs]", lambda e: fmt_number(_sub(e, "solve_time_us", "p99"), ".1f")),
        ),
        sweep_columns=(
            Column("solve median [µs] (bootstrap 95 %)", _solve_median_ci, section="cost"),
            Column(
                "median of run p99 [µs]",
                lambda e: fmt_number(_sub(e, "solve_time_us", "median_of_p99"), ".0f"),
                section="cost",
            ),
            Column(
                "p95 of run p99 [µs]",
                lambda e: fmt_number(_sub(e, "solve_time_percentiles_us", "p95_of_run_p99"), ".0f"),
                section="cost",
            ),
            Column(
                "worst step after warm-up [µs] (wall / limit clock)",
                lambda e: (
                    fmt_number(_sub(e, "solve_time_us", "max"), ".0f")
                    + " / "
                    + fmt_number(_sub(e, "solve_time_us", "max_on_limit_clock"), ".0f")
                ),
                section="cost",
            ),
        ),
    ),
    Metric(
        "realtime_factor",
        "",
        lambda run: run.meta.sim_time_s / run.meta.wall_time_s if run.meta.wall_time_s > 0 else None,
        aggregate=("median", "min"),
        run_columns=(Column("realtime ×", lambda e: fmt_number(e.get("realtime_factor"), ".2f")),),
        sweep_columns=(
            Column(
                "realtime × (median)", lambda e: fmt_number(_sub(e, "realtime_factor", "median"), ".1f"), section="cost"
            ),
        ),
    ),
    *(
        Metric(group, "", lambda run, g=group: _groups(run)[g], flatten=_EXTRA, run_columns=(_margin_column(group),))
        for group in GROUPS
    ),
    Metric(
        "groups",
        "",
        _groups,
        flatten=_flatten_groups,
        aggregate=_aggregate_groups,
        run_columns=lambda entries: [_margin_column(g) for g in _other_groups(entries)],
        sweep_columns=_sweep_group_columns,
    ),
    Metric(
        "min_obstacle_distance_m",
        "m",
        lambda run: [_nanmin(run.column(f"dist_true:{cp}")) for cp in run.meta.control_points],
        flatten=_flatten_min_distance,
        aggregate=lambda runs: {"min_obstacle_distance_m": runs.stat("min_obstacle_distance_m", "min")},
        run_columns=(
            Column(
                "min obstacle dist. [m]",
                lambda e: fmt_number(_min_finite(e.get("min_obstacle_distance_m") or []), ".3f"),
            ),
        ),
    ),
    Metric(
        "ee_error_m",
        "m",
        _ee_error,
        flatten=lambda entry: {
            "ee_error_final_m": _sub(entry, "ee_error_m", "final"),
            "ee_error_mean_m": _sub(entry, "ee_error_m", "mean"),
        },
        aggregate=lambda runs: {
            "ee_error_final_m": {
                "median": runs.stat("ee_error_final_m", "median"),
                "max": runs.stat("ee_error_final_m", "max"),
            }
        },
        run_columns=(Column("EE final error [m]", lambda e: fmt_number(_sub(e, "ee_error_m", "final"), ".4f")),),
    ),
    Metric(
        "failures",
        "",
        lambda run: int((run.shared(_status) == "failed").sum()),
        aggregate=lambda runs: {
            "failures": runs.total("failures"),
            "share_runs_with_failures": runs.share(runs.positive("failures")),
        },
    ),
    Metric(
        "fallbacks",
        "",
        lambda run: int(np.count_nonzero(run.flag("fallback"))),
        aggregate=lambda runs: {
            "fallbacks": runs.total("fallbacks"),
            "share_runs_with_fallbacks": runs.share(runs.positive("fallbacks")),
        },
        sweep_columns=(
            Column(
                "runs with failures / fallbacks",
                lambda e: " / ".join(fmt_percent(e.get(f"share_runs_with_{k}")) for k in ("failures", "fallbacks")),
                section="safety",
            ),
            Column(
                "failures / fallbacks (steps)",
                lambda e: f"{e.get('failures', 0)} / {e.get('fallbacks', 0)}",
                section="safety",
            ),
        ),
    ),
    Metric(
        "activation_toggles_per_s",
        "1/s",
        lambda run: _per_rate(run, run.shared(_toggles)),
        aggregate=lambda runs: {"activation_toggles_per_s_median": runs.stat("activation_toggles_per_s", "median")},
    ),
    # One accounting for every method (docs/design.md §3, §7).
    Metric(
        "status_steps",
        "",
        lambda run: {key: int((run.shared(_status) == key).sum()) for key in STATUSES},
        flatten=lambda entry: {f"status_steps_{k}": _sub(entry, "status_steps", k) for k in STATUSES},
        aggregate=_aggregate_status,
        run_columns=(
            Column(
                "degraded / failed / fallback steps",
                lambda e: (
                    f"{(e.get('status_steps') or {}).get('degraded', '–')} / "
                    f"{e.get('failures', 0)} / {e.get('fallbacks', 0)}"
                ),
                lambda e: "yellow" if e.get("failures") or e.get("fallbacks") else None,
            ),
        ),
        sweep_columns=(
            Column("steps", lambda e: str(e.get("steps") or 0), section="accounting"),
            Column("ok / degraded / failed (failed share)", _failed_share, section="accounting"),
        ),
    ),
    Metric(
        "fallback_steps",
        "",
        lambda run: int(np.count_nonzero(run.flag("fallback"))),
        aggregate=_total("fallback_steps"),
        sweep_columns=(Column("fallback steps", lambda e: str(e.get("fallback_steps", "–")), section="accounting"),),
    ),
    Metric(
        "time_below_physical_s",
        "s",
        _time_below_physical_s,
        aggregate=lambda runs: {
            "time_below_physical_s": float(runs.stat("time_below_physical_s", "sum") or 0.0),
            "share_runs_below_physical": runs.share(runs.positive("time_below_physical_s")),
        },
        sweep_columns=(
            Column(
                "time below a physical threshold [s]",
                lambda e: fmt_number(e.get("time_below_physical_s"), ".2f"),
                section="accounting",
            ),
            Column(
                "runs below a physical threshold",
                lambda e: rate_with_ci(e.get("share_runs_below_physical")),
                section="accounting",
            ),
        ),
    ),
    Metric(
        "deadline_misses",
        "",
        lambda run: int(np.count_nonzero(run.flag("deadline_miss"))),
        aggregate=_total("deadline_misses"),
        sweep_columns=(Column("deadline misses", misses_cell, section="accounting"),),
    ),
    Metric(
        "warmup_steps",
        "",
        lambda run: int(run.meta.warmup_steps),
        aggregate=_total("warmup_steps"),
        sweep_columns=(Column("warm-up solves", lambda e: str(e.get("warmup_steps", "–")), section="accounting"),),
    ),
    # Extras (beyond docs/design.md §7).
    Metric("steps", "", len, aggregate=_total("steps")),
    Metric("dt", "s", lambda run: run.dt, flatten=_EXTRA),
    Metric("sim_time_s", "s", lambda run: float(run.meta.sim_time_s)),
    Metric("wall_time_s", "s", lambda run: float(run.meta.wall_time_s)),
    Metric("sensing", "", lambda run: run.meta.sensing, flatten=_EXTRA),
    Metric("degraded_steps", "", lambda run: int((run.shared(_status) == "degraded").sum()), flatten=_EXTRA),
    Metric("blind_steps", "", lambda run: int(np.count_nonzero(run.flag("blind")))),
    Metric("activation_toggles", "", lambda run: run.shared(_toggles), flatten=_EXTRA),
    Metric("waypoint_tolerance_m", "m", lambda run: run.waypoint_tolerance_m, flatten=_EXTRA),
    Metric("waypoints_reached", "", lambda run: sum(x is not None for x in run.shared(_waypoints)[1])),
    Metric("time_to_waypoint_s", "s", lambda run: run.shared(_waypoints)[1], flatten=_EXTRA),
    Metric("waypoint_sequence", "", lambda run: run.shared(_waypoints)[0], flatten=_EXTRA),
    Metric("peak_joint_acceleration_rad_s2", "rad/s²", lambda run: peak_joint_acceleration(run.steps)),
    Metric("solve_time_us_by_active_count", "µs", _by_active_count, flatten=_EXTRA),
    Metric("control_points", "", lambda run: list(run.meta.control_points), flatten=_EXTRA),
    Metric(
        "set_task_metrics",
        "",
        lambda run: {
            name: {k: v for k, v in m.items() if not k.startswith("_")}
            for name, m in run.shared(_set_task_results)[0].items()
        },
        flatten=_EXTRA,
    ),
    Metric("set_tasks", "", lambda run: [task.to_dict() for task in run.meta.set_tasks], flatten=_EXTRA),
    # Written by the run (compare.run.run_method), not computed from the table.
    Metric(
        "solve_worst_us",
        "µs",
        None,
        flatten=lambda entry: {"solve_worst_us": _sub(entry, "solve_worst_us", "us")},
    ),
    Metric(
        "deadline_steal_excused",
        "",
        None,
        flatten=lambda entry: {"deadline_steal_excused": _sub(entry, "deadline_steal_excused", "steps")},
        # Late on the raw CPU clock only because the hypervisor took the CPU (kept, not missed).
        aggregate=_total("deadline_steal_excused"),
    ),
    Metric(
        "unsafe_commands",
        "",
        None,
        aggregate=_total("unsafe_commands"),
        sweep_columns=(Column("unsafe commands", lambda e: str(e.get("unsafe_commands", 0)), section="safety"),),
    ),
    Metric(
        "iso15066",
        "m",
        None,
        flatten=_flatten_iso,
        aggregate=lambda runs: {
            "iso15066": {
                "min_margin_m": runs.stat("iso_min_margin_m", "min"),
                "median_min_margin_m": runs.stat("iso_min_margin_m", "median"),
                "share_runs_below_zero": runs.share(runs.positive("iso_time_below_zero_s")),
                "time_below_zero_s_total": runs.stat("iso_time_below_zero_s", "sum"),
            }
        },
        sweep_columns=(
            Column(
                "ISO min margin [m]", lambda e: fmt_number(_sub(e, "iso15066", "min_margin_m"), "+.3f"), section="cost"
            ),
            Column(
                "runs below S_p", lambda e: fmt_percent(_sub(e, "iso15066", "share_runs_below_zero")), section="cost"
            ),
        ),
    ),
    Metric("faults", "", None, flatten=_flatten_faults),
)
"""The metrics of every run, in the order of ``summary.json``."""


_REGISTRY: dict[str, Metric] = {}


def register_metric(metric: Metric, *, replace: bool = False) -> Metric:
    """Add ``metric`` to every summary, sweep and report made afterwards in this process.

    Args:
        metric: The metric (:class:`~compare.analysis.metric.Metric`).
        replace: Allow replacing a registered metric of the same name.

    Returns:
        ``metric``.

    Raises:
        MetricsError: The name is taken (and ``replace`` is false).
    """
    if metric.name in _REGISTRY and not replace:
        raise MetricsError(f"metric '{metric.name}' is already registered (pass replace=True to replace it)")
    _REGISTRY[metric.name] = metric
    return metric


def unregister_metric(name: str) -> None:
    """Remove the metric ``name`` (nothing when there is none)."""
    _REGISTRY.pop(name, None)


def registered_metrics() -> tuple[Metric, ...]:
    """Every registered metric, the built-ins first, in registration order."""
    return tuple(_REGISTRY.values())


for _metric in BUILTIN_METRICS:
    register_metric(_metric)


def compute_summary(steps: pd.DataFrame, meta: RunMeta, waypoint_tolerance_m: float = 0.02) -> dict[str, Any]:
    """Metrics of one run for ``summary.json["methods"][meta.method]`` (docs/design.md §6–7).

    Every registered metric with a ``compute`` (:func:`registered_metrics`), in registration
    order. Rows whose ``t`` is NaN (steps the loop could not fill) are dropped first.

    Args:
        steps: Per-step table (columns in the module docstring).
        meta: Run description and set-task thresholds.
        waypoint_tolerance_m: EE error below which a waypoint counts as reached [m].

    Returns:
        JSON-ready dict. The docs/design.md §7 keys (``solve_time_us``, ``realtime_factor``,
        ``joint_limits``, ``walls``, ``obstacles``, ``min_obstacle_distance_m``, ``ee_error_m``,
        ``failures``, ``fallbacks``, ``activation_toggles_per_s``, and the step accounting
        ``status_steps`` {ok, degraded, failed}, ``fallback_steps``, ``time_below_physical_s``
        (any set task past its physical threshold, exact), ``deadline_misses``,
        ``warmup_steps``) plus extras: ``steps``,
        ``dt``, ``sim_time_s``, ``wall_time_s``, ``sensing``, ``blind_steps``,
        ``activation_toggles``, ``waypoints_reached``, ``time_to_waypoint_s``,
        ``waypoint_sequence``, ``waypoint_tolerance_m``, ``peak_joint_acceleration_rad_s2``,
        ``solve_time_us_by_active_count``, ``set_task_metrics`` (per task), ``set_tasks``
        (thresholds of every set task, infinite bounds as ``None``; read by the plots),
        ``groups`` (every group of :func:`task_groups`, those of :data:`GROUPS` included).
        A group with no task is ``None``; a group whose σ was never finite has ``None`` margins
        and zero violations.

    Raises:
        MetricsError: A required column is missing.
    """
    required = ["t", "ee_error_m", "solve_time_us", "status", "fallback"]
    required += [f"sigma:{task.name}" for task in meta.set_tasks]
    missing = [c for c in required if c not in steps.columns]
    if missing:
        raise MetricsError(f"per-step table of method '{meta.method}' lacks column(s): {', '.join(missing)}")
    run = RunSteps(steps, meta, waypoint_tolerance_m)
    return to_jsonable({m.name: m.compute(run) for m in registered_metrics() if m.compute is not None})


def set_tasks_from_summary(method_summary: Entry) -> tuple[SetTaskInfo, ...]:
    """The :class:`SetTaskInfo` stored under ``set_tasks`` of a method summary (empty if absent)."""
    return tuple(SetTaskInfo.from_dict(d) for d in method_summary.get("set_tasks") or [])


__all__ = [
    "BUILTIN_METRICS",
    "GROUPS",
    "VIOLATION_TOLERANCE",
    "MetricsError",
    "RunMeta",
    "SetTaskInfo",
    "compute_summary",
    "group_summary",
    "margins",
    "misses_cell",
    "register_metric",
    "registered_metrics",
    "rising_edges",
    "set_task_infos",
    "set_tasks_from_summary",
    "summary_groups",
    "task_groups",
    "to_jsonable",
    "unregister_metric",
    "waypoint_times",
]
