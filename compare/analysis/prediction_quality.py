r"""How good the person's predicted motion was: the closing speeds the obstacle tasks received against the truth.

For a run with ``[prediction]`` each control point's step table holds the predicted closing speed
of its closest obstacle point (``closing_pred:<cp>``, :mod:`compare.sensing.prediction`). The true
one is the rate at which the person's surface comes toward the control point held where it is,

.. math:: v_c(t) = -\frac{d(P, t + h) - d(P, t - h)}{2h},\qquad v_c^+ = \max(0, v_c),

from the scenario's keyframes (which the estimate never sees), over the steps where the
prediction saw something. Reported per method and control point: the median and RMS error of
the estimate against :math:`v_c^+`, its bias, and its latency: the delay ℓ ∈ [0, 0.3] s that
minimises the RMS error between the estimate at t and the truth at t − ℓ. The same median error
and bias over the steps where the person truly closes in faster than
:data:`CLOSING_MPS` (``closing_*``): most steps have nothing coming, where both are 0.
``python -m compare.analysis.prediction_quality RUN_OR_SWEEP_DIR [--runs N]`` prints them (the
first N runs of a sweep).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from compare.analysis.results import RUNS_DIR, SUMMARY_FILE, load_steps, run_dirs
from compare.arguments import ArgumentParser, existing_dir, positive_int
from compare.config import Config, load_config
from compare.scenarios.random_scenario import realize
from compare.sensing.person import Person
from compare.sensing.person_track import PersonTrack, capsule_margins
from compare.sensing.scene import load_workcell
from robots import Robot

MAX_LATENCY_S = 0.3
"""Largest delay searched for the latency [s]."""
CLOSING_MPS = 0.2
"""True closing speed above which a step counts as the person closing in [m/s]."""


def true_closing(track: PersonTrack, points: np.ndarray, t: np.ndarray, half_window_s: float = 0.02) -> np.ndarray:
    """:math:`v_c` of fixed points ``points`` (T, 3) at times ``t`` (T,) [m/s] (module docstring)."""

    def dist(tt: np.ndarray) -> np.ndarray:
        a, b, r = track.at(tt)
        return capsule_margins(points[:, None, :], a, b, r)[0][:, 0, :].min(axis=1)

    return (dist(t - half_window_s) - dist(t + half_window_s)) / (2.0 * half_window_s)


def run_track(run_dir: Path) -> tuple[Config, Robot, PersonTrack]:
    """The realized config, the arm and the person's track of a run directory."""
    summary = json.loads((run_dir / SUMMARY_FILE).read_text(encoding="utf-8"))
    config, _ = load_config(run_dir / "config.toml", {"scenario.seed": int(summary.get("seed", 0))})
    robot = config.load_robot()
    config = realize(config, robot, draw=int((summary.get("oracle") or {}).get("draw") or 0))
    sc = config.scenario
    person = Person(load_workcell(robot.name), config.person.keyframes, time_scale=sc.time_scale)
    return config, robot, PersonTrack.from_person(person, sc.sim_time_s + 1.0, sc.dt)


def true_closing_of_steps(steps: pd.DataFrame, robot: Robot, track: PersonTrack, cp: str) -> np.ndarray:
    """:math:`v_c^+` of control point ``cp`` at every recorded step [m/s]."""
    t = steps["t"].to_numpy(dtype=float)
    q = steps[[f"q_{j + 1}" for j in range(robot.nq)]].to_numpy(dtype=float)
    points = np.array([robot.kinematics(qk).frame_position(cp) for qk in q])
    return np.maximum(true_closing(track, points, t), 0.0)


