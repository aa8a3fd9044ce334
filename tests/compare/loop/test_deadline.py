"""Solver time limits: a late answer is treated as not arrived, in simulation and on a wall clock.

* simulation: the step whose solve took longer than the limit (CPU time by default) is FAILED,
  uses the fallback and counts as a deadline miss; simulated time is never delayed;
* wall clock (hardware): a stalled backend never delays a step beyond its limit plus one step;
* QP methods: the budget reaches the backends that have a time limit of their own, and a level
  with no time left is given up (DEGRADED keeping the levels above).
"""

from __future__ import annotations

import math
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import qpsolvers
import scipy.sparse as spa

import robots
from compare.config import load_config, parse_config
from compare.loop.closed_loop import run_loop, timed_solve
from compare.loop.deadline import MeasuredDeadline, ThreadedDeadline, guard_solver
from compare.loop.robot_io import JointReading, RobotIO
from compare.methods import make_method
from compare.run import loop_setup, run_method
from qp_baseline.backends import BACKENDS
from qp_baseline.hqp import HqpSolver, available_qp_solvers
from qp_baseline.time_limits import CallBudget, TimeLimitReached
from tests.qp_baseline.helpers import DT, position_level
from tpik.hierarchy import Hierarchy
from tpik.step_result import SolverBase, StepResult

CONFIGS = Path(__file__).resolve().parents[3] / "configs"
BACKEND_TIME_LIMIT = {name: b.time_limit_key for name, b in BACKENDS.items() if b.time_limit_key is not None}


@pytest.fixture(scope="module")
def robot() -> robots.Robot:
    return robots.load("jaco2")


def _config(duration: float = 0.6, methods: tuple[str, ...] = ("tpik",), **solver_limit: Any):
    """Case 1 with ``[loop] realtime = true``: the simulation enforces the limit (the guard under test)."""
    config, _ = load_config(CONFIGS / "case1.toml")
    data = config.model_dump(mode="python")
    data["scenario"].update(duration_s=duration, time_scale=1.0, sensing="geometric")
    data["methods"] = {"names": list(methods), "settings": {}}
    data["solver_limit"] = solver_limit
    data["loop"] = {"realtime": True}
    return parse_config(data)


def _busy(seconds: float) -> None:
    """Burn CPU for ``seconds`` of this thread's CPU time (a backend iterating, not sleeping)."""
    start = time.thread_time()
    while time.thread_time() - start < seconds:
        pass


class SlowOnCalls(SolverBase):
    """A real method that is slow on chosen calls: busy (CPU) or asleep (wall only)."""

    def __init__(self, solver: Any, calls: set[int], seconds: float, busy: bool = True) -> None:
        self._solver, self.name = solver, solver.name
        self.calls, self.seconds, self.busy = calls, seconds, busy
        self.n = 0

    def solve(self, hierarchy: Hierarchy, kin: Any, dt: float) -> StepResult:
        k = self.n
        self.n += 1
        result = self._solver.solve(hierarchy, kin, dt)
        if k in self.calls:
            _busy(self.seconds) if self.busy else time.sleep(self.seconds)
        return result


def _slow_method(monkeypatch, calls: set[int], seconds: float, busy: bool = True) -> None:
    real = make_method
    monkeypatch.setattr("compare.run.make_method", lambda *a, **k: SlowOnCalls(real(*a, **k), calls, seconds, busy))


# ------------------------------------------------------------------ simulation, [loop] realtime = true


def test_a_late_solve_in_simulation_is_a_failed_deadline_miss_and_sim_time_does_not_wait(robot, monkeypatch):
    slow_calls = set(range(20, 25))
    _slow_method(monkeypatch, slow_calls, 0.02)  # 20 ms of CPU against the default 5 ms (0.5 × 10 ms)
    result = run_method(_config(), "tpik", robot)
    steps, summary = result["steps"], result["summary"]
    slow = {c - summary["warmup_steps"] for c in slow_calls}  # the untimed warm-up solves come first
    miss = steps["deadline_miss"].to_numpy()
    assert set(np.flatnonzero(miss)) == slow
    assert summary["deadline_misses"] == 5 and summary["solver_limit"] == {"time_limit_s": 0.005, "clock": "cpu"}
    late = steps.iloc[sorted(slow)]
    assert (late["status"] == "failed").all() and late["fallback"].all()
    assert all("deadline: no answer (cpu time) within the 5 ms solver time limit" in r for r in late["reason"])
    qdot = steps[[f"qdot_{j}" for j in range(1, 8)]].to_numpy()
    assert np.all(qdot[sorted(slow)] == 0.0)  # the fallback ("zero"), not the late answer
    assert np.abs(qdot[min(slow) - 1]).max() > 1e-3  # the arm was moving: the late answers were not zero
    assert not steps["fallback"].iloc[max(slow) + 1 :].any()  # on time again: its answers are used
    np.testing.assert_allclose(np.diff(steps["t"].to_numpy()), DT, atol=1e-9)  # simulated time never waits


