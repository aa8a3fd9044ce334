"""A method's settings tuned on a grid: one resumable sweep per grid point, then one table and the choice.

``tpik-compare tune CONFIG -m METHOD --grid KEY=V1,V2,... [--grid ...]`` runs, for every point
of the grid (every combination of the values), the sweep of ``CONFIG`` with ``METHOD`` alone and
``[methods.settings.METHOD]`` set to the point (:func:`compare.campaign.sweep.run_sweep`, in
``OUT/<point>/``; re-running resumes). Then ``tuning.json`` and ``tuning.md``: per point the
runs with a joint-limit or wall violation, with an obstacle violation (Wilson 95 %), the failed
and degraded steps, the time below a physical threshold, the final EE error and the solve time,
ranked by :data:`RULE` (safety first, among the points that still track the EE target); the
first is the choice.

The grid of ``mink-posture`` (docs/benchmarks.md, "Equal care"): the return weight
``level_cost_ratio`` ∈ {3, 10, 30} × ``posture_cost`` ∈ {1e-2, 1e-1}, on seeds 0–999.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from compare.analysis.metric import fmt_number, rate_with_ci
from compare.analysis.metrics import to_jsonable
from compare.analysis.report import markdown_table, write_markdown
from compare.analysis.results import SWEEP_RUNS_FILE, SWEEP_SUMMARY_FILE, write_json_atomic
from compare.config import override_value
from compare.exceptions import CompareError

TUNING_FILE = "tuning.json"
TUNING_REPORT = "tuning.md"

EE_FACTOR = 2.0
"""A point tracks the EE when its median final EE error is at most this factor × the grid's best."""

WAYPOINT_FRACTION = 0.5
"""... and when it reaches, per run on average, at least this fraction of the grid's most waypoints."""

RULE = (
    f"first the points that track the EE (median final EE error at most {EE_FACTOR:g} × the grid's best, and "
    f"at least {WAYPOINT_FRACTION:g} × the grid's most waypoints reached per run: a setting that stops "
    "following the target is not a safer tuning), then fewest runs with a joint-limit or "
    "wall violation, the least time below a physical threshold, the fewest failed steps, the smallest median "
    "final EE error"
)
"""How the grid points are ranked (:func:`rank_key`); the first is the choice."""


class GridError(CompareError, ValueError):
    """A ``--grid`` option that is not ``KEY=V1,V2,...`` (one line, exit 2)."""


def parse_grid(items: Sequence[str]) -> dict[str, list[Any]]:
    """``["level_cost_ratio=3,10,30", "posture_cost=0.01,0.1"]`` → ``{key: [values]}`` (TOML values).

    Raises:
        GridError: An item without ``=``, a key given twice, or no value.
    """
    grid: dict[str, list[Any]] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        values = [v.strip() for v in text.split(",") if v.strip()]
        if not sep or not key or not values:
            raise GridError(f"--grid: KEY=V1,V2,... expected, got '{item}'")
        if key in grid:
            raise GridError(f"--grid: '{key}' given twice")
        grid[key] = [override_value(v) for v in values]
    if not grid:
        raise GridError("--grid: at least one KEY=V1,V2,... is needed")
    return grid


def grid_points(grid: Mapping[str, Sequence[Any]]) -> list[dict[str, Any]]:
    """Every combination of the grid's values, the first key varying slowest."""
    keys = list(grid)
    return [dict(zip(keys, values, strict=True)) for values in itertools.product(*(grid[k] for k in keys))]


def point_name(point: Mapping[str, Any]) -> str:
    """The directory of a grid point: ``level_cost_ratio-3_posture_cost-0.01``."""
    return "_".join(f"{key}-{value}" for key, value in point.items())


def point_overrides(method: str, point: Mapping[str, Any]) -> dict[str, Any]:
    """Config overrides that run ``method`` alone with the point's settings."""
    overrides: dict[str, Any] = {"methods.names": [method]}
    for key, value in point.items():
        overrides[f"methods.settings.{method}.{key}"] = value
    return overrides


def _waypoints_mean(runs_csv: Path, method: str) -> float | None:
    """Mean waypoints reached per run of ``method`` in a sweep's ``sweep_runs.csv`` (None: no such file or column)."""
    if not runs_csv.is_file():
        return None
    with runs_csv.open(encoding="utf-8", newline="") as f:
        values = [
            float(row["waypoints_reached"])
            for row in csv.DictReader(f)
            if row.get("method") == method and row.get("waypoints_reached") not in (None, "")
        ]
    return sum(values) / len(values) if values else None


def _entry(
    method: str, point: Mapping[str, Any], summary: Mapping[str, Any], waypoints: float | None
) -> dict[str, Any]:
    m = (summary.get("methods") or {}).get(method) or {}
    steps = m.get("status_steps") or {}
    return {
        "point": dict(point),
        "dir": point_name(point),
        "runs": m.get("runs"),
        "limit_or_wall_violation": m.get("share_runs_limit_or_wall_violation"),
        "obstacle_violation": m.get("share_runs_obstacle_violation"),
        "failed_steps": steps.get("failed"),
        "degraded_steps": steps.get("degraded"),
        "time_below_physical_s": m.get("time_below_physical_s"),
        "ee_error_final_m_median": (m.get("ee_error_final_m") or {}).get("median"),
        "waypoints_reached_mean": waypoints,
        "solve_time_us_median": (m.get("solve_time_us") or {}).get("median_of_medians"),
    }


