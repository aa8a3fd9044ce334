"""A per-run metric, declared once and read by every output (:class:`Metric`).

A metric is one entry of a method's ``summary.json`` (docs/design.md §6–7). Its :class:`Metric` says

- ``compute(run)``: the entry, from the run's per-step table (:class:`RunSteps`); ``None`` for an
  entry the run writes from elsewhere (the fault injector, the time limit, the ISO monitor),
- ``flatten(entry)``: its columns of ``sweep_runs.csv`` (default: the value under the metric's name),
- ``aggregate``: its entries of ``sweep_summary.json`` over a sweep's runs (:class:`SweepRuns`),
  either statistics of its column (``("median", "max")`` → ``{name: {"median": …, "max": …}}``)
  or a function returning the entries,
- how it is printed: ``label`` and ``fmt`` (one column of the run table, one per statistic in the
  sweep report), or explicit :class:`Column` lists.

:func:`compare.analysis.metrics.register_metric` adds one; the built-in metrics are registered in
:mod:`compare.analysis.metrics`. :func:`~compare.analysis.metrics.compute_summary` (per run),
:func:`compare.analysis.results.flatten_method` and :func:`compare.analysis.results.summarize_sweep_rows`
(per sweep) and :mod:`compare.analysis.report` (the tables) read
:func:`~compare.analysis.metrics.registered_metrics` in registration order. docs/extending.md,
"A new metric", adds one from a scenario's ``[extensions]``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args

import numpy as np
import pandas as pd

from compare.analysis.statistics import rate, rate_value
from compare.exceptions import CompareError

Entry = Mapping[str, Any]
"""One method's entry of ``summary.json`` (run table) or of ``sweep_summary.json`` (sweep report)."""

Stat = Literal["median", "mean", "p95", "p99", "min", "max", "sum"]
"""A statistic over the runs of a sweep (:meth:`SweepRuns.stat`)."""

Section = Literal["safety", "accounting", "cost", "other"]
"""The table of the sweep report a column is shown in."""

_T = TypeVar("_T")


class MetricsError(CompareError, ValueError):
    """The per-step table does not match the run description, or a metric is declared wrong."""


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


class RunSteps:
    """One method's per-step table of a run with its description: what a metric computes from.

    Rows whose ``t`` is NaN (steps the loop could not fill) are dropped. Columns are listed in
    :mod:`compare.analysis.metrics`.

    Args:
        steps: The per-step table.
        meta: The run's description.
        waypoint_tolerance_m: EE error below which a waypoint counts as reached [m].
    """

    def __init__(self, steps: pd.DataFrame, meta: RunMeta, waypoint_tolerance_m: float = 0.02) -> None:
        self.steps = steps[steps["t"].notna()].reset_index(drop=True)
        self.meta = meta
        self.dt = float(meta.dt)
        self.waypoint_tolerance_m = float(waypoint_tolerance_m)
        self._shared: dict[Callable[[RunSteps], Any], Any] = {}

    def __len__(self) -> int:
        return len(self.steps)

    def has(self, name: str) -> bool:
        """Whether the table has column ``name``."""
        return name in self.steps.columns

    def column(self, name: str, default: float = math.nan) -> np.ndarray:
        """Column ``name`` as floats (missing values NaN); ``default`` everywhere when absent. Shape (T,)."""
        if name in self.steps.columns:
            return self.steps[name].to_numpy(dtype=float, na_value=np.nan)
        return np.full(len(self.steps), default)

    def flag(self, name: str) -> np.ndarray:
        """Boolean column ``name`` (missing values and an absent column: False). Shape (T,)."""
        if name not in self.steps.columns:
            return np.zeros(len(self.steps), dtype=bool)
        values = self.steps[name]
        if values.dtype == np.bool_:  # the loop's own table: no missing values to fill
            return values.to_numpy(dtype=bool, copy=True)
        return values.astype("boolean").fillna(False).to_numpy(dtype=bool)

    def shared(self, compute: Callable[[RunSteps], _T]) -> _T:
        """``compute(self)``, evaluated once per run: what several metrics read (task margins, a mask)."""
        if compute not in self._shared:
            self._shared[compute] = compute(self)
        return self._shared[compute]  # type: ignore[no-any-return]


