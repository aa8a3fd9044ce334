"""Run a scenario's hierarchy on the real arm: the hardware counterpart of :func:`compare.run.run_method`.

Sequence (docs/hardware.md, "Safety behaviour"):

1. build the hierarchy and the solver; refuse early if obstacle tasks need a depth camera whose
   calibrated transform is missing, or if the master or this node would listen beyond loopback
   (:mod:`compare.hardware.exposure`, decided before any connection);
2. connect to ROS, wait for joint states (and camera info + depth), check the joint state rate,
   check who publishes on the driver's topics and keep watching
   (:mod:`compare.hardware.publisher_watch`);
3. take the first joint state (and a first depth update): refuse if any set-based task is
   outside its safety thresholds;
4. run :func:`compare.loop.closed_loop.run_loop` — the same loop as in simulation — on a
   :class:`~compare.hardware.ros_io.RosRobotIO`, until the end or a halt (a foreign or second
   publisher, a signal);
5. whatever happens (end, Ctrl-C, SIGTERM, an exception): stream zero velocity, shut down;
6. write ``summary.json`` + per-step table (the same :class:`~compare.analysis.results.ResultsWriter` and
   :func:`~compare.analysis.metrics.compute_summary`), and the plots.

On hardware there is no ground truth: obstacle metrics use the measured distances, and the
summary says so (``obstacle_distance_source``).
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

import robots
from compare.analysis.metrics import compute_summary
from compare.analysis.run_report import render_run_report
from compare.config import Config
from compare.hardware.calibration import AlignmentResidual, check_alignment
from compare.hardware.exceptions import StartRefused
from compare.hardware.replay import open_recording
from compare.hardware.ros_io import RosRobotIO
from compare.hardware.safety import start_problems
from compare.hardware.sensing import (
    HardwareDepthSensing,
    capture_background,
    load_background,
    save_background,
    static_background,
)
from compare.loop.closed_loop import ObstacleSource, control_points, run_loop, warm_up_solver
from compare.loop.deadline import guard_solver
from compare.methods import make_method
from compare.run import loop_setup, open_results, run_meta, solver_limit_entry, write_plots
from tpik.hierarchy import Hierarchy
from tpik.tasks import ObstacleDistanceTask

log = logging.getLogger(__name__)


class Interrupted:
    """Signal state shared with the handler: the first signal asks the loop to stop cleanly."""

    def __init__(self) -> None:
        self.signal_name: str | None = None


@contextmanager
def _signals(io: RosRobotIO, state: Interrupted) -> Iterator[None]:
    """SIGINT/SIGTERM: first → zero velocity at once and end the loop; second → KeyboardInterrupt."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, _frame: Any) -> None:
        name = signal.Signals(signum).name
        if state.signal_name is not None:
            raise KeyboardInterrupt(name)
        state.signal_name = name
        io.halt(f"{name} received")

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def hardware_robot(config: Config) -> robots.Robot:
    """The arm of ``[scenario] robot``, checked against ``[hardware]``: one driver joint per model joint.

    Raises:
        StartRefused: ``hardware.joint_names`` does not name the robot's joints one to one.
    """
    robot = config.load_robot()
    names = config.hardware.joint_names
    if len(names) != robot.nq:
        raise StartRefused(
            f"hardware.joint_names has {len(names)} names but robot '{robot.name}' has {robot.nq} joints "
            f"({', '.join(robot.joint_names)}); set hardware.joint_names to the driver's names for this arm"
        )
    return robot


def make_obstacle_source(config: Config, robot: robots.Robot, io: RosRobotIO) -> ObstacleSource:
    """Depth-space obstacle distance on the live frames: static background, self-filter, distance."""
    frame = io.read_depth()
    if frame is None:
        raise StartRefused("no depth frame to build the obstacle sensing from")
    hw = config.hardware
    if hw.background_file is not None:
        depth = load_background(Path(hw.background_file), frame.camera)
    elif hw.background_capture_s > 0:
        log.info("capturing the static background for %.1f s: keep people out of view", hw.background_capture_s)
        depth = capture_background(io.read_depth, io.frame_q, robot, config, hw.background_capture_s)
    else:
        depth = None
    background = static_background(depth, config) if depth is not None else None
    return HardwareDepthSensing(robot, frame.camera, io.read_depth, io.frame_q, config, background, io.frame_q_ahead)


