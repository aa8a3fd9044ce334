r"""Per-run metrics (DESIGN §6) computed from the per-step table of the closed loop.

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
``deadline_miss``          bool     the solve took longer than its deadline (the control period,
                                    or the solver time limit when one is set)
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

``compare.run.run_method`` adds per method ``faults`` (per fault kind: injected steps,
reaction, latencies; :meth:`compare.loop.faults.FaultInjector.summarize`), ``unsafe_commands``
and ``iso15066`` (:func:`compare.analysis.iso15066.summarize`) to the summary.

Margins are signed, in the task's unit, positive inside the allowed set:

.. math:: m_k = \min(\sigma_k - \sigma_{k,l},\ \sigma_{k,u} - \sigma_k)

with the safety thresholds :math:`\sigma_{s,l}, \sigma_{s,u}` for the safety margin and the
physical ones :math:`\sigma_m, \sigma_M` for the physical margin. Non-finite σ (no obstacle in
range, or a row the loop could not fill) contributes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from compare.exceptions import CompareError
from tpik.hierarchy import Hierarchy

GROUPS: tuple[str, ...] = ("joint_limits", "walls", "obstacles")
"""The DESIGN §7 set-task groups, always in ``summary.json`` (``None`` when the run has none).

Every group, these and any other a set task names (:attr:`tpik.tasks.SetTask.group`, e.g. a
new safety task's), is also under ``"groups"``: ``summary["groups"][<group>]`` (:func:`task_groups`).
"""


class MetricsError(CompareError, ValueError):
    """The per-step table does not match the run description (missing columns, empty table)."""


@dataclass(frozen=True)
class SetTaskInfo:
    """Name, group and thresholds of one scalar set-based task.

    Attributes:
        name: Task name (the ``sigma:<name>`` / ``active:<name>`` columns).
        group: The task's metrics group (:attr:`tpik.tasks.SetTask.group`): ``joint_limits``,
            ``walls``, ``obstacles`` or any other; each group is summarised under its name.
        physical_lower: σ_m, physical lower threshold (−inf if none) [task unit].
        safety_lower: σ_{s,l}, safety lower threshold (−inf if none) [task unit].
        safety_upper: σ_{s,u}, safety upper threshold (+inf if none) [task unit].
        physical_upper: σ_M, physical upper threshold (+inf if none) [task unit].
    """

    name: str
    group: str
    physical_lower: float
    safety_lower: float
    safety_upper: float
    physical_upper: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict; infinite thresholds become ``None`` (no bound on that side)."""
        return to_jsonable(
            {
                "name": self.name,
                "group": self.group,
                "physical_lower": self.physical_lower,
                "safety_lower": self.safety_lower,
                "safety_upper": self.safety_upper,
                "physical_upper": self.physical_upper,
            }
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SetTaskInfo:
        """Inverse of :meth:`to_dict` (``None`` lower/upper → −inf/+inf)."""

        def bound(key: str, default: float) -> float:
            value = data.get(key)
            return default if value is None else float(value)

        return cls(
            name=str(data["name"]),
            group=str(data["group"]),
            physical_lower=bound("physical_lower", -math.inf),
            safety_lower=bound("safety_lower", -math.inf),
            safety_upper=bound("safety_upper", math.inf),
            physical_upper=bound("physical_upper", math.inf),
        )


def set_task_infos(hierarchy: Hierarchy) -> tuple[SetTaskInfo, ...]:
    """Group (:attr:`tpik.tasks.SetTask.group`) and thresholds of every set-based task, for the metrics."""
    infos = []
    for task in hierarchy.set_tasks:
        th = task.thresholds
        infos.append(
            SetTaskInfo(task.name, task.group, th.physical_lower, th.safety_lower, th.safety_upper, th.physical_upper)
        )
    return tuple(infos)


@dataclass(frozen=True)
class RunMeta:
    """What the metrics need to know about a run besides its per-step table.

    Attributes:
        scenario: Scenario name.
        seed: Random seed of the scenario.
        method: Method key (``tpik``, ``hqp-daqp``, ``mink``, ...).
        dt: Control period [s].
        sim_time_s: Simulated time covered [s].
        wall_time_s: Wall-clock time of the loop [s].
        sensing: ``depth`` or ``geometric``.
        set_tasks: Every scalar set-based task of the hierarchy.
        control_points: Frames of the obstacle control points (``dist_*:<frame>`` columns;
            ``compare.loop.closed_loop.control_points``); none = no distances reported.
        warmup_steps: Untimed solves made before the first control step (not in the table,
            hence not in the solve-time percentiles).
    """

    scenario: str
    seed: int
    method: str
    dt: float
    sim_time_s: float
    wall_time_s: float
    sensing: str
    set_tasks: tuple[SetTaskInfo, ...]
    control_points: tuple[str, ...] = ()
    warmup_steps: int = 0


def to_jsonable(obj: Any) -> Any:
    """Convert ``obj`` to plain JSON types: numpy scalars/arrays → Python, NaN/±inf → ``None``.

    Dict keys become strings, tuples become lists, paths become strings.
    """
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [to_jsonable(v) for v in obj.tolist()]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)


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


def summary_groups(method_summary: dict[str, Any]) -> tuple[str, ...]:
    """The set-task groups of a method summary (the keys of its ``groups``; :data:`GROUPS` if absent)."""
    return tuple(method_summary.get("groups") or GROUPS)


def group_summary(method_summary: dict[str, Any], group: str) -> dict[str, Any] | None:
    """The metrics of one group in a method summary (``None`` when the run has no task of it)."""
    groups = method_summary.get("groups")
    value = groups.get(group) if isinstance(groups, dict) else method_summary.get(group)
    return value if isinstance(value, dict) else None


def _nanmin(x: np.ndarray) -> float | None:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(x.min()) if x.size else None


def _column(steps: pd.DataFrame, name: str, default: float = math.nan) -> np.ndarray:
    if name in steps.columns:
        return steps[name].to_numpy(dtype=float, na_value=np.nan)
    return np.full(len(steps), default)


def _bool_column(steps: pd.DataFrame, name: str) -> np.ndarray:
    if name not in steps.columns:
        return np.zeros(len(steps), dtype=bool)
    return steps[name].astype("boolean").fillna(False).to_numpy(dtype=bool)


def task_sigma_for_safety(steps: pd.DataFrame, task: SetTaskInfo) -> np.ndarray:
    """σ used for the safety metrics: ``truth:N`` when recorded (obstacle tasks), else ``sigma:N``."""
    if f"truth:{task.name}" in steps.columns:
        return _column(steps, f"truth:{task.name}")
    return _column(steps, f"sigma:{task.name}")


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
        # Extras (not part of the DESIGN §7 contract).
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


def compute_summary(steps: pd.DataFrame, meta: RunMeta, waypoint_tolerance_m: float = 0.02) -> dict[str, Any]:
    """Metrics of one run for ``summary.json["methods"][meta.method]`` (DESIGN §6–7).

    Rows whose ``t`` is NaN (steps the loop could not fill) are dropped first.

    Args:
        steps: Per-step table (columns in the module docstring).
        meta: Run description and set-task thresholds.
        waypoint_tolerance_m: EE error below which a waypoint counts as reached [m].

    Returns:
        JSON-ready dict. The DESIGN §7 keys (``solve_time_us``, ``realtime_factor``,
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
    steps = steps[steps["t"].notna()].reset_index(drop=True)
    dt = float(meta.dt)
    t = steps["t"].to_numpy(dtype=float)

    per_task_raw = {task.name: _task_metrics(task_sigma_for_safety(steps, task), task, dt) for task in meta.set_tasks}
    groups: dict[str, Any] = {}
    for group in task_groups(meta.set_tasks):
        groups[group] = _group_metrics(per_task_raw, [task for task in meta.set_tasks if task.group == group], dt)
    per_task = {name: {k: v for k, v in m.items() if not k.startswith("_")} for name, m in per_task_raw.items()}
    below_physical = np.zeros(len(steps), dtype=bool)
    for task in meta.set_tasks:
        physical = margins(task_sigma_for_safety(steps, task), task.physical_lower, task.physical_upper)
        with np.errstate(invalid="ignore"):
            below_physical |= np.nan_to_num(physical, nan=0.0) < 0.0

    min_dist: list[float | None] = [_nanmin(_column(steps, f"dist_true:{cp}")) for cp in meta.control_points]

    ee_error = _column(steps, "ee_error_m")
    finite_err = ee_error[np.isfinite(ee_error)]
    status = steps["status"].astype("string").fillna("")
    fallback = _bool_column(steps, "fallback")

    active_cols = [f"active:{task.name}" for task in meta.set_tasks if f"active:{task.name}" in steps.columns]
    active = np.zeros((len(steps), len(active_cols)), dtype=bool)
    for k, col in enumerate(active_cols):
        active[:, k] = _bool_column(steps, col)
    toggles = int(np.count_nonzero(active[1:] != active[:-1])) if len(steps) > 1 else 0
    sim_time_s = float(meta.sim_time_s)

    solve_us = _column(steps, "solve_time_us")
    by_active: dict[str, Any] = {}
    n_active = active.sum(axis=1).astype(int)
    for k in np.unique(n_active):
        sel = solve_us[(n_active == k) & np.isfinite(solve_us)]
        if sel.size:
            by_active[str(int(k))] = {
                "steps": int(sel.size),
                "median": float(np.median(sel)),
                "p99": float(np.percentile(sel, 99)),
            }

    waypoint = steps["waypoint"].to_numpy(dtype=int) if "waypoint" in steps.columns else np.zeros(len(steps), int)
    wp_indices, wp_times = waypoint_times(t, waypoint, ee_error, waypoint_tolerance_m)

    summary: dict[str, Any] = {
        "solve_time_us": _percentiles_us(solve_us),
        "realtime_factor": sim_time_s / meta.wall_time_s if meta.wall_time_s > 0 else None,
        "joint_limits": groups["joint_limits"],
        "walls": groups["walls"],
        "obstacles": groups["obstacles"],
        "min_obstacle_distance_m": min_dist,
        "ee_error_m": {
            "final": float(finite_err[-1]) if finite_err.size else None,
            "mean": float(finite_err.mean()) if finite_err.size else None,
        },
        "failures": int((status == "failed").sum()),
        "fallbacks": int(np.count_nonzero(fallback)),
        "activation_toggles_per_s": toggles / sim_time_s if sim_time_s > 0 else None,
        # One accounting for every method (DESIGN §3, §7).
        "status_steps": {key: int((status == key).sum()) for key in ("ok", "degraded", "failed")},
        "fallback_steps": int(np.count_nonzero(fallback)),
        "time_below_physical_s": float(np.count_nonzero(below_physical) * dt),
        "deadline_misses": int(np.count_nonzero(_bool_column(steps, "deadline_miss"))),
        "warmup_steps": int(meta.warmup_steps),
        # Extras.
        "steps": len(steps),
        "dt": dt,
        "sim_time_s": sim_time_s,
        "wall_time_s": float(meta.wall_time_s),
        "sensing": meta.sensing,
        "degraded_steps": int((status == "degraded").sum()),
        "blind_steps": int(np.count_nonzero(_bool_column(steps, "blind"))),
        "activation_toggles": toggles,
        "waypoint_tolerance_m": float(waypoint_tolerance_m),
        "waypoints_reached": sum(x is not None for x in wp_times),
        "time_to_waypoint_s": wp_times,
        "waypoint_sequence": wp_indices,
        "peak_joint_acceleration_rad_s2": peak_joint_acceleration(steps),
        "solve_time_us_by_active_count": by_active,
        "control_points": list(meta.control_points),
        "set_task_metrics": per_task,
        "set_tasks": [task.to_dict() for task in meta.set_tasks],
        "groups": groups,
    }
    return to_jsonable(summary)


def set_tasks_from_summary(method_summary: dict[str, Any]) -> tuple[SetTaskInfo, ...]:
    """The :class:`SetTaskInfo` stored under ``set_tasks`` of a method summary (empty if absent)."""
    return tuple(SetTaskInfo.from_dict(d) for d in method_summary.get("set_tasks") or [])


__all__ = [
    "GROUPS",
    "MetricsError",
    "RunMeta",
    "SetTaskInfo",
    "compute_summary",
    "group_summary",
    "margins",
    "rising_edges",
    "set_tasks_from_summary",
    "summary_groups",
    "task_groups",
    "to_jsonable",
    "waypoint_times",
]