class SweepRuns:
    """One method's finished runs of a sweep, one row each (the columns of :meth:`Metric.flatten`).

    Args:
        rows: The method's rows of ``sweep_runs.csv`` without an error.
    """

    def __init__(self, rows: pd.DataFrame) -> None:
        self.rows = rows
        self.n = len(rows)

    def values(self, column: str) -> pd.Series:
        """Column ``column`` (all NaN when no run has it)."""
        if column in self.rows.columns:
            return self.rows[column]
        return pd.Series(np.nan, index=self.rows.index, dtype=float)

    def finite(self, column: str) -> np.ndarray:
        """The finite numbers of ``column`` (non-numbers and missing values left out)."""
        x = pd.to_numeric(self.values(column), errors="coerce").to_numpy(dtype=float)
        return x[np.isfinite(x)]

    def stat(self, column: str, stat: Stat) -> float | None:
        """A statistic of the finite values of ``column``; None when there is none."""
        x = self.finite(column)
        if x.size == 0:
            return None
        if stat == "median":
            return float(np.median(x))
        if stat == "mean":
            return float(x.mean())
        if stat in ("p95", "p99"):
            return float(np.percentile(x, float(stat[1:])))
        if stat == "min":
            return float(x.min())
        if stat == "max":
            return float(x.max())
        if stat == "sum":
            return float(x.sum())
        raise MetricsError(f"unknown statistic '{stat}'; one of {', '.join(get_args(Stat))}")

    def total(self, column: str) -> int:
        """Sum of ``column`` over the runs as an integer (0 when none has it)."""
        return int(self.stat(column, "sum") or 0)

    def positive(self, column: str) -> pd.Series:
        """Per run: ``column`` > 0 (a missing value counts as 0)."""
        return pd.to_numeric(self.values(column), errors="coerce").fillna(0) > 0

    def share(self, mask: pd.Series) -> dict[str, Any]:
        """The runs where ``mask`` holds, as a :func:`~compare.analysis.statistics.rate` (Wilson interval)."""
        return rate(int(mask.sum()), self.n)


def fmt_number(x: Any, fmt: str = ".3g") -> str:
    """``x`` formatted with ``fmt``; "–" for None and non-finite numbers."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(x, fmt)


def fmt_percent(x: Any) -> str:
    """The rate of a :func:`~compare.analysis.statistics.rate` entry as ``12.3 %`` ("–" without one)."""
    value = rate_value(x)
    return "–" if value is None else f"{100.0 * value:.1f} %"


def rate_with_ci(x: Any) -> str:
    """``1.2 % [0.6, 2.3] (12/1000)`` from a rate entry (Wilson 95 % interval)."""
    if not isinstance(x, dict) or x.get("rate") is None:
        return fmt_percent(x)
    interval = x.get("ci95")
    ci = f" [{100.0 * interval[0]:.1f}, {100.0 * interval[1]:.1f}]" if interval else ""
    return f"{100.0 * float(x['rate']):.1f} %{ci} ({x['count']}/{x['runs']})"


def _no_style(entry: Entry) -> str | None:
    return None


@dataclass(frozen=True)
class Column:
    """One column of a results table.

    Attributes:
        header: Column header, unit in brackets.
        cell: The text of a method's cell, from its entry.
        style: Rich style of the cell in the terminal (``"bold red"``), or None.
        section: The sweep report's table that shows it (the run table has one).
    """

    header: str
    cell: Callable[[Entry], str]
    style: Callable[[Entry], str | None] = _no_style
    section: Section = "other"


Columns = Sequence[Column] | Callable[[Sequence[Entry]], Sequence[Column]]
"""Columns, or a function of the entries shown that gives them (e.g. one per set-task group)."""

Aggregate = tuple[Stat, ...] | Callable[[SweepRuns], dict[str, Any]]
"""Statistics of the metric's column, or a function giving its entries of ``sweep_summary.json``."""


def no_columns(entry: Entry) -> dict[str, Any]:
    """``flatten`` of a metric with no column in ``sweep_runs.csv``."""
    return {}