def _number(x: Any) -> float:
    return float(x) if isinstance(x, int | float) and math.isfinite(x) else math.inf


def rank_key(
    entry: Mapping[str, Any], best_ee_m: float, most_waypoints: float = 0.0
) -> tuple[float, float, float, float, float]:
    """:data:`RULE` as a sort key.

    ``best_ee_m``: the grid's smallest median final EE error [m] (a point without it: last);
    ``most_waypoints``: the grid's most waypoints reached per run (a point without the figure is
    judged on the EE error alone).
    """
    ee = _number(entry.get("ee_error_final_m_median"))
    waypoints = entry.get("waypoints_reached_mean")
    reaches = waypoints is None or waypoints >= WAYPOINT_FRACTION * most_waypoints
    violations = (entry.get("limit_or_wall_violation") or {}).get("count")
    return (
        0.0 if ee <= EE_FACTOR * best_ee_m and reaches else 1.0,
        _number(violations),
        _number(entry.get("time_below_physical_s")),
        _number(entry.get("failed_steps")),
        ee,
    )


def tuning_table(out_dir: Path, method: str, points: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Every finished grid point's figures, ranked by :data:`RULE`; ``choice`` is the first point."""
    entries = []
    for point in points:
        path = Path(out_dir) / point_name(point) / SWEEP_SUMMARY_FILE
        if path.is_file():
            waypoints = _waypoints_mean(path.parent / SWEEP_RUNS_FILE, method)
            entries.append(_entry(method, point, json.loads(path.read_text(encoding="utf-8")), waypoints))
    most = max((e["waypoints_reached_mean"] or 0.0 for e in entries), default=0.0)
    reaching = [
        e
        for e in entries
        if e["waypoints_reached_mean"] is None or e["waypoints_reached_mean"] >= WAYPOINT_FRACTION * most
    ]
    best = min((_number(e["ee_error_final_m_median"]) for e in reaching), default=math.inf)
    entries.sort(key=lambda e: rank_key(e, best, most))
    return {
        "method": method,
        "rule": RULE,
        "grid": [dict(p) for p in points],
        "points": entries,
        "choice": entries[0]["point"] if entries else None,
    }


def write_tuning(out_dir: Path, method: str, points: Sequence[Mapping[str, Any]], command: str) -> Path:
    """Write ``tuning.json`` and ``tuning.md`` of the grid in ``out_dir``; returns the report path."""
    table = tuning_table(out_dir, method, points)
    table["command"] = command
    write_json_atomic(Path(out_dir) / TUNING_FILE, to_jsonable(table))
    runs = {e["runs"] for e in table["points"]}
    lines = [
        f"# `{method}` tuned on a grid ({len(table['points'])} of {len(points)} points, runs per point: "
        f"{', '.join(str(r) for r in sorted(runs, key=str)) or '–'})",
        "",
        f"- command: `{command}`",
        f"- ranked by: {RULE}",
        f"- choice: `{table['choice']}`" if table["choice"] is not None else "- choice: none (no finished point)",
        "",
    ]
    headers = [
        "rank",
        "settings",
        "joint-limit/wall violation (Wilson 95 %)",
        "obstacle violation (Wilson 95 %)",
        "time below a physical threshold [s]",
        "steps failed / degraded",
        "EE final error [m] (median)",
        "waypoints reached per run (mean)",
        "solve median [µs]",
    ]
    rows = [
        [
            str(i + 1),
            ", ".join(f"{k} = {v}" for k, v in e["point"].items()),
            rate_with_ci(e["limit_or_wall_violation"]),
            rate_with_ci(e["obstacle_violation"]),
            fmt_number(e["time_below_physical_s"], ".2f"),
            f"{fmt_number(e['failed_steps'], 'd')} / {fmt_number(e['degraded_steps'], 'd')}",
            fmt_number(e["ee_error_final_m_median"], ".3f"),
            fmt_number(e["waypoints_reached_mean"], ".2f"),
            fmt_number(e["solve_time_us_median"], ".0f"),
        ]
        for i, e in enumerate(table["points"])
    ]
    lines.append(markdown_table(headers, rows) if rows else "No finished grid point.")
    return write_markdown(Path(out_dir) / TUNING_REPORT, lines)


__all__ = [
    "EE_FACTOR",
    "RULE",
    "WAYPOINT_FRACTION",
    "TUNING_FILE",
    "TUNING_REPORT",
    "GridError",
    "grid_points",
    "parse_grid",
    "point_name",
    "point_overrides",
    "rank_key",
    "tuning_table",
    "write_tuning",
]