def capture_background_file(config: Config, path: Path, duration_s: float) -> float:
    """Record the static background on the real setup and save it (nothing is published).

    Move the arm through its workspace meanwhile (joystick, Kinova GUI) so every pixel is seen
    unhidden at least once; keep people out of the camera's view.

    Returns:
        Fraction of pixels that got a background.
    """
    robot = hardware_robot(config)
    hw = config.hardware.model_copy(update={"startup_timeout_s": max(config.hardware.startup_timeout_s, 5.0)})
    io = RosRobotIO(hw, robot.v_max, config.scenario.dt, use_depth=True, dry_run=True, watch_command_topic=False)
    try:
        io.connect()
        io.wait_ready()
        depth = capture_background(io.read_depth, io.frame_q, robot, config, duration_s)
    finally:
        io.close()
    if depth is None:
        raise StartRefused("no depth frame during the capture")
    save_background(path, depth)
    return float(np.mean(depth > 0))


def measure_alignment(io: RosRobotIO, frames: int = 1, timeout_s: float = 5.0) -> AlignmentResidual:
    """Alignment residual of the arm model on the next ``frames`` depth frames (the median one).

    Each frame is compared with the arm rendered at the joint positions measured when it arrived.

    Raises:
        StartRefused: no new frame or joint positions within ``timeout_s``.
    """
    results: list[AlignmentResidual] = []
    last = None
    deadline = time.monotonic() + timeout_s
    while len(results) < frames:
        frame = io.read_depth()
        if frame is not None and frame is not last:
            last = frame
            q = io.frame_q(frame.stamp_s)
            if q is not None:
                results.append(check_alignment(frame.camera, q, frame.depth_m))
        if time.monotonic() > deadline:
            raise StartRefused("calibration check: no depth frame with joint positions")
        time.sleep(0.01)
    return sorted(results, key=lambda r: r.residual_m)[len(results) // 2]


def calibration_problem(residual: AlignmentResidual, limit_m: float) -> str | None:
    """Why motion must be refused after the calibration check, or None (``limit_m`` 0: never)."""
    if limit_m <= 0.0:
        return None
    if not residual.conclusive:
        return (
            f"calibration check inconclusive: {residual.valid_pixels} arm pixels with a depth return "
            "(arm out of view or hidden?); set hardware.calibration_max_residual_m = 0 to skip it"
        )
    if residual.residual_m > limit_m:
        return (
            f"camera calibration off: {residual.describe()}, limit {100 * limit_m:.1f} cm: check "
            "hardware.camera_translation_m/camera_quaternion_xyzw (the depth = IR optical frame) with "
            "`tpik-compare hw-check`"
        )
    return None


def check_camera(config: Config, replay: Path | None = None, frames: int = 5) -> AlignmentResidual:
    """``tpik-compare hw-check``: connect without publishing, render the arm into live frames, return the residual.

    Raises:
        StartRefused: camera transform missing, no data.
        MasterUnreachable: no ROS master (live).
        ReplayError: bad recording.
    """
    robot = config.load_robot()
    recording = open_recording(replay) if replay is not None else None
    io = RosRobotIO(
        config.hardware,
        robot.v_max,
        config.scenario.dt,
        use_depth=True,
        dry_run=True,
        replay=recording,
        watch_command_topic=False,
    )
    try:
        io.connect()
        io.wait_ready()
        return measure_alignment(io, frames)
    finally:
        io.close()


def executed_motion_ratio(steps: Any) -> float | None:
    r"""Measured joint path length over commanded path length (1: the arm moved as commanded).

    :math:`\sum_k \|q_{k+1} - q_k\|_1 / \sum_k \|\dot q_k\|_1 (t_{k+1} - t_k)` over the run. Over USB about
    half of the driver's velocity messages are dropped and the ratio falls to ~0.5
    (docs/hardware.md, "What reaches the arm"). None without motion.
    """
    q = steps[[c for c in steps.columns if c.startswith("q_")]].to_numpy(dtype=float)
    qdot = steps[[c for c in steps.columns if c.startswith("qdot_")]].to_numpy(dtype=float)
    t = steps["t"].to_numpy(dtype=float)
    if len(t) < 3:
        return None
    moved = float(np.nansum(np.abs(np.diff(q, axis=0))))
    commanded = float(np.nansum(np.abs(qdot[:-1]) * np.diff(t)[:, None]))
    return moved / commanded if commanded > 1e-6 else None


def _apply_sensing(hierarchy: Hierarchy, result: Any) -> None:
    for task in hierarchy.set_tasks:
        if isinstance(task, ObstacleDistanceTask):
            r = result.readings.get(task.frame)
            task.set_obstacle(r.closest_point if r is not None and r.in_range else None)


def run_hardware(
    config: Config,
    method: str,
    out_dir: Path,
    config_text: str | None = None,
    dry_run: bool = False,
    duration_s: float | None = None,
    make_plots: bool = True,
    progress: Callable[[float], None] | None = None,
    obstacle_source: Callable[[Config, robots.Robot, RosRobotIO], ObstacleSource] | None = None,
    replay: Path | None = None,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Drive the arm through ROS with one method; write results like a simulated run (``report.md`` included).

    Args:
        config: Validated configuration (scenario, hierarchy, methods' settings, ``[hardware]``).
        method: Method key (``tpik``, ``hqp-daqp``, ``mink``, ...).
        out_dir: Results directory.
        config_text: TOML text copied to the results.
        dry_run: Everything runs, nothing is published on the velocity topic.
        duration_s: Run time [s]; default the scenario's (after ``time_scale``).
        make_plots: Draw the plots after the run.
        progress: Called with the elapsed time [s] about every 0.5 s.
        obstacle_source: Builds the obstacle source (default :func:`make_obstacle_source`).
        replay: A bag (or a directory of bags) to play instead of the live topics
            (:mod:`compare.hardware.replay`); implies ``dry_run``; the run ends with the recording.
        overwrite: Replace the results already in ``out_dir`` (else they are kept and this
            method added, or the run is refused before the arm moves).

    Returns:
        The content of ``summary.json``; ``["methods"][method]["hardware"]`` holds the measured
        rates, watchdog events and counters, and ``halt_cause``: why the arm was halted before
        the end (a foreign publisher, a signal; None if it ran to the end);
        ``["methods"][method]["interrupted"]`` the signal that ended the run.

    Raises:
        NetworkExposed: the master or this node would listen beyond loopback (before anything
            is connected or written; ``hardware.allow_network_master`` to run anyway).
        StartRefused: a start-up check failed (nothing was commanded but zero).
        MasterUnreachable: no ROS master.
        RosUnavailable: ROS 1 not installed.
        compare.analysis.exceptions.ResultsError: ``out_dir`` cannot take the results (checked
            before anything is sent to the arm).
    """
    robot = hardware_robot(config)
    sc = config.scenario
    hw = config.hardware
    hierarchy = config.build_hierarchy(robot)
    obstacle_tasks = [t for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)]
    if obstacle_tasks and not hw.use_depth:
        raise StartRefused("the hierarchy has obstacle tasks but hardware.use_depth is false")
    if len(config.sensor.cameras) > 1:
        raise StartRefused(
            f"{len(config.sensor.cameras)} cameras in [[sensor.cameras]]: the hardware bridge reads one depth "
            "topic (hardware.depth_topic); fusing several cameras is simulation-only for now (docs/sensing.md)"
        )
    use_depth = hw.use_depth and bool(obstacle_tasks)
    duration = float(duration_s) if duration_s is not None else sc.sim_time_s
    solver = make_method(method, robot, config.methods.settings.get(method))
    if abs(sc.control_rate_hz - 100.0) > 1e-9:
        log.warning("control rate %.0f Hz: the Kinova driver expects commands at 100 Hz", sc.control_rate_hz)

    recording = open_recording(replay) if replay is not None else None
    io = RosRobotIO(hw, robot.v_max, sc.dt, use_depth=use_depth, dry_run=dry_run, replay=recording)  # needs camera pose
    io.check_network()  # before the results directory is made and before any connection
    # The results directory is checked (and locked) before anything is sent to the arm.
    writer = open_results(config, Path(out_dir), config_text, robot, overwrite, make_plots, duration, [method])
    unguarded = solver
    solver = guard_solver(solver, config.solver_limit, sc.dt, realtime=True)  # the loop never waits past it
    warmup_steps = 0
    alignment: AlignmentResidual | None = None
    state = Interrupted()
    with _signals(io, state):
        try:
            io.connect()
            io.wait_ready()
            if use_depth:
                alignment = measure_alignment(io)
                log.info("camera: %s", alignment.describe())
                problem = calibration_problem(alignment, hw.calibration_max_residual_m)
                if problem is not None:
                    raise StartRefused(problem)
            obstacles = (obstacle_source or make_obstacle_source)(config, robot, io) if use_depth else None
            reading = io.read_joints()
            if reading is None:
                raise StartRefused("joint states stopped during start-up")
            # Untimed solves at the start state, as in simulation: the first calls of a fresh
            # process (lazy imports, compiled kernels) never reach the arm's first control steps.
            warmup_steps = warm_up_solver(unguarded, hierarchy, robot, reading.q, sc.dt)
            kin = robot.kinematics(reading.q)
            if obstacles is not None:
                first = obstacles.update(io.now(), kin)
                if first.blind:
                    raise StartRefused("depth sensing is blind at start (too few valid pixels or stale frame)")
                _apply_sensing(hierarchy, first)
            problems = start_problems(hierarchy, kin)
            if problems:
                raise StartRefused("arm outside its safety thresholds at start: " + "; ".join(problems))
            remaining = io.replay_remaining_s()
            if remaining is not None:  # replay: stop before the recording ends (its end would trip the watchdog)
                duration = min(duration, max(0.0, remaining - 0.2))
                if duration < 10 * sc.dt:
                    raise StartRefused(f"the recording ends {remaining:.1f} s after the start checks: nothing to run")
            if io.halt_cause is not None:  # a foreign publisher, a second publisher during the checks
                raise StartRefused(io.halt_cause)
            io.start_driver()
            schedule, settings = loop_setup(config, kin.frame_position(robot.ee_frame), duration)
            mode = " (replay: nothing published)" if recording else " (dry run: nothing published)" if dry_run else ""
            log.info("hardware run: %s, %.1f s%s", method, duration, mode)
            io.start_clock()
            out = run_loop(
                io,
                robot,
                hierarchy,
                solver,
                schedule,
                settings,
                obstacles,
                None,
                progress,
                on_step=lambda: state.signal_name is None and io.halt_cause is None,
            )
        except BaseException:
            writer.close()
            raise
        finally:
            io.close()
            solver.close()

    steps = out.steps.drop(columns=[c for c in out.steps.columns if c.startswith(("truth:", "dist_true:"))])
    sensing = "depth" if use_depth else "none"
    summary = compute_summary(steps, run_meta(config, method, hierarchy, robot, out, sensing, warmup_steps))
    cps = control_points(hierarchy, robot)
    measured = [steps[f"dist_meas:{cp}"].to_numpy(dtype=float) for cp in cps if f"dist_meas:{cp}" in steps]
    summary["min_obstacle_distance_m"] = [_finite_min(d) for d in measured]
    summary["obstacle_distance_source"] = "measured (depth camera; no ground truth on hardware)"
    summary["hardware"] = io.report()
    summary["hardware"]["calibration"] = alignment.as_dict() if alignment is not None else None
    ratio = executed_motion_ratio(out.steps) if not io.dry_run else None
    summary["hardware"]["executed_motion_ratio"] = ratio
    if ratio is not None and ratio < 0.8:
        log.warning(
            "the arm moved %.0f %% of the commanded joint path: the driver drops velocity messages "
            "(connection_type %s; docs/hardware.md, 'What reaches the arm')",
            100 * ratio,
            hw.connection_type,
        )
    summary["events"] = out.events[:50]
    summary["interrupted"] = state.signal_name
    summary["solver_limit"] = solver_limit_entry(config, realtime=True)
    with writer:
        writer.add_method(method, summary, steps)
        if make_plots:
            write_plots(Path(out_dir))
        render_run_report(Path(out_dir), config)
        return writer.summary


def _finite_min(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(x.min()) if x.size else None
