"""A witness run: a policy that knows the person's future drives the run's plant, judged by the methods' metrics.

A witness is named by its policy and look-ahead: ``oracle-<T>s`` is the clairvoyant
receding-horizon optimiser with horizon T (:mod:`compare.campaign.oracle`), ``preview-<τ>s``
the greedy preview policy with preview τ (:mod:`compare.campaign.preview`). It drives the same
plant as the methods (simulation mode, joint drive, control period) through
:func:`compare.loop.closed_loop.run_loop`, senses nothing, and its run is scored by
:func:`compare.analysis.metrics.compute_summary` on the ground-truth distances, as every
method's. It *held* when no obstacle, joint-limit or wall safety threshold was passed by more than
the metrics' tolerance (:data:`compare.analysis.metrics.VIOLATION_TOLERANCE`) over the whole
run: then a motion within the robot's limits that keeps every threshold exists, on this plant.
A witness that did not hold proves nothing.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import robots
from compare.analysis.atomic_files import write_json_atomic
from compare.analysis.metrics import VIOLATION_TOLERANCE, compute_summary, to_jsonable
from compare.campaign.oracle import ClairvoyantOracle
from compare.campaign.preview import PreviewPolicy, PreviewSettings
from compare.config import Config, WitnessSpec
from compare.loop.closed_loop import run_loop
from compare.loop.simulation import build_simulation
from compare.run import loop_setup, run_meta
from compare.sensing.person_track import PersonTrack
from robots import Kinematics
from tpik.tasks import ObstacleDistanceTask

WITNESS_VERSION = 2
"""Bumped whenever a witness's formulation or its judgement changes: part of the cache key."""


@dataclass
class WitnessRun:
    """One witness on one scenario.

    Attributes:
        entry: ``held``, ``min_distance_m``, the three groups' worst safety margins, ``stopped_early``,
            ``wall_time_s``, ``key``, ``cached``.
        steps: The per-step table (None when read from a cache).
    """

    entry: dict[str, Any]
    steps: pd.DataFrame | None = None