@dataclass(frozen=True)
class Metric:
    """One per-run metric: its ``summary.json`` entry, sweep columns and aggregates, and how it is shown.

    Attributes:
        name: Key of the entry in ``summary.json["methods"][<method>]``.
        unit: Unit of the value (``"m"``, ``"s"``, ``"µs"``; ``""`` for a count or a structure).
        compute: ``compute(run) -> value`` from the per-step table; None: the run writes the entry
            itself (:func:`compare.run.run_method`) and the registry only reads it.
        flatten: ``flatten(entry) -> {column: value}``, the metric's columns of ``sweep_runs.csv``
            from the method's whole ``summary.json`` entry; None: ``{name: entry[name]}``.
        aggregate: Statistics of the column ``name`` over a sweep's runs, written as
            ``sweep_summary.json["methods"][<method>][name] = {stat: value}``, or a function of
            :class:`SweepRuns` returning the entries to add; ``()``: not aggregated.
        label: Header of the metric's column in the run table (the unit is appended) and, with
            statistics, in the sweep report; ``""``: not shown (unless the columns are given).
        fmt: Format of its numbers in those columns (``format(value, fmt)``).
        run_columns: The run table's columns, replacing those of ``label``.
        sweep_columns: The sweep report's columns, replacing those of ``label``.
    """

    name: str
    unit: str
    compute: Callable[[RunSteps], Any] | None
    flatten: Callable[[Entry], dict[str, Any]] | None = None
    aggregate: Aggregate = ()
    label: str = ""
    fmt: str = ".3g"
    run_columns: Columns | None = field(default=None, repr=False)
    sweep_columns: Columns | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not self.name:
            raise MetricsError("a metric needs a name (its key in summary.json)")
        if isinstance(self.aggregate, tuple):
            unknown = [s for s in self.aggregate if s not in get_args(Stat)]
            if unknown:
                raise MetricsError(
                    f"metric '{self.name}': unknown statistic(s) {', '.join(map(str, unknown))};"
                    f" one of {', '.join(get_args(Stat))}"
                )

    @property
    def header(self) -> str:
        """``label [unit]`` (the label alone for a unitless metric)."""
        return f"{self.label} [{self.unit}]" if self.unit else self.label

    def columns(self, entry: Entry) -> dict[str, Any]:
        """The metric's columns of ``sweep_runs.csv`` for one method's ``summary.json`` entry."""
        if self.flatten is not None:
            return self.flatten(entry)
        return {self.name: entry.get(self.name)}

    def aggregates(self, runs: SweepRuns) -> dict[str, Any]:
        """The metric's entries of ``sweep_summary.json`` for one method."""
        if callable(self.aggregate):
            return self.aggregate(runs)
        if not self.aggregate:
            return {}
        return {self.name: {stat: runs.stat(self.name, stat) for stat in self.aggregate}}

    def run_table(self, entries: Sequence[Entry]) -> list[Column]:
        """The metric's columns of the run table, for these methods' ``summary.json`` entries."""
        if self.run_columns is not None:
            return list(self.run_columns(entries) if callable(self.run_columns) else self.run_columns)
        if not self.label:
            return []
        name, fmt = self.name, self.fmt
        return [Column(self.header, lambda e: fmt_number(e.get(name), fmt))]

    def sweep_table(self, entries: Sequence[Entry]) -> list[Column]:
        """The metric's columns of the sweep report, for these methods' ``sweep_summary.json`` entries."""
        if self.sweep_columns is not None:
            return list(self.sweep_columns(entries) if callable(self.sweep_columns) else self.sweep_columns)
        if not self.label or callable(self.aggregate):
            return []
        return [self._stat_column(stat) for stat in self.aggregate]

    def _stat_column(self, stat: Stat) -> Column:
        name, fmt = self.name, self.fmt
        return Column(f"{self.header}, {stat} of runs", lambda e: fmt_number((e.get(name) or {}).get(stat), fmt))


__all__ = [
    "Aggregate",
    "Column",
    "Columns",
    "Entry",
    "Metric",
    "MetricsError",
    "RunMeta",
    "RunSteps",
    "Section",
    "SetTaskInfo",
    "Stat",
    "SweepRuns",
    "fmt_number",
    "fmt_percent",
    "no_columns",
    "rate_with_ci",
    "to_jsonable",
]
