"""Run one scenario with every selected method and write the results (docs/design.md §5–7)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

import robots
from compare.analysis import iso15066, preflight
from compare.analysis.avoidability import split_obstacle_violations
from compare.analysis.metrics import RunMeta, compute_summary, set_task_infos
from compare.analysis.person_speeds import part_max_speeds
from compare.analysis.results import ResultsWriter
from compare.analysis.run_report import render_run_report
from compare.config import Config, dump_config
from compare.config_hash import config_fingerprint, config_hash, method_settings
from compare.loop.closed_loop import LoopOutput, ObstacleSource, control_points, run_loop, warm_up_solver
from compare.loop.deadline import MeasuredDeadline, guard_solver
from compare.loop.faults import FaultInjector, unsafe_commands
from compare.loop.settings import LoopSettings
from compare.loop.simulation import build_simulation, make_predictor
from compare.loop.warmup import warm_up_process
from compare.loop.waypoints import WaypointSchedule
from compare.methods import make_method
from compare.scenarios.random_scenario import realize
from tpik.hierarchy import Hierarchy
from tpik.tasks import ObstacleDistanceTask

log = logging.getLogger(__name__)


def run_meta(
    config: Config,
    method: str,
    hierarchy: Hierarchy,
    robot: robots.Robot,
    out: LoopOutput,
    sensing: str,
    warmup_steps: int = 0,
) -> RunMeta:
    """What the metrics need besides the per-step table, for a simulated or a hardware run.

    Args:
        config: The (realized) scenario.
        method: Method key.
        hierarchy: The hierarchy the run used (its set tasks' groups and thresholds).
        robot: The arm (the run's control points: :func:`~compare.loop.closed_loop.control_points`).
        out: The loop's output (simulated and wall time).
        sensing: How obstacles were sensed (``depth``, ``geometric``, ``none``).
        warmup_steps: Untimed solves made before the first step (excluded from the timing).
    """
    sc = config.scenario
    return RunMeta(
        scenario=sc.name,
        seed=sc.seed,
        method=method,
        dt=sc.dt,
        sim_time_s=out.sim_time_s,
        wall_time_s=out.wall_time_s,
        sensing=sensing,
        set_tasks=set_task_infos(hierarchy),
        control_points=control_points(hierarchy, robot),
        warmup_steps=warmup_steps,
    )


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
        # Deferred: matplotlib costs ~0.25 s of CPU, and sweep workers, which import this module, never plot.
        from compare.analysis.plots import plot_run

        plot_run(Path(out_dir))
    except Exception as exc:  # plots must never lose the results
        log.warning("plots failed: %s", exc)


def run_method(
    config: Config,
    method: str,
    robot: robots.Robot,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Simulate ``config`` (already realized) with one method; return summary and steps."""
    hierarchy = config.build_hierarchy(robot)
    solver = make_method(method, robot, config.methods.settings.get(method))
    sc = config.scenario
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    sim = build_simulation(config, robot, q0)
    schedule, settings = loop_setup(config, robot.frame_position(q0, robot.ee_frame))
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
        obstacles = sim.depth_source(io)  # depth mode: the pipeline reads the faulty frames
    elif sim.pipeline is None:
        obstacles = injector.wrap_obstacles(obstacles)  # geometric mode: frame faults emulated
    warm_up_process(config, method, robot, q0)  # once per process: kernels loaded, caches built (throwaway copy)
    warmup_steps = warm_up_solver(solver, hierarchy, robot, q0, sc.dt)  # before faults and timing
    inner = injector.wrap_solver(solver)
    # Only with [loop] realtime does a late solve change the run: otherwise it is a function of (config, seed).
    solver = guard_solver(inner, config.solver_limit, sc.dt) if config.loop.realtime else inner
    stale_after_s = (
        None if settings.stale_frame_periods is None else settings.stale_frame_periods * settings.sensing_period_s
    )
    cps = control_points(hierarchy, robot)
    monitor = iso15066.SeparationMonitor(obstacles, stale_after_s, cps) if config.iso15066.enabled else None
    try:
        predictor = make_predictor(config, sim)
        out = run_loop(
            io,
            robot,
            hierarchy,
            solver,
            schedule,
            settings,
            monitor or obstacles,
            sim.truth,
            callback,
            predictor=predictor,
        )
    finally:
        sim.close()
    if progress is not None and task_id is not None:
        progress.update(task_id, completed=sc.sim_time_s)
    steps = injector.annotate(out.steps)
    if monitor is not None:
        known = sim.truth.recorded_points(len(steps)) if sim.truth.frames == monitor.frames else None
        steps = pd.concat([steps, monitor.margins(steps, robot, config.iso15066, known)], axis=1)
    summary = compute_summary(steps, run_meta(config, method, hierarchy, robot, out, sc.sensing, warmup_steps))
    summary["robot"] = robot.name
    summary["faults"] = injector.summarize(steps, settings.sensing_period_s)
    summary["unsafe_commands"] = unsafe_commands(steps, robot.v_max)
    if monitor is not None:
        summary["iso15066"] = iso15066.summarize(steps, sc.dt, config.iso15066, cps)
    summary["sensing"] = sc.sensing
    summary["solver_limit"] = solver_limit_entry(config, realtime=False)
    summary["events"] = out.events[:50]
    summary["solve_worst_us"] = worst_solve_entry(solver, config)
    summary["deadline_steal_excused"] = steal_excused_entry(solver)
    return {"summary": summary, "steps": steps}


def worst_solve_entry(solver: object, config: Config) -> dict[str, Any]:
    """The run's worst steady-state solve on the time limit's clock, for ``summary.json``.

    Every timed step comes after the warm-up (:func:`~compare.loop.warmup.warm_up_process`, then
    :func:`~compare.loop.closed_loop.warm_up_solver`), so this is the worst step after warm-up.
    ``solve_time_us.max`` is the same on the wall clock; on a shared machine the CPU clock (the
    default of ``[solver_limit]``) leaves out the time the process was not running.

    Returns:
        ``{"us": worst [µs] or None when the solver had no time limit, "clock": "cpu" | "wall" | None}``.
    """
    worst = solver.worst_s if isinstance(solver, MeasuredDeadline) else None
    clock = config.solver_limit.simulation_clock if worst is not None else None
    return {"us": None if worst is None else 1e6 * float(worst), "clock": clock}


def steal_excused_entry(solver: object) -> dict[str, Any]:
    """Solves late on the raw CPU clock but kept once the hypervisor's steal was taken out.

    Returns:
        ``{"steps": count or None (no CPU-clock guard with a steal counter), "stolen_s": steal taken out [s]}``.
    """
    guard = solver if isinstance(solver, MeasuredDeadline) else None
    if guard is None or not guard.excludes_steal:
        return {"steps": None, "stolen_s": None}
    return {"steps": guard.steal_excused, "stolen_s": guard.stolen_s}


def solver_limit_entry(config: Config, realtime: bool) -> dict[str, Any]:
    """The time limit a run's solves had, for ``summary.json`` (``time_limit_s`` None = none).

    Args:
        config: The run's config.
        realtime: A hardware run (wall clock, always enforced); in simulation the limit is
            enforced only with ``[loop] realtime``.
    """
    enforced = realtime or config.loop.realtime
    limit = config.solver_limit.limit_s(config.scenario.dt) if enforced else None
    clock = "wall" if realtime else config.solver_limit.simulation_clock
    return {"time_limit_s": limit, "clock": clock if limit is not None else None}


def expected_run_bytes(config: Config, robot: robots.Robot, methods: int, plots: bool) -> int:
    """Expected size of a run directory of ``config`` with ``methods`` methods [bytes] (up-front check)."""
    hierarchy = config.build_hierarchy(robot)
    set_tasks = hierarchy.set_tasks
    obstacles = sum(isinstance(t, ObstacleDistanceTask) for t in set_tasks)
    steps = max(1, round(config.scenario.sim_time_s / config.scenario.dt))
    return preflight.run_bytes(steps, preflight.step_columns(robot.nq, len(set_tasks), obstacles), methods, plots)


def open_results(
    config: Config,
    out_dir: Path,
    config_text: str | None,
    robot: robots.Robot,
    overwrite: bool = False,
    plots: bool = True,
    duration_s: float | None = None,
    methods: list[str] | None = None,
) -> ResultsWriter:
    """The :class:`ResultsWriter` of a run of ``config``'s methods into ``out_dir``, checked up front.

    ``methods`` (default: the config's) are the ones about to be written; ``duration_s`` replaces
    the scenario's simulated time (hardware runs).

    Raises:
        compare.analysis.exceptions.ResultsError: The directory holds conflicting results, is
            busy, cannot be written or has no room (one line each).
    """
    sc = config.scenario
    names = list(methods or config.methods.names)
    steps_config = config
    if duration_s is not None:
        scenario = config.scenario.model_copy(update={"duration_s": duration_s, "time_scale": 1.0})
        steps_config = config.model_copy(update={"scenario": scenario})
    return ResultsWriter(
        Path(out_dir),
        sc.name,
        sc.seed,
        sc.sim_time_s if duration_s is None else duration_s,
        config_text,
        config_hash=config_hash(config),
        config_fingerprint=config_fingerprint(config),
        methods=names,
        method_settings={m: method_settings(config, m) for m in names if config.methods.settings.get(m)},
        overwrite=overwrite,
        expected_bytes=expected_run_bytes(steps_config, robot, len(names), plots),
    )


def realize_only(config: Config, robot: robots.Robot, out_dir: Path) -> tuple[Config, dict[str, Any] | None]:
    """The concrete scenario of ``config`` and no verdict: the default ``prepare`` of :func:`run_scenario`."""
    return realize(config, robot), None


Prepare = Callable[[Config, robots.Robot, Path], tuple[Config, dict[str, Any] | None]]
"""``prepare(config, robot, out_dir) -> (realized config, the run's verdict or None)``, before the methods run."""


def run_scenario(
    config: Config,
    out_dir: Path,
    config_text: str | None = None,
    progress: bool = True,
    make_plots: bool = True,
    overwrite: bool = False,
    prepare: Prepare = realize_only,
    report: bool = True,
) -> dict[str, Any]:
    """Run every method of ``config`` on the same scenario; results survive a crash of one method.

    ``prepare`` realizes the scenario and may compute its verdict (``summary.json["oracle"]``;
    :func:`compare.campaign.realize.realize_with_verdict` does when ``[oracle] enabled``).
    ``report``: write ``report.md`` after the results and plots
    (:func:`~compare.analysis.run_report.render_run_report`; the runs of a sweep have none).

    ``out_dir`` is checked before the first step (:func:`open_results`): results already there
    of the same scenario and configuration get these methods added; anything else is refused
    unless ``overwrite``.

    Returns:
        The content of ``out_dir/summary.json``.

    Raises:
        compare.analysis.exceptions.ResultsError: See :func:`open_results`.
    """
    robot = config.load_robot()
    with open_results(config, Path(out_dir), config_text, robot, overwrite, make_plots) as writer:
        config, oracle = prepare(config, robot, Path(out_dir))
        if oracle is not None:
            writer.set_run_info("oracle", oracle)
        writer.set_replay(dump_config(config))
        if config.person.keyframes:
            writer.set_run_info("person", {"max_speed_mps": part_max_speeds(config, robot)})
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
                except Exception as exc:  # a bug: traceback in the log, recorded, non-zero exit; other methods kept
                    log.exception("method %s aborted", method)
                    writer.add_error(method, f"{type(exc).__name__}: {exc}")
                    continue
                if oracle is not None:
                    result["summary"]["obstacle_violations"] = split_obstacle_violations(result["summary"], oracle)
                writer.add_method(method, result["summary"], result["steps"])
                log.info("%s done in %.1f s", method, time.perf_counter() - t0)
        if make_plots:
            write_plots(Path(out_dir))
        if report:
            render_run_report(Path(out_dir), config)
        return writer.summary


def view_scenario(config: Config, method: str) -> None:
    """Run one method in the interactive MuJoCo viewer, in real time."""
    import mujoco.viewer  # Deferred: the GLFW viewer needs a display; headless runs never load it.

    robot = config.load_robot()
    config = realize(config, robot)
    sc = config.scenario
    q0 = np.array(sc.start_q) if sc.start_q is not None else robot.home.copy()
    sim = build_simulation(config, robot, q0)
    hierarchy = config.build_hierarchy(robot)
    solver = guard_solver(make_method(method, robot, config.methods.settings.get(method)), config.solver_limit, sc.dt)
    schedule, settings = loop_setup(config, robot.frame_position(q0, robot.ee_frame))
    with mujoco.viewer.launch_passive(sim.io.model, sim.io.data) as viewer:
        clock = {"tick": time.perf_counter()}

        def sync() -> bool:
            viewer.sync()
            time.sleep(max(0.0, sc.dt - (time.perf_counter() - clock["tick"])))
            clock["tick"] = time.perf_counter()
            return viewer.is_running()

        predictor = make_predictor(config, sim)
        run_loop(
            sim.io,
            robot,
            hierarchy,
            solver,
            schedule,
            settings,
            sim.obstacles,
            sim.truth,
            on_step=sync,
            predictor=predictor,
        )
    sim.close()
