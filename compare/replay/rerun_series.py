"""The time series of a replay recording: distances and thresholds, activation, status, solve time.

Entities (``plots/...``) are listed in :mod:`compare.replay.recording`; every series is on the
one timeline :data:`TIMELINE` [s].
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import rerun as rr

from compare.replay.run_data import MethodRun, ReplayRun

TIMELINE = "time"
METHOD_COLOURS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75))
"""Colour of each method's series, in the order replayed (matplotlib's tab10)."""


def time_column(t: np.ndarray) -> list[rr.TimeColumn]:
    """The index of ``send_columns``: times [s] on :data:`TIMELINE`."""
    return [rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float))]


def _scalars(
    rec: rr.RecordingStream, path: str, t: np.ndarray, values: np.ndarray, name: str, colour: Iterable[int]
) -> None:
    values = np.where(np.isfinite(values), values, np.nan)
    rec.log(path, rr.SeriesLines(names=[name], colors=[list(colour)]), static=True)
    rec.send_columns(path, indexes=time_column(t), columns=rr.Scalars.columns(scalars=values))


def log_series(
    rec: rr.RecordingStream, run: ReplayRun, method: MethodRun, rows: np.ndarray, colour: tuple[int, int, int]
) -> None:
    """Distances, activation, status and solve time of one method."""
    t, name = method.t[rows], method.name
    faint = tuple(int(0.55 * c + 0.45 * 255) for c in colour)
    for frame in run.control_points:
        base = f"plots/distance/{frame}/{name}"
        _scalars(rec, f"{base}/measured", t, method.column(f"dist_meas:{frame}")[rows], f"{name} measured", colour)
        _scalars(rec, f"{base}/true", t, method.column(f"dist_true:{frame}")[rows], f"{name} true", faint)
    for task in run.set_tasks:
        column = f"active:{task.name}"
        if column in method.steps.columns:
            on = method.steps[column].fillna(False).to_numpy(dtype=float)[rows]
            _scalars(rec, f"plots/active/{name}/{task.name}", t, on, task.name, colour)
    _scalars(rec, f"plots/status/{name}", t, method.status_codes()[rows], name, colour)
    _scalars(rec, f"plots/solve_time_us/{name}", t, method.column("solve_time_us")[rows], name, colour)


def log_thresholds(rec: rr.RecordingStream, run: ReplayRun) -> None:
    """Each control point's thresholds as constant lines over the window."""
    ends = np.array([run.t_from, run.t_to])
    for frame, th in run.obstacle_thresholds().items():
        levels = {
            "physical": (th.physical_lower, (120, 0, 0)),
            "safety": (th.safety_lower, (230, 30, 25)),
            "activation": (th.safety_lower + th.activation_margin, (255, 160, 15)),
        }
        for level, (value, colour) in levels.items():
            if math.isfinite(value):
                _scalars(rec, f"plots/distance/{frame}/{level}", ends, np.full(2, value), level, colour)
