r"""Why an obstacle violation happened: the person's closing speed against the task's gain.

A velocity-level set-based obstacle task with gain K asks the control point for
:math:`\dot\sigma = K(\sigma_s - \sigma)` once it acts (TPIK inserts it with the safety threshold
as its target, eq. 7; HQP bounds :math:`J\dot q \ge -K(\sigma - \sigma_s)`), with no feed-forward of
the obstacle's motion. If the person's closest point comes at speed v, the distance then settles
at :math:`\sigma_s - v/K`: a violation of about :math:`v/K` that no solver of that formulation can
avoid, however fast the arm could retreat.

For every violation episode of every method in a run, :func:`explain_run` gives the person's
closing speed toward the control point when the episode starts (the control point frozen where
it is, the person's capsules from the scenario's keyframes), the predicted undershoot v/K, the
measured worst margin of the episode, and whether the clairvoyant oracle held the threshold in
that run. ``python -m compare.analysis.violations SWEEP_OR_RUN_DIR`` prints them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from compare.analysis.metrics import VIOLATION_TOLERANCE
from compare.analysis.results import RUNS_DIR, SUMMARY_FILE, load_steps, run_dirs
from compare.arguments import ArgumentParser, existing_dir
from compare.config import load_config
from compare.scenarios.random_scenario import realize
from compare.sensing.person import Person
from compare.sensing.person_track import PersonTrack, capsule_margins
from compare.sensing.scene import load_workcell
from tpik.tasks import ObstacleDistanceTask


def closing_speed(track: Any, point: np.ndarray, t: float, half_window_s: float = 0.05) -> float:
    """Speed at which the person's surface comes toward a fixed ``point`` at time ``t`` [m/s]."""

    def dist(tt: float) -> float:
        return float(capsule_margins(point[None, :], *track.at(tt))[0].min())

    return (dist(t - half_window_s) - dist(t + half_window_s)) / (2.0 * half_window_s)


def _episodes(margin: np.ndarray) -> list[tuple[int, int]]:
    """(first, last + 1) step indices of the runs where ``margin`` < −tolerance."""
    bad = np.nan_to_num(margin, nan=0.0) < -VIOLATION_TOLERANCE
    edges = np.flatnonzero(np.diff(np.concatenate([[0], bad.astype(int), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def explain_run(run_dir: Path) -> list[dict[str, Any]]:
    """One row per obstacle violation episode of every method of a run (module docstring)."""
    run_dir = Path(run_dir)
    summary = json.loads((run_dir / SUMMARY_FILE).read_text(encoding="utf-8"))
    oracle = summary.get("oracle") or {}
    config, _ = load_config(run_dir / "config.toml", {"scenario.seed": int(summary.get("seed", 0))})
    robot = config.load_robot()
    config = realize(config, robot, draw=int(oracle.get("draw") or 0))
    sc = config.scenario
    person = Person(load_workcell(robot.name), config.person.keyframes, time_scale=sc.time_scale)
    track = PersonTrack.from_person(person, sc.sim_time_s + 1.0, sc.dt)
    tasks = [t for t in config.build_hierarchy(robot).set_tasks if isinstance(t, ObstacleDistanceTask)]
    rows: list[dict[str, Any]] = []
    for method in summary.get("methods") or {}:
        steps = load_steps(run_dir, method)
        t = steps["t"].to_numpy(dtype=float)
        q = steps[[f"q_{j + 1}" for j in range(robot.nq)]].to_numpy(dtype=float)
        for task in tasks:
            col = f"truth:{task.name}"
            if col not in steps.columns:
                continue
            margin = steps[col].to_numpy(dtype=float) - task.thresholds.safety_lower
            for first, end in _episodes(margin):
                point = np.array(robot.kinematics(q[first]).frame_position(task.frame))
                v = closing_speed(track, point, float(t[first]))
                worst = int(first + np.nanargmin(margin[first:end]))
                rows.append(
                    {
                        "run": run_dir.name,
                        "seed": summary.get("seed"),
                        "method": method,
                        "control_point": task.frame,
                        "start_s": float(t[first]),
                        "duration_s": float(t[end - 1] - t[first]) + sc.dt,
                        "worst_margin_m": float(margin[worst]),
                        "closing_speed_mps": v,
                        "predicted_margin_m": -max(v, 0.0) / task.gain,
                        "gain_per_s": task.gain,
                        "oracle_held": oracle.get("held_safety"),
                    }
                )
    return rows


def explain(directory: Path) -> pd.DataFrame:
    """:func:`explain_run` for a run directory or every run of a sweep directory."""
    return pd.DataFrame([row for run in run_dirs(directory) for row in explain_run(run)])


def main(argv: list[str] | None = None) -> int:
    """Print the episodes of a run or sweep directory and how well v/K predicts them."""
    parser = ArgumentParser(
        prog="python -m compare.analysis.violations",
        description="Every obstacle violation episode of a run or sweep: the person's closing speed v [m/s]\n"
        "toward the control point, the predicted undershoot v/K [m] and the measured worst margin [m].",
    )
    parser.add_argument(
        "directory", type=existing_dir, help="a run directory (summary.json) or a sweep directory (runs/)"
    )
    directory = parser.parse_args(argv).directory
    if not (directory / SUMMARY_FILE).is_file() and not (directory / RUNS_DIR).is_dir():
        parser.error(f"{directory} is neither a run (summary.json) nor a sweep (runs/) directory")
    frame = explain(directory)
    if frame.empty:
        print("no obstacle violation")
        return 0
    with pd.option_context("display.width", 200, "display.max_rows", 500):
        print(frame.round(3).to_string(index=False))
    ok = frame[frame["closing_speed_mps"] > 0.02]
    if len(ok) > 1:
        r = float(np.corrcoef(ok["predicted_margin_m"], ok["worst_margin_m"])[0, 1])
        print(f"\n{len(frame)} episodes; closing in at > 2 cm/s: {len(ok)}; correlation(v/K, worst margin) = {r:.2f}")
        ratio = (ok["worst_margin_m"] / ok["predicted_margin_m"]).median()
        print(f"median worst margin / (−v/K): {ratio:.2f}" if math.isfinite(ratio) else "")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