def test_a_limit_below_any_solve_makes_every_step_a_miss(robot):
    result = run_method(_config(duration=0.2, time_limit_s=1e-7), "tpik", robot)
    summary = result["summary"]
    assert summary["deadline_misses"] == summary["fallbacks"] == summary["failures"] == summary["steps"] == 20


def test_without_a_limit_a_miss_is_a_solve_longer_than_the_control_period(robot, monkeypatch):
    _slow_method(monkeypatch, {8, 9}, 0.012, busy=False)
    result = run_method(_config(duration=0.15, enabled=False), "tpik", robot)
    steps = result["steps"]
    miss = steps["deadline_miss"].to_numpy()
    first = 8 - result["summary"]["warmup_steps"]  # the untimed warm-up solves come first
    assert miss[first] and miss[first + 1]
    np.testing.assert_array_equal(miss, steps["solve_time_us"].to_numpy() > 1e4)  # wall time > 10 ms
    assert not steps["fallback"].any()  # no limit: the late answers are used
    assert result["summary"]["solver_limit"] == {"time_limit_s": None, "clock": None}


def test_an_injected_solver_timeout_counts_as_a_deadline_miss(robot):
    config = _config(duration=0.3)
    data = config.model_dump(mode="python")
    data["faults"] = {"inject": [{"kind": "solver_timeout", "start_s": 0.1, "end_s": 0.2, "delay_s": 0.05}]}
    result = run_method(parse_config(data), "tpik", robot)
    steps = result["steps"]
    np.testing.assert_array_equal(steps["deadline_miss"].to_numpy(), steps["fault:solver_timeout"].to_numpy())
    assert result["summary"]["deadline_misses"] == 10


class _Sleeper(SolverBase):
    name = "sleeper"

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds

    def solve(self, hierarchy: Any, kin: Any, dt: float) -> StepResult:
        time.sleep(self.seconds)
        return StepResult(np.ones(kin.nq))


def test_the_cpu_clock_ignores_time_the_solver_did_not_compute_and_the_wall_clock_does_not(robot):
    kin = robot.kinematics(robot.home)
    on_cpu = MeasuredDeadline(_Sleeper(0.02), 0.005, "cpu").solve(None, kin, DT)  # type: ignore[arg-type]
    on_wall = MeasuredDeadline(_Sleeper(0.02), 0.005, "wall").solve(None, kin, DT)  # type: ignore[arg-type]
    assert on_cpu.ok and np.all(on_cpu.qdot == 1.0) and not on_cpu.deadline_miss
    assert not on_wall.ok and on_wall.deadline_miss and on_wall.extras["took_s"] >= 0.02
    assert np.all(on_wall.qdot == 0.0)


# ------------------------------------------------------------------ wall clock (hardware)


class RealTimeIO(RobotIO):
    """A kinematic arm on the wall clock: ``wait`` sleeps to the next tick, as a hardware backend."""

    def __init__(self, robot: robots.Robot, q0: np.ndarray, dt: float) -> None:
        self.dt, self.nq = dt, robot.nq
        self.q = q0.copy()
        self.qdot = np.zeros(robot.nq)
        self._t0 = time.perf_counter()
        self._tick = 0
        self.read_at: list[float] = []
        self.sent_at: list[float] = []

    def now(self) -> float:
        return time.perf_counter() - self._t0

    def read_joints(self) -> JointReading:
        self.read_at.append(self.now())
        return JointReading(self.q.copy(), self.qdot.copy(), self.now())

    def read_depth(self) -> None:
        return None

    def send_velocity(self, qdot: np.ndarray) -> None:
        self.sent_at.append(self.now())
        self.qdot = np.array(qdot, dtype=float)

    def wait(self) -> None:
        self.q = self.q + self.qdot * self.dt
        self._tick += 1
        time.sleep(max(0.0, self._tick * self.dt - self.now()))


