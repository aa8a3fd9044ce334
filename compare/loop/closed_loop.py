"""The closed loop shared by every method, in simulation and on hardware (docs/design.md §4, §7).

One control step (period ``dt``, 100 Hz in the paper):

1. read the joint state from the :class:`~compare.loop.robot_io.RobotIO`;
2. at the sensing rate (30 Hz), update the closest obstacle point of each control point
   from the obstacle source; between updates the latest estimate is used;
3. advance the waypoint schedule and set the EE target; evaluate σ of every set task and the
   ground truth (the loop's own snapshot of ``q``, once per step);
4. solve the hierarchy, timed: the method gets a kinematics snapshot at the step's ``q`` with
   nothing computed yet, so the kinematics it reads (pinocchio's for HQP, MuJoCo's for mink,
   TPIK's compiled chain) are computed inside its timed call — one rule for every method
   (:func:`timed_solve`);
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
classified by the same rules (docs/design.md §3): FAILED when the solver reports it or raises one of its
package's own errors (:data:`SOLVER_ERRORS`: a backend's no-solution, a task that cannot be
evaluated); DEGRADED when the solver reports it (a slack used, a level given up, damping, the
velocity scaled) or when its command misses the reference rate of a set-based task at or past an
activation threshold (:func:`tpik.reference.unmet_set_rates`); OK otherwise. Any other exception
is a bug: the loop stops the robot and re-raises it, so the run aborts with its traceback.
A step whose solve takes longer than its deadline (``LoopSettings.deadline_s``, default the
control period) is flagged ``deadline_miss``.

The parts, each in its own place: the sensing gate (:class:`~compare.loop.sensing_gate.SensingGate`),
the timed solve (:func:`timed_solve`), the command guard and fallback policy
(:class:`~compare.loop.fallback.FallbackPolicy`), σ of the set tasks and the status check
(:class:`~compare.loop.set_task_watch.SetTaskWatch`), the step table
(:class:`~compare.loop.recorder.StepRecorder`); :class:`_Step` puts one control step together
and :func:`run_loop` repeats it.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from compare.loop.deadline import DeadlineGuard
from compare.loop.fallback import FallbackPolicy, guard
from compare.loop.recorder import RecordedTruth, StepRecorder
from compare.loop.robot_io import RobotIO
from compare.loop.sensing_gate import (
    DistanceResultLike,
    ObstacleReadingLike,
    ObstacleSource,
    SensingGate,
    sensing_problem,
)
from compare.loop.set_task_watch import SetTaskWatch
from compare.loop.settings import LoopSettings
from compare.loop.waypoints import WaypointSchedule
from compare.sensing.prediction import Predictor
from qp_baseline.exceptions import HqpError
from qp_baseline.time_limits import TimeLimitReached
from robots import Kinematics, Robot
from tpik.exceptions import TpikError
from tpik.hierarchy import Hierarchy
from tpik.reference import ControlReference
from tpik.step_result import IkSolver, SolveStatus
from tpik.tasks import ObstacleDistanceTask, PositionTask

__all__ = [
    "SOLVER_ERRORS",
    "WARMUP_SOLVES",
    "DistanceResultLike",
    "LoopOutput",
    "ObstacleReadingLike",
    "ObstacleSource",
    "control_points",
    "ee_position_tasks",
    "guard",
    "run_loop",
    "sensing_problem",
    "timed_solve",
    "warm_up_solver",
]


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
        from mink.exceptions import MinkError  # Deferred: optional method (compare.methods)

        errors.append(MinkError)
    except ImportError:
        pass
    try:
        from qpsolvers.exceptions import QPError  # Deferred: optional method (compare.methods)

        errors.append(QPError)
    except ImportError:
        pass
    return tuple(errors)


SOLVER_ERRORS: tuple[type[Exception], ...] = _solver_errors()
"""The solver-domain errors (each package's root error): a FAILED step, not a bug."""


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


_STATUS_VALUES = {status: status.value for status in SolveStatus}
"""The table's word for each status (an Enum's ``value`` is a descriptor call)."""


class _Targets:
    """Sets the EE position tasks' target, only when it changed (``set_target`` copies and checks)."""

    def __init__(self, tasks: list[PositionTask]) -> None:
        self._tasks = tasks
        self._last: list[float] | None = None

    def set(self, target: np.ndarray, value: list[float] | None = None) -> None:
        """Hand ``target`` [m] to the tasks unless it equals the last one (``value``: its ``tolist()``, if made)."""
        if value is None:
            value = np.asarray(target).tolist()
        if value == self._last:  # NaN never equals: a bad target is always handed over (and refused)
            return
        for task in self._tasks:
            task.set_target(target)
        self._last = value


def timed_solve(
    solver: IkSolver, hierarchy: Hierarchy, kin: Kinematics, dt: float
) -> tuple[np.ndarray, SolveStatus, Sequence[str], str, bool, float]:
    """One solve, timed: everything ``solver.solve`` does, the kinematics it reads from ``kin`` included.

    The loop hands over a fresh snapshot (:meth:`robots.Robot.kinematics`: nothing computed until
    first read), so every method pays for its own kinematics inside this window.

    A solver error of its own domain (:data:`SOLVER_ERRORS`) is a FAILED step with zero velocity.
    Python's cyclic garbage collector is paused during the solve (it runs at the next allocation
    after it, in the loop's own time): a full collection takes milliseconds of the harness's
    objects and would otherwise land, at random, on some method's solve and its time limit.

    Returns:
        (q̇ [rad/s], status, active set, message, the solver's deadline-miss flag, solve time [µs]).
    """
    collecting = gc.isenabled()
    gc.disable()
    wall0 = time.perf_counter_ns()
    try:
        result = solver.solve(hierarchy, kin, dt)
        qdot, status, active, message = result.qdot, result.status, result.active_set, result.message
        missed = bool(result.deadline_miss)
    except SOLVER_ERRORS as exc:  # the solver's own domain (no solution, a task it cannot evaluate)
        qdot, status, active, message = np.zeros(kin.nq), SolveStatus.FAILED, (), f"{type(exc).__name__}: {exc}"
        missed = isinstance(exc, TimeLimitReached)  # the solver's own time-limit check: a deadline miss too
    finally:
        # The method's own call when a simulation guard timed it (its steal-counter reads are not the method's).
        inner_ns = solver.last_call_wall_ns if isinstance(solver, DeadlineGuard) else None
        elapsed_us = (inner_ns if inner_ns is not None else time.perf_counter_ns() - wall0) * 1e-3
        if collecting:
            gc.enable()
    return qdot, status, active, message, missed, elapsed_us


class _Step:
    """One control step of :func:`run_loop`: sense, target, solve, guard, send, record."""

    def __init__(
        self,
        io: RobotIO,
        robot: Robot,
        hierarchy: Hierarchy,
        solver: IkSolver,
        waypoints: WaypointSchedule,
        settings: LoopSettings,
        obstacles: ObstacleSource | None,
        truth: Callable[[Kinematics], Mapping[str, float]] | None,
        predictor: Predictor | None = None,
    ) -> None:
        self.io, self.robot, self.hierarchy, self.solver = io, robot, hierarchy, solver
        self.waypoints, self.truth = waypoints, truth
        # A truth that records the steps computes them at the end (RecordedTruth), else one call a step.
        self.recorded_truth = truth if isinstance(truth, RecordedTruth) else None
        self.dt, self.nq, self.ee_frame = settings.dt, robot.nq, robot.ee_frame
        self.stop_when_blind = settings.stop_when_blind
        set_tasks = hierarchy.set_tasks
        obstacle_tasks = [t for t in set_tasks if isinstance(t, ObstacleDistanceTask)]
        cps = control_points(hierarchy, robot)
        self.events: list[str] = []
        self.gate = SensingGate(obstacles, obstacle_tasks, cps, settings, self.events, predictor)
        self.watch = SetTaskWatch(set_tasks, predicting=predictor is not None)
        self.policy = FallbackPolicy(settings, solver.name, robot.v_max, self.events)
        self.targets = _Targets(ee_position_tasks(hierarchy, robot))
        n_steps = max(1, round(settings.duration_s / settings.dt))
        self.recorder = StepRecorder(n_steps, robot.nq, set_tasks, obstacle_tasks, cps, predictor is not None)
        self.n_steps = n_steps
        if self.recorded_truth is not None:
            self.recorded_truth.start(n_steps)
        self.reference: ControlReference = solver.reference
        # A deadline miss: flagged by the solver's time-limit guard (compare.loop.deadline) when it
        # has one, else a solve longer than ``settings.deadline_s`` (default the control period).
        self.guarded = isinstance(solver, DeadlineGuard)
        self.deadline_us = 1e6 * (settings.deadline_s if settings.deadline_s is not None else settings.dt)
        self.t0 = io.now()

    def run(self, i: int) -> float | None:
        """Step ``i``; returns its loop time [s], or None when no joint reading came (zero sent)."""
        io, robot, gate = self.io, self.robot, self.gate
        reading = io.read_joints()
        t = io.now() - self.t0
        if reading is None:
            io.send_velocity(np.zeros(self.nq))
            return None
        q = reading.q
        # The loop's own snapshot of q: sensing, the waypoints, σ and the status check's rows, the
        # ground truth, each computed once (the method's snapshot below is of the same q).
        kin = robot.kinematics(q)
        gate.step(t, kin)
        ee = kin.frame_position(self.ee_frame)
        target = self.waypoints.update(t, ee)
        target_xyz = target.tolist()
        self.targets.set(target, target_xyz)
        sigmas = self.watch.measure(kin)
        true_d: Mapping[str, float] | None = None
        if self.recorded_truth is not None:
            self.recorded_truth.record(i, kin)
        else:
            true_d = self.truth(kin) if self.truth is not None else {}
        # A fresh snapshot, nothing computed: the method's kinematics fall inside its timed solve.
        solved = timed_solve(self.solver, self.hierarchy, robot.renew(kin), self.dt)
        qdot, status, active, message, missed, solve_us = solved
        command, fallback, status = self.policy.decide(t, qdot, status, message)
        stopped = gate.blind and self.stop_when_blind
        if stopped:
            command = np.zeros(self.nq)
        io.send_velocity(command)
        if status is SolveStatus.OK and fallback is None and self.watch.unmet(qdot, self.dt, self.reference):
            status = SolveStatus.DEGRADED  # a set task's reference rate missed: the same rule for every method
        rec = self.recorder
        rec.motion(i, t, ee.tolist(), target_xyz, q, command)
        rec.set_tasks(i, sigmas, active)
        rec.distances(i, (gate.measured, gate.source, gate.predicted), true_d)
        missed = missed or (not self.guarded and solve_us > self.deadline_us)
        stop_why = gate.reason if stopped else None
        rec.outcome(i, solve_us, missed, self.waypoints.index, fallback, gate.blind, stop_why, _STATUS_VALUES[status])
        return t

    def table(self) -> pd.DataFrame:
        """The per-step table of the steps run (the recorded ground truth computed now)."""
        if self.recorded_truth is not None:
            self.recorder.true_distances(self.recorded_truth.recorded(self.recorder.n))
        return self.recorder.frame()


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
    predictor: Predictor | None = None,
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
        predictor: Prediction of the obstacles' motion handed to the obstacle tasks (``[prediction]``).

    Returns:
        :class:`LoopOutput`. A solver error of its own domain (:data:`SOLVER_ERRORS`) is a FAILED
        step and the loop goes on with the fallback.

    Raises:
        Exception: Any other exception of the solver (a bug): the robot is stopped first.
    """
    step = _Step(io, robot, hierarchy, solver, waypoints, settings, obstacles, truth, predictor)
    start_wall = time.perf_counter()
    next_progress = 0.0
    try:
        for i in range(step.n_steps):
            t = step.run(i)
            if t is None:
                io.wait()
                continue
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
    return LoopOutput(step.table(), wall, io.now() - step.t0, step.events)
