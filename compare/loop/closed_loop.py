"""The closed loop shared by every method, in simulation and on hardware (DESIGN §4, §7).

One control step (period ``dt``, 100 Hz in the paper):

1. read the joint state from the :class:`~compare.loop.robot_io.RobotIO`;
2. at the sensing rate (30 Hz), update the closest obstacle point of each control point
   from the obstacle source; between updates the latest estimate is used;
3. advance the waypoint schedule and set the EE target;
4. solve the hierarchy (timed: kinematics + solver);
5. guard the command: a failed solve, a non-finite or out-of-limit velocity is replaced by the
   configured fallback; blind or stale sensing commands zero velocity (safe stop);
6. send the command and wait for the next period.

Sensing is checked at the update that sees a problem (:func:`sensing_problem`): a blind frame
(``DistanceResult.blind``: too few valid pixels, NaN or all-zero frames, no frame), a frame
older than ``stale_frame_periods`` sensing periods (frozen or delayed camera), or a reading
that is not finite. The loop then commands zero velocity in that same step and logs why; the
estimates of the last good update are kept but not trusted. While the frame stamp does not
advance, the source is polled again at every control step (not only at the sensing rate), so a
frozen frame is caught within half a period plus one control period of being overdue. The
older rule stays as a second guard: no good update for ``max_sensing_age_s`` → safe stop.

Every method runs this same code on the same scenario, seed and sensing, and every step is
classified by the same rules (DESIGN §3): FAILED when the solver reports it or raises one of its
package's own errors (:data:`SOLVER_ERRORS`: a backend's no-solution, a task that cannot be
evaluated); DEGRADED when the solver reports it (a slack used, a level given up, damping, the
velocity scaled) or when its command misses the reference rate of a set-based task at or past an
activation threshold (:func:`tpik.reference.unmet_set_rates`); OK otherwise. Any other exception
is a bug: the loop stops the robot and re-raises it, so the run aborts with its traceback.
A step whose solve takes longer than its deadline (``LoopSettings.deadline_s``, default the
control period) is flagged ``deadline_miss``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import pandas as pd

from compare.loop.robot_io import RobotIO
from compare.loop.waypoints import WaypointSchedule
from qp_baseline.exceptions import HqpError
from robots import Kinematics, Robot
from tpik.exceptions import TpikError
from tpik.hierarchy import Hierarchy
from tpik.reference import DEFAULT_REFERENCE, ControlReference, unmet_set_rates
from tpik.step_result import IkSolver, SolveStatus
from tpik.tasks import ObstacleDistanceTask, PositionTask, SetTask

log = logging.getLogger(__name__)


def control_points(hierarchy: Hierarchy, robot: Robot) -> tuple[str, ...]:
    """The control points of a run: the frames of the hierarchy's obstacle tasks, in order.

    A hierarchy without obstacle tasks still records the true distance of the robot's default
    control points (``robot.control_points``), so every run reports its closest approach.
    """
    frames = [t.frame for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)]
    return tuple(dict.fromkeys(frames)) or tuple(robot.control_points)


def _solver_errors() -> tuple[type[Exception], ...]:
    errors: list[type[Exception]] = [TpikError, HqpError]
    try:
        from mink.exceptions import MinkError

        errors.append(MinkError)
    except ImportError:
        pass
    try:
        from qpsolvers.exceptions import QPError

        errors.append(QPError)
    except ImportError:
        pass
    return tuple(errors)


SOLVER_ERRORS: tuple[type[Exception], ...] = _solver_errors()
"""The solver-domain errors (each package's root error): a FAILED step, not a bug."""


class ObstacleReadingLike(Protocol):
    """Closest obstacle of one control point (see :mod:`compare.sensing`)."""

    distance_m: float
    closest_point: np.ndarray | None
    in_range: bool


class DistanceResultLike(Protocol):
    """One sensing update: a reading per control point and whether the sensor is blind."""

    readings: Mapping[str, ObstacleReadingLike]
    blind: bool


class ObstacleSource(Protocol):
    """Anything that gives closest obstacle points for the control points."""

    def update(self, t: float, kin: Kinematics) -> DistanceResultLike:
        """Sense at time ``t`` [s] with the robot at ``kin.q``."""
        ...


@dataclass
class LoopSettings:
    """Timing and safety reactions of the loop.

    Attributes:
        dt: Control period [s].
        duration_s: Simulated (or wall) time to run [s].
        sensing_period_s: Period of obstacle updates [s] (1/30 s).
        fallback: ``zero`` or ``hold_last`` (last safe command, decaying to zero).
        fallback_decay_s: Decay time of ``hold_last`` [s].
        max_sensing_age_s: An estimate older than this is stale → zero velocity [s].
        stop_when_blind: Command zero velocity while sensing is blind or stale.
        stale_frame_periods: A sensing update whose frame stamp is more than this many sensing
            periods older than the loop time is stale (frozen or delayed frame) → zero velocity
            at that update; ``None`` disables the check (then only ``max_sensing_age_s`` applies).
        deadline_s: A solve longer than this is a deadline miss (``deadline_miss`` column) [s];
            None = the control period ``dt`` (a solver time limit, when one is set, replaces it).
    """

    dt: float = 0.01
    duration_s: float = 10.0
    sensing_period_s: float = 1.0 / 30.0
    fallback: str = "zero"
    fallback_decay_s: float = 0.2
    max_sensing_age_s: float = 0.2
    stop_when_blind: bool = True
    stale_frame_periods: float | None = 1.5
    deadline_s: float | None = None


@dataclass
class LoopOutput:
    """What one run of the loop produced.

    Attributes:
        steps: Per-step table (columns documented in :mod:`compare.analysis.metrics`).
        wall_time_s: Wall-clock time of the loop [s].
        sim_time_s: Time covered on the backend's clock [s].
        events: Log lines of safety reactions (fallbacks, blind sensing).
    """

    steps: pd.DataFrame
    wall_time_s: float
    sim_time_s: float
    events: list[str] = field(default_factory=list)


class _Recorder:
    """Preallocated per-step columns, turned into a DataFrame at the end."""

    def __init__(
        self, n_steps: int, nq: int, set_tasks: tuple[SetTask, ...], obstacle_tasks: list[str], cps: tuple[str, ...]
    ) -> None:
        self.n = 0
        self.cols: dict[str, np.ndarray] = {}
        f = self._float
        for name in ["t", "ee_x", "ee_y", "ee_z", "target_x", "target_y", "target_z", "ee_error_m", "solve_time_us"]:
            f(name, n_steps)
        self.nq = nq
        self.q = np.full((n_steps, nq), np.nan)
        self.qdot = np.full((n_steps, nq), np.nan)
        for task in set_tasks:
            f(f"sigma:{task.name}", n_steps)
            self.cols[f"active:{task.name}"] = np.zeros(n_steps, dtype=bool)
        for name in obstacle_tasks:
            f(f"truth:{name}", n_steps)
        for cp in cps:
            f(f"dist_meas:{cp}", n_steps)
            f(f"dist_true:{cp}", n_steps)
            self.cols[f"occluded:{cp}"] = np.zeros(n_steps, dtype=bool)
            self.cols[f"camera:{cp}"] = np.full(n_steps, "", dtype=object)
        self.cols["waypoint"] = np.zeros(n_steps, dtype=np.int32)
        self.cols["status"] = np.empty(n_steps, dtype=object)
        self.cols["reason"] = np.full(n_steps, "", dtype=object)
        for name in ("fallback", "blind", "deadline_miss"):
            self.cols[name] = np.zeros(n_steps, dtype=bool)

    def _float(self, name: str, n: int) -> None:
        self.cols[name] = np.full(n, np.nan)

    def frame(self) -> pd.DataFrame:
        cols = {k: v[: self.n] for k, v in self.cols.items()}
        for j in range(self.nq):
            cols[f"q_{j + 1}"] = self.q[: self.n, j]
            cols[f"qdot_{j + 1}"] = self.qdot[: self.n, j]
        return pd.DataFrame(cols)


def sensing_problem(result: DistanceResultLike, t: float, stale_after_s: float | None) -> str | None:
    """Why a sensing update must not be trusted, or None when it is usable.

    Args:
        result: The update.
        t: Loop time of the update [s] (the clock of ``result.stamp_s``).
        stale_after_s: Largest accepted age ``t - stamp_s`` of the frame [s]; None = no check.

    Returns:
        ``"blind frame ..."``, ``"stale frame ..."`` or ``"invalid reading ..."``, or None.
    """
    if result.blind:
        fraction = getattr(result, "valid_fraction", math.nan)
        return f"blind frame (valid fraction {fraction:.2f})"
    stamp = float(getattr(result, "stamp_s", math.nan))
    if stale_after_s is not None and math.isfinite(stamp) and t - stamp > stale_after_s + 1e-9:
        return f"stale frame (age {1e3 * (t - stamp):.0f} ms)"
    for name, r in result.readings.items():
        if not r.in_range:
            continue
        point = r.closest_point
        if not math.isfinite(r.distance_m) or point is None or not np.all(np.isfinite(point)):
            return f"invalid reading for {name}"
    return None


def _guard(qdot: np.ndarray, v_max: np.ndarray) -> str | None:
    """Why a command must not be sent, or None when it is finite and within the limits."""
    if qdot.shape != v_max.shape:
        return f"command has shape {qdot.shape}, expected {v_max.shape}"
    if not np.isfinite(qdot).all():
        return "command is not finite"
    if (np.abs(qdot) > v_max * (1.0 + 1e-6) + 1e-9).any():
        return f"command exceeds the velocity limits by {float(np.max(np.abs(qdot) - v_max)):.3g} rad/s"
    return None


WARMUP_SOLVES = 3
"""Untimed solves at the start state before the first control step (:func:`warm_up_solver`)."""


def ee_position_tasks(hierarchy: Hierarchy, robot: Robot) -> list[PositionTask]:
    """The position tasks of the robot's EE frame (either spelling of its name): the waypoints move them."""
    ee_id = robot.frame_id(robot.ee_frame)
    return [t for t in hierarchy.tasks if isinstance(t, PositionTask) and robot.frame_id(t.frame) == ee_id]


def warm_up_solver(
    solver: IkSolver, hierarchy: Hierarchy, robot: Robot, q: np.ndarray, dt: float, solves: int = WARMUP_SOLVES
) -> int:
    """Solve ``solves`` times at ``q`` before the run, untimed, results discarded.

    The first calls of a fresh process pay for lazy imports, caches and compiled code; done here,
    they never reach the solve-time percentiles (``warmup_steps`` in ``summary.json``). The EE
    targets are set to the EE's own position for the warm-up (the loop sets the real ones at its
    first step); an error of the solver's domain is left for the loop to report.

    Returns:
        The number of warm-up solves made.
    """
    kin = robot.kinematics(q)
    for task in ee_position_tasks(hierarchy, robot):
        task.set_target(kin.frame_position(robot.ee_frame))
    done = 0
    for _ in range(solves):
        try:
            solver.solve(hierarchy, robot.kinematics(q), dt)
        except SOLVER_ERRORS:
            break
        done += 1
    return done


def run_loop(
    io: RobotIO,
    robot: Robot,
    hierarchy: Hierarchy,
    solver: IkSolver,
    waypoints: WaypointSchedule,
    settings: LoopSettings,
    obstacles: ObstacleSource | None = None,
    truth: Callable[[Kinematics], Mapping[str, float]] | None = None,
    progress: Callable[[float], None] | None = None,
    on_step: Callable[[], bool] | None = None,
) -> LoopOutput:
    """Run the closed loop for ``settings.duration_s`` and record every step.

    Args:
        io: Robot and sensor backend (simulation or hardware).
        robot: Kinematic model.
        hierarchy: The tasks (this method's own copy: targets and obstacles are set here).
        solver: Any :class:`~tpik.step_result.IkSolver`.
        waypoints: EE target schedule.
        settings: Rates and safety reactions.
        obstacles: Obstacle source; None = no obstacle sensing (obstacle tasks stay inactive).
        truth: Ground-truth distance per control point (simulation only), recorded for metrics.
        progress: Called with the elapsed backend time [s] about every 0.5 s.
        on_step: Called after every step (e.g. to sync a viewer); returning False stops the loop.

    Returns:
        :class:`LoopOutput`. A solver error of its own domain (:data:`SOLVER_ERRORS`) is a FAILED
        step and the loop goes on with the fallback.

    Raises:
        Exception: Any other exception of the solver (a bug): the robot is stopped first.
    """
    dt = settings.dt
    n_steps = max(1, round(settings.duration_s / dt))
    set_tasks = hierarchy.set_tasks
    obstacle_tasks = [t for t in set_tasks if isinstance(t, ObstacleDistanceTask)]
    ee_frame = robot.ee_frame
    position_tasks = ee_position_tasks(hierarchy, robot)
    cps = control_points(hierarchy, robot)
    rec = _Recorder(n_steps, robot.nq, set_tasks, [t.name for t in obstacle_tasks], cps)
    cols = rec.cols
    # Column arrays and σ functions looked up once (recording is a noticeable share of a fast run).
    # σ alone (SetTask.compute_value): the solver already formed the Jacobians it needed.
    sigma_record = [(cols[f"sigma:{t.name}"], cols[f"active:{t.name}"], t.name, t.compute_value) for t in set_tasks]
    dist_record = [(cols[f"dist_meas:{cp}"], cols[f"dist_true:{cp}"], cp) for cp in cps]
    source_record = [(cols[f"occluded:{cp}"], cols[f"camera:{cp}"], cp) for cp in cps]
    truth_record = [(cols[f"truth:{t.name}"], t.frame) for t in obstacle_tasks]
    c_t, c_ee_x, c_ee_y, c_ee_z = cols["t"], cols["ee_x"], cols["ee_y"], cols["ee_z"]
    c_tx, c_ty, c_tz, c_err = cols["target_x"], cols["target_y"], cols["target_z"], cols["ee_error_m"]
    c_solve, c_wp, c_status, c_fallback, c_blind, c_deadline = (
        cols["solve_time_us"],
        cols["waypoint"],
        cols["status"],
        cols["fallback"],
        cols["blind"],
        cols["deadline_miss"],
    )
    deadline_us = 1e6 * (settings.deadline_s if settings.deadline_s is not None else dt)
    reference: ControlReference = getattr(solver, "reference", DEFAULT_REFERENCE)
    sigmas = [math.nan] * len(set_tasks)
    events: list[str] = []
    v_max = robot.v_max
    # A deadline miss: flagged by the solver's time-limit guard (compare.loop.deadline) when it
    # has one, else a solve longer than ``settings.deadline_s`` (default the control period).
    guarded = getattr(solver, "deadline_s", None) is not None
    last_safe = np.zeros(robot.nq)
    last_safe_t = -math.inf
    next_sense_t = -math.inf
    last_good_sense_t = -math.inf
    blind = obstacles is not None and bool(obstacle_tasks)
    measured = dict.fromkeys(cps, math.inf)
    # What each reading is: assumed from hidden space (occluded) or measured, and by which camera.
    measured_source: dict[str, tuple[bool, str]] = dict.fromkeys(cps, (False, ""))
    was_blind = False
    fallback_since: float | None = None  # start of the current fallback episode [s]
    sensing_reason: str | None = None  # why the latest update was not usable (None: it was)
    blind_reason = ""
    last_stamp = math.nan
    repoll = False
    stale_after_s = (
        None if settings.stale_frame_periods is None else settings.stale_frame_periods * settings.sensing_period_s
    )
    start_wall = time.perf_counter()
    t0 = io.now()
    next_progress = 0.0

    try:
        for i in range(n_steps):
            reading = io.read_joints()
            t = io.now() - t0
            if reading is None:
                io.send_velocity(np.zeros(robot.nq))
                io.wait()
                continue
            kin = robot.kinematics(reading.q)

            if obstacles is not None and obstacle_tasks and (t + 1e-9 >= next_sense_t or repoll):
                if t + 1e-9 >= next_sense_t:
                    next_sense_t = (
                        t + settings.sensing_period_s if next_sense_t < 0 else next_sense_t + settings.sensing_period_s
                    )
                result = obstacles.update(t, kin)
                stamp = float(getattr(result, "stamp_s", math.nan))
                repoll = math.isfinite(stamp) and stamp == last_stamp  # frame did not advance: look again next step
                last_stamp = stamp
                sensing_reason = sensing_problem(result, t, stale_after_s)
                if sensing_reason is None:
                    last_good_sense_t = t
                    for task in obstacle_tasks:
                        r = result.readings.get(task.frame)
                        task.set_obstacle(r.closest_point if r is not None and r.in_range else None)
                    for cp in cps:
                        r = result.readings.get(cp)
                        measured[cp] = r.distance_m if r is not None and r.in_range else math.inf
                        measured_source[cp] = (
                            (bool(getattr(r, "occluded", False)), getattr(r, "camera", None) or "")
                            if r is not None and r.in_range
                            else (False, "")
                        )
            if obstacles is not None and obstacle_tasks:
                if sensing_reason is not None:
                    reason_now = sensing_reason
                elif t - last_good_sense_t > settings.max_sensing_age_s:
                    reason_now = f"no good sensing update (for {1e3 * (t - last_good_sense_t):.0f} ms)"
                else:
                    reason_now = ""
                blind = bool(reason_now)
                if blind != was_blind or (blind and reason_now.split(" (")[0] != blind_reason.split(" (")[0]):
                    what = f"sensing blind or stale: {reason_now}: safe stop" if blind else "sensing recovered"
                    events.append(f"t={t:.3f} s: {what}")
                    log.warning(events[-1])
                    was_blind = blind
                blind_reason = reason_now

            ee = kin.frame_position(ee_frame)
            target = waypoints.update(t, ee)
            for task in position_tasks:
                task.set_target(target)

            wall0 = time.perf_counter_ns()
            try:
                result_step = solver.solve(hierarchy, kin, dt)
                qdot, status, active, message = (
                    result_step.qdot,
                    result_step.status,
                    result_step.active_set,
                    result_step.message,
                )
                missed = bool(result_step.extras.get("deadline_miss", False))
            except SOLVER_ERRORS as exc:  # the solver's own domain (no solution, a task it cannot evaluate)
                qdot, status, active, message = (
                    np.zeros(robot.nq),
                    SolveStatus.FAILED,
                    (),
                    f"{type(exc).__name__}: {exc}",
                )
                missed = False
            solve_us = (time.perf_counter_ns() - wall0) * 1e-3
            if not kin.is_current:  # a solver computed kinematics of its own: take a fresh snapshot
                kin = robot.kinematics(reading.q)

            reason = message if status is SolveStatus.FAILED else _guard(np.asarray(qdot, dtype=float), v_max)
            fallback = reason is not None
            if fallback:
                status = SolveStatus.FAILED  # no usable command (DESIGN §3)
                if settings.fallback == "hold_last":
                    decay = math.exp(-(t - last_safe_t) / settings.fallback_decay_s)
                    command = last_safe * decay
                else:
                    command = np.zeros(robot.nq)
                if fallback_since is None:  # log the start of a fallback episode, not every step of it
                    fallback_since = t
                    events.append(f"t={t:.3f} s: {solver.name}: fallback ({settings.fallback}): {reason}")
                    log.warning(events[-1])
            else:
                command = np.array(qdot, dtype=float)
                last_safe, last_safe_t = command, t
                if fallback_since is not None:
                    events.append(f"t={t:.3f} s: {solver.name}: recovered after {t - fallback_since:.2f} s of fallback")
                    log.warning(events[-1])
                    fallback_since = None
            stopped = blind and settings.stop_when_blind
            if stopped:
                command = np.zeros(robot.nq)
            io.send_velocity(command)

            c_t[i] = t
            c_ee_x[i], c_ee_y[i], c_ee_z[i] = ee
            c_tx[i], c_ty[i], c_tz[i] = target
            c_err[i] = math.dist(target, ee)
            c_solve[i] = solve_us
            c_deadline[i] = missed or (not guarded and solve_us > deadline_us)
            c_wp[i] = waypoints.index
            c_fallback[i] = fallback
            c_blind[i] = blind
            if fallback or stopped:
                parts = [f"sensing: {blind_reason}"] if stopped else []
                cols["reason"][i] = "; ".join(parts + ([f"fallback: {reason}"] if fallback else []))
            rec.q[i] = reading.q
            rec.qdot[i] = command
            active_names = set(active)
            for k, (c_sigma, c_active, name, value) in enumerate(sigma_record):
                sigmas[k] = c_sigma[i] = value(kin)
                c_active[i] = name in active_names
            if (
                status is SolveStatus.OK
                and not fallback
                and unmet_set_rates(set_tasks, sigmas, kin, qdot, dt, reference)
            ):
                status = SolveStatus.DEGRADED  # a set task's reference rate missed: the same rule for every method
            c_status[i] = status.value
            true_d = truth(kin) if truth is not None else {}
            for c_meas, c_true, cp in dist_record:
                c_meas[i] = measured[cp]
                c_true[i] = true_d.get(cp, math.inf)
            for c_occ, c_cam, cp in source_record:
                c_occ[i], c_cam[i] = measured_source[cp]
            for c_truth, frame in truth_record:
                c_truth[i] = true_d.get(frame, math.inf)
            rec.n = i + 1

            if progress is not None and t >= next_progress:
                progress(t)
                next_progress = t + 0.5
            io.wait()
            if on_step is not None and not on_step():
                break
    except BaseException:
        io.stop()  # a bug (or Ctrl-C) ends the run with the robot stopped, then surfaces
        raise

    io.stop()
    wall = time.perf_counter() - start_wall
    return LoopOutput(rec.frame(), wall, io.now() - t0, events)
