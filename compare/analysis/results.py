"""Results directories: ``summary.json``, per-step tables, sweeps (DESIGN §7).

A run directory holds::

    config.toml              copy of the configuration (when given)
    summary.json             {"scenario", "seed", "sim_time_s", "versions", "methods": {...},
                              "errors": {...} (only if a method failed)}
    steps/<method>.parquet   per-step table (``steps/<method>.csv`` if Parquet is unavailable)
    plots/*.png              written by :mod:`compare.analysis.plots`
    report.md                written by :mod:`compare.analysis.report`

``summary.json`` is rewritten atomically after every method, so a crash leaves the methods
finished so far intact. Each method entry is the output of
:func:`compare.analysis.metrics.compute_summary`; its ``set_tasks`` list holds the thresholds of every
set task (infinite bounds as ``null``), which the plots read.

A sweep directory holds ``runs/<index:05d>/`` run directories, ``sweep_runs.csv`` (one row per
run and method), ``sweep_summary.json`` (per-method aggregates), ``plots/`` and
``sweep_report.md`` (:func:`compare.analysis.report.render_sweep_report`).
"""

from __future__ import annotations

import copy
import functools
import json
import logging
import math
import os
import subprocess
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from compare.analysis.metrics import GROUPS, to_jsonable
from compare.versions import versions

log = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"
STEPS_DIR = "steps"
RUNS_DIR = "runs"
SWEEP_SUMMARY_FILE = "sweep_summary.json"
SWEEP_RUNS_FILE = "sweep_runs.csv"


@functools.cache
def git_commit() -> str | None:
    """Commit of the project checkout (``git rev-parse HEAD``), or None outside a git checkout."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=5.0,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit or None


def run_versions() -> dict[str, str]:
    """:func:`compare.bench.timing.versions` plus ``git_commit`` when available."""
    out = dict(versions())
    commit = git_commit()
    if commit is not None:
        out["git_commit"] = commit
    return out


def write_json_atomic(path: Path, data: Any) -> None:
    """Write ``data`` as JSON to ``path`` through a temporary file and :func:`os.replace`.

    Readers never see a half-written file. NaN/inf are refused (encode them as ``None`` first,
    see :func:`compare.analysis.metrics.to_jsonable`).
    """
    path = Path(path)
    text = json.dumps(data, indent=2, allow_nan=False)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.write("\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def safe_name(method: str) -> str:
    """File-system-safe version of a method key (``hqp-daqp`` stays as it is)."""
    return "".join(c if c.isalnum() or c in "-_.+" else "_" for c in method)


class ResultsWriter:
    """Write one run's results method by method.

    Args:
        out_dir: Run directory (created with its parents).
        scenario: Scenario name.
        seed: Scenario seed.
        sim_time_s: Simulated duration of the scenario [s].
        config_text: TOML text of the configuration, copied to ``config.toml`` (skipped if None).
    """

    def __init__(self, out_dir: Path, scenario: str, seed: int, sim_time_s: float, config_text: str | None) -> None:
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        if config_text is not None:
            (self.out_dir / "config.toml").write_text(config_text, encoding="utf-8")
        self._summary: dict[str, Any] = {
            "scenario": scenario,
            "seed": int(seed),
            "sim_time_s": float(sim_time_s),
            "versions": run_versions(),
            "methods": {},
        }
        self._write()

    @property
    def summary(self) -> dict[str, Any]:
        """A copy of the content of ``summary.json``."""
        return copy.deepcopy(self._summary)

    @property
    def summary_path(self) -> Path:
        """Path of ``summary.json``."""
        return self.out_dir / SUMMARY_FILE

    def add_method(self, name: str, summary: dict[str, Any], steps: pd.DataFrame) -> Path:
        """Store one finished method: its per-step table, then the updated ``summary.json``.

        Args:
            name: Method key (``tpik``, ``hqp-daqp``, ``mink``, ...).
            summary: Output of :func:`compare.analysis.metrics.compute_summary` (extra keys allowed).
            steps: Per-step table.

        Returns:
            Path of the per-step table written.
        """
        steps_path = self._write_steps(name, steps)
        entry = to_jsonable(summary)
        entry["steps_file"] = steps_path.relative_to(self.out_dir).as_posix()
        self._summary["methods"][name] = entry
        errors = self._summary.get("errors")
        if errors and name in errors:  # a re-run succeeded
            del errors[name]
            if not errors:
                del self._summary["errors"]
        self._write()
        return steps_path

    def set_run_info(self, key: str, value: Any) -> None:
        """Store a run-level entry of ``summary.json`` beside ``methods`` (e.g. ``oracle``)."""
        if key in ("methods", "errors"):
            raise ValueError(f"'{key}' is written by add_method/add_error")
        self._summary[key] = to_jsonable(value)
        self._write()

    def add_error(self, name: str, message: str) -> None:
        """Record that method ``name`` failed, keeping every other method's results."""
        self._summary.setdefault("errors", {})[name] = str(message)
        self._write()

    def _write_steps(self, name: str, steps: pd.DataFrame) -> Path:
        steps_dir = self.out_dir / STEPS_DIR
        steps_dir.mkdir(exist_ok=True)
        stem = safe_name(name)
        parquet = steps_dir / f"{stem}.parquet"
        try:
            steps.to_parquet(parquet, index=False)
            (steps_dir / f"{stem}.csv").unlink(missing_ok=True)
            return parquet
        except Exception as exc:  # no pyarrow, or a column it cannot encode: CSV always works
            log.warning("Parquet failed for %s (%s); writing CSV", name, exc)
            parquet.unlink(missing_ok=True)
            csv = steps_dir / f"{stem}.csv"
            steps.to_csv(csv, index=False)
            return csv

    def _write(self) -> None:
        write_json_atomic(self.summary_path, to_jsonable(self._summary))