@pytest.mark.timeout(120)
def test_a_stalled_solve_on_the_wall_clock_never_delays_a_step_beyond_its_limit_plus_one_step(robot):
    dt, limit, stall_s = 0.05, 0.02, 1.0  # a slow loop, so that the bound holds on a shared machine
    config = _config(duration=2.0)
    hierarchy = config.build_hierarchy(robot)
    stalled = SlowOnCalls(make_method("tpik", robot), {5}, stall_s, busy=False)
    guard = guard_solver(stalled, config.solver_limit.model_copy(update={"time_limit_s": limit}), dt, realtime=True)
    assert isinstance(guard, ThreadedDeadline)
    io = RealTimeIO(robot, robot.home, dt)
    schedule, settings = loop_setup(config, robot.frame_position(robot.home, "end_effector"))
    settings.dt, settings.duration_s = dt, 2.0
    try:
        out = run_loop(io, robot, hierarchy, guard, schedule, settings)
    finally:
        guard.close()
    steps = out.steps
    n = len(io.read_at)  # stop() sends one more (zero) command at the end
    delay = np.array(io.sent_at[:n]) - np.array(io.read_at)
    assert delay.max() <= limit + dt  # without the guard the stalled step alone takes 1 s
    miss = steps["deadline_miss"].to_numpy()
    # Step 5 waits its 20 ms, then the steps of the stall get the fallback at once.
    episode = 5
    while episode < len(miss) and miss[episode]:
        episode += 1
    assert episode - 5 >= round(stall_s / dt) - 2
    waiting = steps["reason"].iloc[6:episode]
    assert waiting.str.contains("the previous solve is still running").sum() >= episode - 8
    assert steps["fallback"].to_numpy()[miss].all() and (steps["status"][miss] == "failed").all()
    qdot = steps[[f"qdot_{j}" for j in range(1, 8)]].to_numpy()
    assert np.all(qdot[miss] == 0.0)
    recovered = ~miss[episode:] & ~steps["fallback"].to_numpy()[episode:]
    assert recovered.sum() >= 0.8 * recovered.size > 0  # answers in time again once the stall is over


def test_the_threaded_guard_passes_answers_and_errors_through(robot):
    kin = robot.kinematics(robot.home)

    class Boom(SolverBase):
        name = "boom"

        def solve(self, hierarchy: Any, kin: Any, dt: float) -> StepResult:
            raise ZeroDivisionError("a bug in the method")

    fine = ThreadedDeadline(_Sleeper(0.0), 0.5)
    assert np.all(fine.solve(None, kin, DT).qdot == 1.0)  # type: ignore[arg-type]
    fine.close()
    broken = ThreadedDeadline(Boom(), 0.5)
    with pytest.raises(ZeroDivisionError, match="a bug in the method"):
        broken.solve(None, kin, DT)  # type: ignore[arg-type]
    broken.close()


# ------------------------------------------------------------------ QP backends


def _random_qp(solver: str, n: int = 150, m: int = 200):
    rng = np.random.default_rng(0)
    M = rng.standard_normal((n, n))
    P, q = M @ M.T + np.eye(n), rng.standard_normal(n)
    G, h = rng.standard_normal((m, n)), rng.random(m)
    if solver in ("osqp", "clarabel"):
        return qpsolvers.Problem(spa.csc_matrix(P), q, spa.csc_matrix(G), h)
    return qpsolvers.Problem(P, q, G, h)


@pytest.mark.parametrize("solver", sorted(BACKEND_TIME_LIMIT))
def test_the_backends_time_limit_setting_is_the_one_they_honour(solver):
    if solver not in qpsolvers.available_solvers:
        pytest.skip(f"{solver} not installed")
    problem = _random_qp(solver)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # qpsolvers warns on the cut solve
        assert qpsolvers.solve_problem(problem, solver=solver).found
        cut = qpsolvers.solve_problem(problem, solver=solver, **{BACKEND_TIME_LIMIT[solver]: 1e-7})
    assert not cut.found


def test_a_budget_hands_the_backend_what_is_left_on_the_wall_clock_only():
    wall = CallBudget(1.0, "wall")
    wall.start()
    kwargs = wall.backend_kwargs("osqp")
    assert 0.9 < kwargs["time_limit"] <= 1.0  # all that is left: no share held back
    assert wall.backend_kwargs("proxqp") == {} and wall.backend_kwargs("quadprog") == {}
    cpu = CallBudget(0.05, "cpu")
    cpu.start()
    assert cpu.backend_kwargs("osqp") == {}  # backends count wall time: not on the CPU clock
    spent = CallBudget(0.001, "cpu")
    spent.start()
    _busy(0.002)
    with pytest.raises(TimeLimitReached, match="time limit of 1 ms reached before the daqp call"):
        spent.backend_kwargs("daqp")


