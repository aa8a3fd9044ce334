"""Find and load what a replay needs: the run directory, its concrete scenario, each method's steps.

A run directory is replayable when its ``summary.json`` carries a replay record
(``{"replay": {"format", "scenario_file"}}``, written by
:meth:`compare.analysis.results.ResultsWriter.set_replay`) naming the concrete scenario that was
simulated (``replay.toml``: random draws resolved). Results written before that record existed,
and hardware runs, are refused with one line.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import robots
from compare.analysis.results import (
    REPLAY_FORMAT,
    RUNS_DIR,
    SUMMARY_FILE,
    is_sweep_dir,
    load_steps,
    load_summary,
)
from compare.config import Config, ConfigError, parse_config
from compare.replay.exceptions import ReplayError
from compare.sensing.person import Person
from tpik.hierarchy import Hierarchy
from tpik.tasks import ObstacleDistanceTask, SetTask, Thresholds

STATUS_CODES = {"ok": 0, "degraded": 1, "failed": 2}
"""Step status as a number (time series): 0 ok, 1 degraded, 2 failed."""


@dataclass(frozen=True)
class MethodRun:
    """One method's recorded run.

    Attributes:
        name: Method key (``tpik``, ``hqp-daqp``, ``mink``, ...).
        steps: The per-step table (:mod:`compare.analysis.metrics` lists its columns).
        t: Step times [s]. Shape (N,).
        q: Measured joint positions [rad]. Shape (N, n).
    """

    name: str
    steps: pd.DataFrame
    t: np.ndarray
    q: np.ndarray

    def rows_at(self, times: np.ndarray | Sequence[float]) -> np.ndarray:
        """Index of the step shown at each of ``times`` [s]: the last one at or before it. Shape (T,)."""
        k = np.searchsorted(self.t, np.asarray(times, dtype=float) + 1e-9, side="right") - 1
        return np.clip(k, 0, len(self.t) - 1)

    def column(self, name: str, default: float = math.nan) -> np.ndarray:
        """Column ``name`` as float64 (``default`` everywhere when the table has none). Shape (N,)."""
        if name not in self.steps.columns:
            return np.full(len(self.t), default)
        return pd.to_numeric(self.steps[name], errors="coerce").to_numpy(dtype=float)

    def status_codes(self) -> np.ndarray:
        """Step status as :data:`STATUS_CODES` (NaN for an unknown word). Shape (N,)."""
        if "status" not in self.steps.columns:
            return np.zeros(len(self.t))
        return self.steps["status"].map(STATUS_CODES).to_numpy(dtype=float)


@dataclass(frozen=True)
class ReplayRun:
    """A finished run ready to be redrawn.

    Attributes:
        run_dir: The run directory.
        summary: Its ``summary.json``.
        config: The concrete scenario that was simulated.
        robot: The arm.
        hierarchy: The scenario's task hierarchy (thresholds of the set tasks).
        methods: The methods replayed, in the summary's order.
        t_from: Start of the replayed window [s].
        t_to: End of the replayed window [s].
    """

    run_dir: Path
    summary: dict[str, Any]
    config: Config
    robot: robots.Robot
    hierarchy: Hierarchy
    methods: tuple[MethodRun, ...]
    t_from: float
    t_to: float

    @property
    def set_tasks(self) -> tuple[SetTask, ...]:
        """The set-based tasks, highest level first."""
        return self.hierarchy.set_tasks

    @property
    def control_points(self) -> tuple[str, ...]:
        """Frames whose obstacle distance the run recorded (``dist_meas:<frame>`` columns)."""
        for name in (m.name for m in self.methods):
            recorded = (self.summary["methods"].get(name) or {}).get("control_points")
            if recorded:
                return tuple(str(f) for f in recorded)
        frames = [t.frame for t in self.set_tasks if isinstance(t, ObstacleDistanceTask)]
        return tuple(dict.fromkeys(frames)) or tuple(self.robot.control_points)

    def obstacle_thresholds(self) -> dict[str, Thresholds]:
        """Thresholds of the obstacle task of each control point that has one, by frame."""
        return {t.frame: t.thresholds for t in self.set_tasks if isinstance(t, ObstacleDistanceTask)}

    def person(self) -> Person:
        """The scripted person of the scenario, in the robot's work cell."""
        sc = self.config.scenario
        return Person(self.robot.workcell_model(), self.config.person.keyframes, time_scale=sc.time_scale)

    @property
    def depth_sensing(self) -> bool:
        """Whether the run sensed the person with depth cameras."""
        return self.config.scenario.sensing == "depth"