def load_summary(results_dir: Path) -> dict[str, Any]:
    """Read ``results_dir/summary.json``.

    Raises:
        FileNotFoundError: No summary in ``results_dir``.
    """
    with open(Path(results_dir) / SUMMARY_FILE, encoding="utf-8") as fh:
        return json.load(fh)


def load_steps(results_dir: Path, method: str) -> pd.DataFrame:
    """Read the per-step table of ``method`` (Parquet or CSV).

    Raises:
        FileNotFoundError: No table for ``method``; the message lists the available ones.
    """
    steps_dir = Path(results_dir) / STEPS_DIR
    stem = safe_name(method)
    parquet = steps_dir / f"{stem}.parquet"
    if parquet.is_file():
        return pd.read_parquet(parquet)
    csv = steps_dir / f"{stem}.csv"
    if csv.is_file():
        return pd.read_csv(csv)
    available = sorted(p.stem for p in steps_dir.glob("*")) if steps_dir.is_dir() else []
    raise FileNotFoundError(
        f"no per-step table for method '{method}' in {steps_dir} (available: {', '.join(available) or 'none'})"
    )


# --------------------------------------------------------------------------------------------- sweeps


def sweep_run_dir(out_dir: Path, index: int) -> Path:
    """Directory of run ``index`` of a sweep: ``out_dir/runs/00042``."""
    return Path(out_dir) / RUNS_DIR / f"{int(index):05d}"


def is_finished(run_dir: Path, methods: Iterable[str] | None = None) -> bool:
    """Whether ``run_dir`` holds a readable ``summary.json`` with results for every method.

    Args:
        run_dir: Run directory.
        methods: Methods that must be present; None = at least one method and no recorded error.

    Returns:
        False if the summary is missing, unreadable, lacks a requested method, or (with
        ``methods=None``) records an error — such runs are re-run by a resumed sweep.
    """
    try:
        summary = load_summary(run_dir)
    except (OSError, ValueError):
        return False
    done = summary.get("methods") or {}
    if methods is None:
        return bool(done) and not summary.get("errors")
    return all(m in done for m in methods)


def _min_or_none(values: Iterable[Any]) -> float | None:
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return min(finite) if finite else None


def flatten_method(summary: dict[str, Any]) -> dict[str, Any]:
    """Key metrics of one method summary as a flat dict (one row of ``sweep_runs.csv``).

    Missing values are ``None``; a group the scenario does not have gives ``None`` margins and
    ``0`` violations.
    """
    solve = summary.get("solve_time_us") or {}
    ee = summary.get("ee_error_m") or {}
    dist = summary.get("min_obstacle_distance_m") or []
    cps = summary.get("control_points") or [f"cp{i}" for i in range(len(dist))]
    row: dict[str, Any] = {
        "solve_median_us": solve.get("median"),
        "solve_p95_us": solve.get("p95"),
        "solve_p99_us": solve.get("p99"),
        "solve_max_us": solve.get("max"),
        "realtime_factor": summary.get("realtime_factor"),
    }
    for group in GROUPS:
        g = summary.get(group)
        row[f"{group}_present"] = isinstance(g, dict)
        g = g if isinstance(g, dict) else {}
        row[f"{group}_safety_margin_min"] = g.get("safety_margin_min")
        row[f"{group}_physical_margin_min"] = g.get("physical_margin_min")
        row[f"{group}_violations"] = int(g.get("violations") or 0)
        row[f"{group}_violation_time_s"] = float(g.get("violation_time_s") or 0.0)
    row["min_obstacle_distance_m"] = _min_or_none(dist)
    for cp, d in zip(cps, dist, strict=False):
        row[f"min_obstacle_distance_m:{cp}"] = d
    row.update(
        {
            "ee_error_final_m": ee.get("final"),
            "ee_error_mean_m": ee.get("mean"),
            "failures": summary.get("failures"),
            "fallbacks": summary.get("fallbacks"),
            "activation_toggles_per_s": summary.get("activation_toggles_per_s"),
            "blind_steps": summary.get("blind_steps"),
            "waypoints_reached": summary.get("waypoints_reached"),
            "peak_joint_acceleration_rad_s2": summary.get("peak_joint_acceleration_rad_s2"),
        }
    )
    # Reliability campaigns (issue 9): ISO/TS 15066 margin, injected faults, command guard, cost.
    iso = summary.get("iso15066") or {}
    faults = summary.get("faults") or {}
    latencies = [f.get("reaction_latency_s_max") for f in faults.values() if isinstance(f, dict)]
    row.update(
        {
            "iso_min_margin_m": iso.get("min_margin_m"),
            "iso_time_below_zero_s": iso.get("time_below_zero_s"),
            "iso_human_speed_max_mps": iso.get("human_speed_max_mps"),
            "unsafe_commands": summary.get("unsafe_commands"),
            "fault_injected_steps": int(sum((f.get("injected_steps") or 0) for f in faults.values())),
            "fault_unreacted": int(sum(f.get("reaction") == "none" for f in faults.values())),
            "fault_reaction_latency_s_max": _max_or_none(latencies),
            "sim_time_s": summary.get("sim_time_s"),
            "wall_time_s": summary.get("wall_time_s"),
        }
    )
    return row


