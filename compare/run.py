"""Run one scenario with every selected method and write the results (DESIGN §5–7)."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

import robots
from compare.analysis import iso15066
from compare.analysis.avoidability import split_obstacle_violations
from compare.analysis.metrics import RunMeta, SetTaskInfo, compute_summary
from compare.analysis.results import ResultsWriter
from compare.campaign.random_scenario import realize
from compare.config import Config
from compare.loop.closed_loop import LoopSettings, ObstacleSource, run_loop
from compare.loop.faults import FaultInjector, unsafe_commands
from compare.loop.simulation import build_simulation
from compare.loop.waypoints import WaypointSchedule
from compare.methods import make_method
from tpik.hierarchy import Hierarchy
from tpik.tasks import JointLimitTask, ObstacleDistanceTask, VirtualWallTask

log = logging.getLogger(__name__)


def set_task_infos(hierarchy: Hierarchy) -> tuple[SetTaskInfo, ...]:
    """Group and thresholds of every set-based task, for the metrics."""
    infos = []
    for task in hierarchy.set_tasks:
        if isinstance(task, JointLimitTask):
            group = "joint_limits"
        elif isinstance(task, VirtualWallTask):
            group = "walls"
        elif isinstance(task, ObstacleDistanceTask):
            group = "obstacles"
        else:
            group = "other"
        th = task.thresholds
        infos.append(
            SetTaskInfo(task.name, group, th.physical_lower, th.safety_lower, th.safety_upper, th.physical_upper)
        )
    return tuple(infos)


def loop_setup(
    config: Config, ee0: np.ndarray, duration_s: float | None = None
) -> tuple[WaypointSchedule, LoopSettings]:
    """Waypoint schedule and loop settings of a scenario (simulation, viewer and hardware alike).

    Args:
        config: The (realized) scenario.
        ee0: EE position at the start [m] (the target when there are no waypoints).
        duration_s: Run time [s]; default the scenario's scaled duration.
    """
    sc = config.scenario
    wp = config.waypoints
    schedule = WaypointSchedule(wp.positions, ee0, wp.tolerance_m, wp.dwell_s * sc.time_scale, wp.cycle)
    settings = LoopSettings(
        dt=sc.dt,
        duration_s=sc.sim_time_s if duration_s is None else duration_s,
        sensing_period_s=1.0 / sc.sensing_rate_hz,
        fallback=sc.fallback,
        fallback_decay_s=sc.fallback_decay_s,
        max_sensing_age_s=config.sensor.max_age_s,
    )
    return schedule, settings


def write_plots(out_dir: Path) -> None:
    """Draw the run's plots; a plotting error is logged and never loses the results."""
    try:
        from compare.analysis.plots import plot_run

        plot_run(Path(out_dir))
    except Exception as exc:  # plots must never lose the results
        log.warning("plots failed: %s", exc)


def run_method(config: Config, method: str, robot: robots.Robot, progress: Progress | None = None) -> dict[str, Any]:
    """Simulate ``config`` (already realized) with one method; return summary and steps."""
    hierarchy = config.build_hierarchy(robot)
    solver = make_method(method, robot, config.methods.settings.get(method))
    sc = config.scenario
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    sim = build_simulation(config, robot, q0)
    schedule, settings = loop_setup(config, robot.frame_position(q0, "end_effector"))
    task_id = None
    callback = None
    if progress is not None:
        task_id = progress.add_task(method, total=sc.sim_time_s)

        def callback(t: float) -> None:
            progress.update(task_id, completed=t)

    # Faults (``[faults]``) and the ISO/TS 15066 monitor wrap the backend, the sensing and the solver.
    injector = FaultInjector(config.faults, sc.seed, sc.time_scale, sim.io.now, config.sensor.blind_fraction, sc.dt)
    io = injector.wrap_io(sim.io)
    obstacles: ObstacleSource = sim.obstacles
    if sim.pipeline is not None and io is not sim.io:
        obstacles = sim.pipeline.source(io.read_depth)  # depth mode: the pipeline reads the faulty frames
    elif sim.pipeline is None:
        obstacles = injector.wrap_obstacles(obstacles)  # geometric mode: frame faults emulated
    solver = injector.wrap_solver(solver)
    stale_after_s = (
        None if settings.stale_frame_periods is None else settings.stale_frame_periods * settings.sensing_period_s
    )
    monitor = iso15066.SeparationMonitor(obstacles, stale_after_s) if config.iso15066.enabled else None
    try:
        out = run_loop(io, robot, hierarchy, solver, schedule, settings, monitor or obstacles, sim.truth, callback)
    finally:
        sim.close()
    if progress is not None and task_id is not None:
        progress.update(task_id, completed=sc.sim_time_s)
    steps = injector.annotate(out.steps)
    if monitor is not None:
        steps = pd.concat([steps, monitor.margins(steps, robot, config.iso15066)], axis=1)
    meta = RunMeta(
        scenario=sc.name,
        seed=sc.seed,
        method=method,
        dt=sc.dt,
        sim_time_s=out.sim_time_s,
        wall_time_s=out.wall_time_s,
        sensing=sc.sensing,
        set_tasks=set_task_infos(hierarchy),
    )
    summary = compute_summary(steps, meta)
    summary["faults"] = injector.summarize(steps, settings.sensing_period_s)
    summary["unsafe_commands"] = unsafe_commands(steps, robot.v_max)
    if monitor is not None:
        summary["iso15066"] = iso15066.summarize(steps, sc.dt, config.iso15066)
    summary["sensing"] = sc.sensing
    summary["events"] = out.events[:50]
    return {"summary": summary, "steps": steps}