def resolve_run_dir(path: Path, seed: int | None = None) -> Path:
    """The run directory named by ``path``: a run directory, or the run of ``seed`` in a sweep.

    Raises:
        ReplayError: No such directory, a sweep without ``seed``, no run of ``seed``, or a run
            of another seed.
    """
    path = Path(path)
    if not path.is_dir():
        raise ReplayError(f"{path}: no such results directory")
    if (path / SUMMARY_FILE).is_file() and not (path / RUNS_DIR).is_dir():
        if seed is not None:
            recorded = _read_json(path / SUMMARY_FILE).get("seed")
            if recorded != seed:
                raise ReplayError(f"{path} is a run of seed {recorded}, not {seed}")
        return path
    if not is_sweep_dir(path):
        raise ReplayError(f"{path}: neither a run (summary.json) nor a sweep (runs/) directory")
    seeds: dict[int, Path] = {}
    for run_dir in sorted(p for p in (path / RUNS_DIR).glob("*") if p.is_dir()):
        recorded = _read_json(run_dir / SUMMARY_FILE).get("seed")
        if isinstance(recorded, int):
            seeds.setdefault(recorded, run_dir)
    span = f"seeds {min(seeds)}–{max(seeds)}" if seeds else "no finished run"
    if seed is None:
        raise ReplayError(f"{path} is a sweep of {len(seeds)} runs ({span}): give --seed")
    if seed not in seeds:
        raise ReplayError(f"no run of seed {seed} in the sweep {path} ({span})")
    return seeds[seed]


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def load_run(
    path: Path,
    methods: Sequence[str] | None = None,
    seed: int | None = None,
    t_from: float | None = None,
    t_to: float | None = None,
) -> ReplayRun:
    """Load a run (or a sweep's run of ``seed``) for replay.

    Args:
        path: A run directory, or a sweep directory with ``seed``.
        methods: Methods to replay (default every finished one, in the summary's order).
        seed: Scenario seed of the run (required for a sweep).
        t_from: Start of the window [s] (default 0).
        t_to: End of the window [s] (default the end of the run; later values are clipped).

    Raises:
        ReplayError: One line: see :func:`resolve_run_dir`; results without a replay record;
            an unknown method; an empty window.
    """
    run_dir = resolve_run_dir(Path(path), seed)
    summary = load_summary(run_dir)
    config = _scenario(run_dir, summary)
    robot = config.load_robot()
    available = [str(m) for m in summary.get("methods") or {}]
    picked = list(dict.fromkeys(methods)) if methods else available
    unknown = [m for m in picked if m not in available]
    if unknown:
        raise ReplayError(
            f"no results of method {', '.join(unknown)} in {run_dir} (available: {', '.join(available) or 'none'})"
        )
    if not picked:
        raise ReplayError(f"{run_dir} holds no finished method to replay")
    runs = tuple(_method_run(run_dir, name, robot.nq) for name in picked)
    end = max(float(r.t[-1]) + config.scenario.dt for r in runs)
    start = 0.0 if t_from is None else float(t_from)
    stop = end if t_to is None else min(float(t_to), end)
    if not 0.0 <= start < stop:
        raise ReplayError(f"empty window {start:g}–{stop:g} s (--from, --to): the run spans 0–{end:g} s")
    hierarchy = config.build_hierarchy(robot)
    return ReplayRun(run_dir, summary, config, robot, hierarchy, runs, start, stop)


def _scenario(run_dir: Path, summary: dict[str, Any]) -> Config:
    """The concrete scenario of the replay record; raises :class:`ReplayError`."""
    record = summary.get("replay")
    if not isinstance(record, dict) or "format" not in record:
        raise ReplayError(
            f"{run_dir} has no replay record (results written before tpik-compare recorded one, "
            "or a hardware run): run the scenario again to replay it"
        )
    if int(record["format"]) > REPLAY_FORMAT:
        raise ReplayError(
            f"{run_dir}: replay record format {record['format']} is newer than this tpik-compare reads "
            f"({REPLAY_FORMAT}); update tpik-compare"
        )
    path = run_dir / str(record.get("scenario_file"))
    try:
        return parse_config(tomllib.loads(path.read_text(encoding="utf-8")))
    except OSError:
        raise ReplayError(f"{path}: the replay record's scenario file is missing") from None
    except (tomllib.TOMLDecodeError, ConfigError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ReplayError(f"{path}: unreadable scenario ({first})") from None


def _method_run(run_dir: Path, name: str, nq: int) -> MethodRun:
    try:
        steps = load_steps(run_dir, name)
    except FileNotFoundError as exc:
        raise ReplayError(str(exc)) from None
    missing = [c for c in ("t", *(f"q_{i}" for i in range(1, nq + 1))) if c not in steps.columns]
    if missing or steps.empty:
        what = f"lacks {', '.join(missing)}" if missing else "is empty"
        raise ReplayError(f"{run_dir}: the per-step table of {name} {what}")
    t = steps["t"].to_numpy(dtype=float)
    q = steps[[f"q_{i}" for i in range(1, nq + 1)]].to_numpy(dtype=float)
    return MethodRun(name, steps, t, q)