def witness_key(config: Config, robot: robots.Robot, spec: WitnessSpec) -> str:
    """Cache key of a witness on a *realized* scenario: everything its result depends on."""
    sc = config.scenario
    oracle = config.oracle.model_dump(
        mode="json", include={"knot_s", "replan_period_s", "sqp_iterations", "trust_region_rad_s", "secondary_weight"}
    )
    data = {
        "version": WITNESS_VERSION,
        "witness": spec.name,
        "robot": robot.name,
        "scenario": {
            k: getattr(sc, k)
            for k in ("duration_s", "time_scale", "control_rate_hz", "simulation", "drive", "drive_bandwidth_rad_s")
        },
        "start_q": sc.start_q,
        "person": [f.model_dump(mode="json") for f in config.person.keyframes],
        "levels": config.hierarchy_description(),
        "settings": {"margin_cap_m": config.oracle.margin_cap_m, "solver": config.oracle.solver}
        | (oracle if spec.policy == "oracle" else {}),
    }
    text = json.dumps(to_jsonable(data), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def run_witness(config: Config, robot: robots.Robot, spec: WitnessSpec, stop_at_violation: bool = False) -> WitnessRun:
    """Drive the plant of ``config`` (realized) with the witness ``spec`` for the whole run.

    Args:
        config: A realized scenario (scripted, or random after
            :func:`compare.scenarios.random_scenario.realize`).
        robot: The arm.
        spec: Which witness.
        stop_at_violation: Stop at the first safety threshold passed (by more than the metrics'
            tolerance): enough to know it did not hold.
    """
    start = time.perf_counter()
    sc = config.scenario.model_copy(update={"sensing": "geometric"})  # a witness senses nothing
    config = config.model_copy(update={"scenario": sc})
    hierarchy = config.build_hierarchy(robot)
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    sim = build_simulation(config, robot, q0)
    track = PersonTrack.from_person(sim.person, sc.sim_time_s + spec.look_ahead_s + 1.0, sc.dt)
    policy: ClairvoyantOracle | PreviewPolicy
    if spec.policy == "oracle":
        policy = ClairvoyantOracle(robot, hierarchy, track, config.oracle, sim.io.now, horizon_s=spec.look_ahead_s)
    else:
        settings = PreviewSettings(
            preview_s=spec.look_ahead_s, margin_cap_m=config.oracle.margin_cap_m, solver=config.oracle.solver
        )
        policy = PreviewPolicy(robot, hierarchy, track, settings, sim.io.now, name=spec.name)
    schedule, loop_settings = loop_setup(config, robot.frame_position(q0, robot.ee_frame))
    bounds = [(t, t.thresholds.safety_lower, t.thresholds.safety_upper) for t in hierarchy.set_tasks]
    obstacles = {t.frame: t.thresholds.safety_lower for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)}
    state = {"worst": math.inf}

    def truth(kin: Kinematics) -> dict[str, float]:
        d = sim.truth(kin)
        if stop_at_violation:
            worst = min((d.get(frame, math.inf) - thr for frame, thr in obstacles.items()), default=math.inf)
            for task, lo, hi in bounds:
                if not isinstance(task, ObstacleDistanceTask):
                    sigma = float(task.compute_value_and_jacobian(kin)[0])
                    worst = min(worst, sigma - lo, hi - sigma)
            state["worst"] = min(state["worst"], worst)
        return d

    def keep_going() -> bool:
        return state["worst"] >= -VIOLATION_TOLERANCE

    try:
        out = run_loop(sim.io, robot, hierarchy, policy, schedule, loop_settings, None, truth, on_step=keep_going)
    finally:
        sim.close()
    summary = compute_summary(out.steps, run_meta(config, spec.name, hierarchy, robot, out, "none (clairvoyant)"))
    stopped = out.sim_time_s < sc.sim_time_s - 1.5 * sc.dt
    groups = {g: summary.get(g) or {} for g in ("obstacles", "joint_limits", "walls")}
    dists = [d for d in summary["min_obstacle_distance_m"] if d is not None]
    entry = {
        "witness": spec.name,
        "held": not stopped and not any(group.get("violations") for group in groups.values()),
        "min_distance_m": min(dists) if dists else None,
        "min_distance_per_control_point_m": dict(
            zip(summary["control_points"], summary["min_obstacle_distance_m"], strict=True)
        ),
        "obstacles_margin_min": groups["obstacles"].get("safety_margin_min"),
        "joint_limits_margin_min": groups["joint_limits"].get("safety_margin_min"),
        "walls_margin_min": groups["walls"].get("safety_margin_min"),
        "stopped_early": stopped,
        "sim_time_s": out.sim_time_s,
        "wall_time_s": time.perf_counter() - start,
        **policy.stats(),
        "key": witness_key(config, robot, spec),
    }
    return WitnessRun(to_jsonable(entry), out.steps)


def cached_witness(
    config: Config, robot: robots.Robot, spec: WitnessSpec, cache_dir: Path | None, stop_at_violation: bool = False
) -> WitnessRun:
    """:func:`run_witness`, read from ``cache_dir/<key>.json`` when it was computed before.

    A run that stopped at its first violation is reused only by a caller that also accepts a
    stopped run (both say ``held = false``; the full run has the true minimum distance).
    """
    key = witness_key(config, robot, spec)
    path = None if cache_dir is None else Path(cache_dir) / f"{key}.json"
    if path is not None and path.is_file():
        try:
            entry = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            entry = None
        if isinstance(entry, dict) and (stop_at_violation or not entry.get("stopped_early")):
            entry["cached"] = True
            return WitnessRun(entry)
    result = run_witness(config, robot, spec, stop_at_violation)
    result.entry["cached"] = False
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, {k: v for k, v in result.entry.items() if k != "cached"})
        if config.oracle.keep_steps and result.steps is not None:
            result.steps.to_parquet(path.with_suffix(".parquet"), index=False)
    return result