def test_the_solvers_own_time_limit_check_is_a_failed_deadline_miss(robot):
    """``TimeLimitReached`` (the QP methods' check before a backend call) counts like the guard's miss."""
    hierarchy, kin = _two_levels(robot)

    class OutOfTime(SolverBase):
        name = "out-of-time"

        def solve(self, hierarchy: Hierarchy, kin: Any, dt: float) -> StepResult:
            raise TimeLimitReached("time limit of 5 ms reached before the daqp call")

    qdot, status, _, message, missed, _ = timed_solve(OutOfTime(), hierarchy, kin, DT)  # type: ignore[arg-type]
    assert missed and status.value == "failed" and "TimeLimitReached" in message
    assert np.array_equal(qdot, np.zeros(robot.nq))


def _two_levels(robot: robots.Robot) -> tuple[Hierarchy, Any]:
    kin = robot.kinematics(robot.home)
    ee, elbow = kin.frame_position("end_effector"), kin.frame_position("link_4")
    levels = [position_level(ee + np.array([0.05, 0.0, 0.0])), position_level(elbow + [0.0, 0.03, 0.0], frame="link_4")]
    return Hierarchy(levels), kin


@pytest.mark.parametrize("solver", available_qp_solvers())
def test_hqp_gives_each_backend_call_the_budget_left(robot, monkeypatch, solver):
    hierarchy, kin = _two_levels(robot)
    hqp = HqpSolver(robot, solver, {"unconstrained_first": False})
    hqp.solve(hierarchy, kin, DT)  # compiled kernels loaded first: on a loaded CI worker that alone can take the budget
    hqp.set_time_limit(0.5, "wall")
    seen: list[dict[str, Any]] = []
    import qp_baseline.hqp as hqp_module

    real = hqp_module._solve_quietly

    def spy(problem, solver_name, quiet, **kwargs):
        seen.append(kwargs)
        return real(problem, solver_name, quiet, **kwargs)

    monkeypatch.setattr(hqp_module, "_solve_quietly", spy)
    assert hqp.solve(hierarchy, kin, DT).ok
    assert len(seen) >= 2
    key = BACKEND_TIME_LIMIT.get(solver)
    if key is None:
        assert all("time_limit" not in k for k in seen)
    else:
        limits = [k[key] for k in seen]
        assert all(0.0 < x <= 0.5 for x in limits) and limits == sorted(limits, reverse=True)


def test_hqp_gives_up_a_level_with_no_time_left_and_keeps_the_levels_above(robot, monkeypatch):
    hierarchy, kin = _two_levels(robot)
    first_only = Hierarchy(hierarchy.levels[:1])
    reference = HqpSolver(robot, "daqp", {"unconstrained_first": False}).solve(first_only, kin, DT)
    hqp = HqpSolver(robot, "daqp", {"unconstrained_first": False})
    hqp.set_time_limit(0.005, "cpu")
    import qp_baseline.hqp as hqp_module

    real = hqp_module._solve_quietly

    def slow_first_level(problem, solver_name, quiet, **kwargs):
        _busy(0.006)  # the first level's QP uses up the whole budget
        return real(problem, solver_name, quiet, **kwargs)

    monkeypatch.setattr(hqp_module, "_solve_quietly", slow_first_level)
    result = hqp.solve(hierarchy, kin, DT)
    assert result.status.value == "degraded"
    assert "time limit of 5 ms reached before the daqp call" in result.message
    assert "kept the solution of the levels above" in result.message
    np.testing.assert_allclose(result.qdot, reference.qdot, atol=1e-9)
    # Behind the guard the whole step is late (6 ms > 5 ms): not used at all.
    late = guard_solver(hqp, _config().solver_limit, 0.01).solve(hierarchy, kin, DT)
    assert not late.ok and late.deadline_miss


def test_mink_gives_its_backend_the_budget(robot, monkeypatch):
    config = _config(methods=("mink",))
    hierarchy = config.build_hierarchy(robot)
    kin = robot.kinematics(robot.home)
    for task in hierarchy.tasks:
        if hasattr(task, "set_target"):
            task.set_target(kin.frame_position("end_effector") + np.array([0.02, 0.0, 0.0]))
    mink = make_method("mink", robot)
    limit = config.solver_limit.model_copy(update={"simulation_clock": "wall", "time_limit_s": 0.5})
    guard = guard_solver(mink, limit, 0.01)  # a generous limit: this checks the wiring, not the speed
    seen: list[dict[str, Any]] = []
    real = qpsolvers.solve_problem

    def spy(problem, solver, **kwargs):
        seen.append(kwargs)
        return real(problem, solver=solver, **kwargs)

    monkeypatch.setattr(qpsolvers, "solve_problem", spy)
    assert guard.solve(hierarchy, kin, 0.01).ok
    assert len(seen) == 1 and 0.45 < seen[0]["time_limit"] <= 0.5  # mink uses daqp; no share held back
    assert math.isclose(guard.deadline_s, 0.5)