def _max_or_none(values: Iterable[Any]) -> float | None:
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return max(finite) if finite else None


def collect_sweep(out_dir: Path) -> pd.DataFrame:
    """One row per (run, method) of a sweep: seed, key metrics, and ``error`` for failed methods.

    Runs without a readable ``summary.json`` are skipped. Columns: ``run``, ``scenario``,
    ``seed``, ``method``, ``error`` (None when the method finished) and those of
    :func:`flatten_method`.
    """
    runs_dir = Path(out_dir) / RUNS_DIR
    rows: list[dict[str, Any]] = []
    for run_dir in sorted(p for p in runs_dir.glob("*") if p.is_dir()) if runs_dir.is_dir() else []:
        try:
            summary = load_summary(run_dir)
        except (OSError, ValueError):
            continue
        base = {"run": run_dir.name, "scenario": summary.get("scenario"), "seed": summary.get("seed")}
        for method, msum in (summary.get("methods") or {}).items():
            rows.append({**base, "method": method, "error": None, **flatten_method(msum)})
        for method, message in (summary.get("errors") or {}).items():
            if method not in (summary.get("methods") or {}):
                rows.append({**base, "method": method, "error": message})
    frame = pd.DataFrame(rows)
    if frame.empty:
        return pd.DataFrame(columns=["run", "scenario", "seed", "method", "error"])
    return frame


def _stat(values: pd.Series, fn: str) -> float | None:
    x = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return None
    if fn == "median":
        return float(np.median(x))
    if fn == "p99":
        return float(np.percentile(x, 99))
    if fn == "min":
        return float(x.min())
    if fn == "max":
        return float(x.max())
    if fn == "sum":
        return float(x.sum())
    raise ValueError(f"unknown statistic '{fn}'")