def estimate_errors(estimate: np.ndarray, truth: np.ndarray, dt: float) -> dict[str, float]:
    """Median and RMS error, bias and latency of ``estimate`` against ``truth`` where the estimate is finite."""
    ok = np.isfinite(estimate) & np.isfinite(truth)
    if ok.sum() < 10:
        return {"samples": int(ok.sum())}
    err = estimate[ok] - truth[ok]
    best_lag, best_rms = 0, float("inf")
    for lag in range(int(round(MAX_LATENCY_S / dt)) + 1):
        a, b = estimate[lag:], truth[: len(truth) - lag]
        m = np.isfinite(a) & np.isfinite(b)
        if m.sum() < 10:
            break
        rms = float(np.sqrt(np.mean((a[m] - b[m]) ** 2)))
        if rms < best_rms - 1e-12:
            best_lag, best_rms = lag, rms
    closing = truth[ok] > CLOSING_MPS
    return {
        "samples": int(ok.sum()),
        "closing_samples": int(closing.sum()),
        "closing_median_abs_error_mps": float(np.median(np.abs(err[closing]))) if closing.any() else np.nan,
        "closing_bias_mps": float(np.mean(err[closing])) if closing.any() else np.nan,
        "median_abs_error_mps": float(np.median(np.abs(err))),
        "rms_error_mps": float(np.sqrt(np.mean(err**2))),
        "bias_mps": float(np.mean(err)),
        "latency_s": best_lag * dt,
    }


def quality_run(run_dir: Path) -> list[dict[str, Any]]:
    """One row per (method, control point) of a run with prediction (none without)."""
    run_dir = Path(run_dir)
    summary = json.loads((run_dir / SUMMARY_FILE).read_text(encoding="utf-8"))
    config, robot, track = run_track(run_dir)
    rows: list[dict[str, Any]] = []
    for method in summary.get("methods") or {}:
        steps = load_steps(run_dir, method)
        for col in [c for c in steps.columns if c.startswith("closing_pred:")]:
            cp = col.split(":", 1)[1]
            truth = true_closing_of_steps(steps, robot, track, cp)
            estimate = steps[col].to_numpy(dtype=float)
            estimate = np.where(np.isfinite(steps[f"dist_pred:{cp}"].to_numpy(dtype=float)), estimate, np.nan)
            errors = estimate_errors(estimate, truth, config.scenario.dt)
            rows.append({"run": run_dir.name, "method": method, "control_point": cp, **errors})
    return rows


def quality(directory: Path, max_runs: int | None = None) -> pd.DataFrame:
    """:func:`quality_run` for a run directory or the first ``max_runs`` runs of a sweep directory."""
    return pd.DataFrame([row for run in run_dirs(directory, max_runs) for row in quality_run(run)])


def main(argv: list[str] | None = None) -> int:
    """Print the errors per run, method and control point, then their medians per method."""
    parser = ArgumentParser(
        prog="python -m compare.analysis.prediction_quality",
        description="The predicted closing speeds [m/s] against the person's true ones: median and RMS error,\n"
        "bias [m/s] and latency [s] per run, method and control point, then their medians per method.",
    )
    parser.add_argument(
        "directory", type=existing_dir, help="a run directory (summary.json) or a sweep directory (runs/)"
    )
    parser.add_argument(
        "--runs", type=positive_int, default=None, metavar="N", help="only the first N runs of a sweep (default: all)"
    )
    args = parser.parse_args(argv)
    directory = args.directory
    if not (directory / SUMMARY_FILE).is_file() and not (directory / RUNS_DIR).is_dir():
        parser.error(f"{directory} is neither a run (summary.json) nor a sweep (runs/) directory")
    frame = quality(directory, args.runs)
    if frame.empty or "median_abs_error_mps" not in frame.columns:
        print("no run with prediction (closing_pred columns)")
        return 0
    print(frame.round(3).to_string(index=False))
    cols = [
        "median_abs_error_mps",
        "rms_error_mps",
        "bias_mps",
        "latency_s",
        "closing_median_abs_error_mps",
        "closing_bias_mps",
    ]
    print("\nmedian over runs and control points:")
    print(frame.groupby("method")[cols].median().round(3).to_string())
    return 0


if __name__ == "__main__":
    sys.exit(main())