def run_scenario(
    config: Config,
    out_dir: Path,
    config_text: str | None = None,
    progress: bool = True,
    make_plots: bool = True,
) -> dict[str, Any]:
    """Run every method of ``config`` on the same scenario; results survive a crash of one method.

    Returns:
        The content of ``out_dir/summary.json``.
    """
    robot = robots.load("jaco2")
    config, oracle = _realize_with_oracle(config, robot, Path(out_dir))
    sc = config.scenario
    writer = ResultsWriter(Path(out_dir), sc.name, sc.seed, sc.sim_time_s, config_text)
    if oracle is not None:
        writer.set_run_info("oracle", oracle)
    columns = (
        TextColumn("[bold]{task.description:<12}"),
        BarColumn(),
        TextColumn("{task.completed:5.1f}/{task.total:.0f} s"),
        TimeElapsedColumn(),
    )
    bar = Progress(*columns, disable=not progress)
    with bar:
        for method in config.methods.names:
            t0 = time.perf_counter()
            try:
                result = run_method(config, method, robot, bar if progress else None)
            except Exception as exc:  # record and go on: the other methods' results are kept
                log.exception("method %s failed", method)
                writer.add_error(method, f"{type(exc).__name__}: {exc}")
                continue
            if oracle is not None:
                result["summary"]["obstacle_violations"] = split_obstacle_violations(result["summary"], oracle)
            writer.add_method(method, result["summary"], result["steps"])
            log.info("%s done in %.1f s", method, time.perf_counter() - t0)
    if make_plots:
        write_plots(Path(out_dir))
    return writer.summary


ORACLE_CACHE_DIR = "oracle"
"""Sub-directory of a run directory caching its oracle runs (``<key>.json``)."""


def _realize_with_oracle(config: Config, robot: robots.Robot, out_dir: Path) -> tuple[Config, dict[str, Any] | None]:
    """The concrete scenario and, with ``[oracle] enabled``, its oracle entry (cached in ``out_dir``)."""
    if not config.oracle.enabled:
        return realize(config, robot), None
    from compare.campaign.oracle import cached_oracle

    cache = out_dir / ORACLE_CACHE_DIR
    if config.oracle.avoidable_only and config.scenario.kind == "random":
        from compare.campaign.avoidable import realize_avoidable

        config, run = realize_avoidable(config, robot, cache)
    else:
        config = realize(config, robot)
        run = cached_oracle(config, robot, cache)
    return config, run.entry


def view_scenario(config: Config, method: str) -> None:
    """Run one method in the interactive MuJoCo viewer, in real time."""
    import mujoco.viewer

    robot = robots.load("jaco2")
    config = realize(config, robot)
    sc = config.scenario
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    sim = build_simulation(config, robot, q0)
    hierarchy = config.build_hierarchy(robot)
    solver = make_method(method, robot, config.methods.settings.get(method))
    schedule, settings = loop_setup(config, robot.frame_position(q0, "end_effector"))
    with mujoco.viewer.launch_passive(sim.io.model, sim.io.data) as viewer:
        clock = {"tick": time.perf_counter()}

        def sync() -> bool:
            viewer.sync()
            time.sleep(max(0.0, sc.dt - (time.perf_counter() - clock["tick"])))
            clock["tick"] = time.perf_counter()
            return viewer.is_running()

        run_loop(sim.io, robot, hierarchy, solver, schedule, settings, sim.obstacles, sim.truth, on_step=sync)
    sim.close()