def summarize_sweep_rows(runs: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """Per-method aggregates of a :func:`collect_sweep` table (the ``methods`` of ``sweep_summary.json``)."""
    if runs.empty or "method" not in runs.columns:
        return {}
    return {str(method): _method_aggregate(rows) for method, rows in runs.groupby("method", sort=False)}


def _method_aggregate(rows: pd.DataFrame) -> dict[str, Any]:
    ok = rows[rows["error"].isna()] if "error" in rows.columns else rows
    n = len(ok)

    def values(name: str) -> pd.Series:
        return ok[name] if name in ok.columns else pd.Series(np.nan, index=ok.index, dtype=float)

    def share(mask: pd.Series) -> float | None:
        return float(mask.sum()) / n if n else None

    def violated(group: str) -> pd.Series:
        return pd.to_numeric(values(f"{group}_violations"), errors="coerce").fillna(0) > 0

    limits_or_walls = violated("joint_limits") | violated("walls")
    obstacles = violated("obstacles")
    return {
        "runs": n,
        "errors": int(len(rows) - n),
        "share_runs_limit_or_wall_violation": share(limits_or_walls),
        "share_runs_obstacle_violation": share(obstacles),
        "share_runs_any_violation": share(limits_or_walls | obstacles),
        "solve_time_us": {
            "median_of_medians": _stat(values("solve_median_us"), "median"),
            "p99_of_medians": _stat(values("solve_median_us"), "p99"),
            "median_of_p99": _stat(values("solve_p99_us"), "median"),
            "max": _stat(values("solve_max_us"), "max"),
        },
        "worst_safety_margin": {g: _stat(values(f"{g}_safety_margin_min"), "min") for g in GROUPS},
        "worst_physical_margin": {g: _stat(values(f"{g}_physical_margin_min"), "min") for g in GROUPS},
        "min_obstacle_distance_m": _stat(values("min_obstacle_distance_m"), "min"),
        "ee_error_final_m": {
            "median": _stat(values("ee_error_final_m"), "median"),
            "max": _stat(values("ee_error_final_m"), "max"),
        },
        "failures": int(_stat(values("failures"), "sum") or 0),
        "fallbacks": int(_stat(values("fallbacks"), "sum") or 0),
        "activation_toggles_per_s_median": _stat(values("activation_toggles_per_s"), "median"),
        # Reliability campaigns (issue 9).
        "share_runs_joint_limit_violation": share(violated("joint_limits")),
        "share_runs_wall_violation": share(violated("walls")),
        "share_runs_with_failures": share(pd.to_numeric(values("failures"), errors="coerce").fillna(0) > 0),
        "share_runs_with_fallbacks": share(pd.to_numeric(values("fallbacks"), errors="coerce").fillna(0) > 0),
        "solve_time_percentiles_us": {
            "p50_of_run_p99": _stat(values("solve_p99_us"), "median"),
            "p95_of_run_p99": _percentile(values("solve_p99_us"), 95),
            "max_of_run_p99": _stat(values("solve_p99_us"), "max"),
            "p95_of_run_medians": _percentile(values("solve_median_us"), 95),
        },
        "iso15066": {
            "min_margin_m": _stat(values("iso_min_margin_m"), "min"),
            "median_min_margin_m": _stat(values("iso_min_margin_m"), "median"),
            "share_runs_below_zero": share(
                pd.to_numeric(values("iso_time_below_zero_s"), errors="coerce").fillna(0) > 0
            ),
            "time_below_zero_s_total": _stat(values("iso_time_below_zero_s"), "sum"),
        },
        "unsafe_commands": int(_stat(values("unsafe_commands"), "sum") or 0),
        "realtime_factor": {
            "median": _stat(values("realtime_factor"), "median"),
            "min": _stat(values("realtime_factor"), "min"),
        },
    }


def _percentile(values: pd.Series, q: float) -> float | None:
    x = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float)
    x = x[np.isfinite(x)]
    return float(np.percentile(x, q)) if x.size else None


TIMING_KEYS = frozenset(
    {"solve_time_us", "realtime_factor", "wall_time_s", "solve_time_us_by_active_count", "versions", "steps_file"}
)
"""Keys of ``summary.json`` whose values depend on the machine's speed or environment, not on
(config, seed): left out when runs are compared for determinism."""


def deterministic_view(summary: Any) -> Any:
    """``summary`` without the :data:`TIMING_KEYS` (recursively): equal for equal (config, seed)."""
    if isinstance(summary, dict):
        return {k: deterministic_view(v) for k, v in summary.items() if k not in TIMING_KEYS}
    if isinstance(summary, list):
        return [deterministic_view(v) for v in summary]
    return summary


def write_sweep_summary(out_dir: Path, runs: pd.DataFrame | None = None) -> dict[str, Any]:
    """Aggregate a sweep per method; write ``sweep_summary.json`` and ``sweep_runs.csv``.

    Args:
        out_dir: Sweep directory.
        runs: Output of :func:`collect_sweep` (collected here if None).

    Returns:
        ``{"runs": <run directories with a summary>, "scenario", "versions",
        "methods": {method: {"runs", "errors", "share_runs_limit_or_wall_violation",
        "share_runs_obstacle_violation", "share_runs_any_violation",
        "solve_time_us": {"median_of_medians", "p99_of_medians", "median_of_p99", "max"},
        "worst_safety_margin": {group: ...}, "worst_physical_margin": {group: ...},
        "min_obstacle_distance_m", "ee_error_final_m": {"median", "max"}, "failures",
        "fallbacks", "activation_toggles_per_s_median"}}}``. Shares are over the runs where
        the method finished; a violation is any safety-margin episode (``violations > 0``).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if runs is None:
        runs = collect_sweep(out_dir)
    runs.to_csv(out_dir / SWEEP_RUNS_FILE, index=False)
    summary: dict[str, Any] = {
        "runs": int(runs["run"].nunique()) if not runs.empty else 0,
        "scenario": None,
        "versions": run_versions(),
        "methods": {},
    }
    if not runs.empty:
        scenarios = runs["scenario"].dropna().unique()
        summary["scenario"] = str(scenarios[0]) if len(scenarios) == 1 else [str(s) for s in scenarios]
        summary["methods"] = summarize_sweep_rows(runs)
    summary = to_jsonable(summary)
    write_json_atomic(out_dir / SWEEP_SUMMARY_FILE, summary)
    return summary
