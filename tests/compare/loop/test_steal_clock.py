"""The CPU clock without the hypervisor's steal: what a late solve is judged on in simulation.

A fake ``/proc/stat`` stands in for the kernel's: the test's "hypervisor" adds steal ticks to it
while a solve burns CPU. A solve late only by what was stolen keeps its answer (counted as
steal-excused, not as a deadline miss); a solve late by its own work is still a miss; the QP
methods' budget sees the same steal.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from compare.config import SolverLimitConfig
from compare.loop.deadline import MeasuredDeadline, guard_solver
from compare.loop.steal_clock import StealClock, parse_steal
from qp_baseline.time_limits import CallBudget, TimeLimitReached
from tpik.step_result import SolverBase, SolveStatus, StepResult

STAT_TEXT = (
    "cpu  100 0 50 900 5 0 3 {total} 0 0\n"
    "cpu0 50 0 25 450 2 0 1 {s0} 0 0\n"
    "cpu1 50 0 25 450 3 0 2 {s1} 0 0\n"
    "intr 12345 0 0 0\n"
    "ctxt 999\n"
)


def _write_stat(path: Path, steal: tuple[int, int]) -> None:
    path.write_text(STAT_TEXT.format(total=sum(steal), s0=steal[0], s1=steal[1]))


def _busy(seconds: float) -> None:
    start = time.thread_time()
    while time.thread_time() - start < seconds:
        pass


class StealingSolver(SolverBase):
    """Burns ``cpu_s`` of CPU time per call while the fake hypervisor adds ``ticks`` of steal to every CPU."""

    name = "stealing"

    def __init__(self, stat: Path, cpu_s: float, ticks: int) -> None:
        self.stat, self.cpu_s, self.ticks = stat, cpu_s, ticks
        self.steal = (10, 20)
        self.calls = 0

    def solve(self, hierarchy: Any, kin: Any, dt: float) -> StepResult:
        self.calls += 1
        self.steal = (self.steal[0] + self.ticks, self.steal[1] + self.ticks)
        _write_stat(self.stat, self.steal)
        _busy(self.cpu_s)
        return StepResult(np.full(7, 0.1), SolveStatus.OK, ())


class _Kin:
    nq = 7


@pytest.fixture
def stat(tmp_path: Path) -> Path:
    path = tmp_path / "stat"
    _write_stat(path, (10, 20))
    return path


def test_parse_steal_reads_the_eighth_value_of_every_cpu_line_and_refuses_a_malformed_one() -> None:
    assert parse_steal(STAT_TEXT.format(total=7, s0=3, s1=4).encode()) == (3, 4)
    assert parse_steal(b"cpu  1 2 3\ncpu0 1 2 3\n") is None
    assert parse_steal(b"intr 1 2\n") is None


def test_the_clock_takes_out_the_steal_counted_on_its_cpu_during_the_call(stat: Path) -> None:
    clock = StealClock(stat)
    if not clock.available:
        pytest.skip("no sched_getcpu on this platform")
    clock.begin()
    _write_stat(stat, (13, 23))  # three ticks on every CPU while the call runs
    _busy(0.002)
    own, stolen = clock.own_elapsed_s()
    assert stolen == pytest.approx(3 * clock.tick_s)
    assert own == 0.0  # 2 ms of work minus 30 ms stolen: never below zero
    clock.begin()
    _busy(0.002)
    own, stolen = clock.own_elapsed_s()
    assert stolen == 0.0 and own >= 0.002


def test_a_thread_that_moved_between_two_cpus_takes_the_larger_count_not_the_sum(stat: Path) -> None:
    clock = StealClock(stat)
    if not clock.available:
        pytest.skip("no sched_getcpu on this platform")
    cpus = iter([0, 1])
    clock._getcpu = lambda: next(cpus)  # starts on cpu0, ends on cpu1
    clock.begin()
    _write_stat(stat, (12, 22))  # one host pause of two ticks, counted on both virtual CPUs
    assert clock.stolen_s() == pytest.approx(2 * clock.tick_s)  # once, not four ticks
    cpus = iter([0, 1])
    clock.begin()
    _write_stat(stat, (15, 23))  # three more ticks on cpu0, one on cpu1
    assert clock.stolen_s() == pytest.approx(3 * clock.tick_s)


def test_a_solve_late_only_by_the_steal_keeps_its_answer_and_is_not_a_miss(stat: Path) -> None:
    inner = StealingSolver(stat, cpu_s=0.012, ticks=2)  # 12 ms of CPU of which ~20 ms "stolen"
    guard = MeasuredDeadline(inner, 0.005, "cpu", stat=stat)
    if not guard.excludes_steal:
        pytest.skip("no sched_getcpu on this platform")
    result = guard.solve(None, _Kin(), 0.01)  # type: ignore[arg-type]
    assert result.status is SolveStatus.OK and not result.deadline_miss
    assert result.extras["stolen_s"] == pytest.approx(0.02)
    assert guard.steal_excused == 1 and guard.stolen_s == pytest.approx(0.02)
    assert guard.worst_s < 0.005  # the worst step is judged without the steal


def test_a_solve_late_by_its_own_work_is_still_a_miss_whatever_was_stolen(stat: Path) -> None:
    inner = StealingSolver(stat, cpu_s=0.030, ticks=1)  # 30 ms of CPU, only ~10 ms stolen
    guard = MeasuredDeadline(inner, 0.005, "cpu", stat=stat)
    if not guard.excludes_steal:
        pytest.skip("no sched_getcpu on this platform")
    result = guard.solve(None, _Kin(), 0.01)  # type: ignore[arg-type]
    assert result.status is SolveStatus.FAILED and result.deadline_miss
    assert guard.steal_excused == 0
    assert 0.015 <= result.extras["took_s"] < 0.030  # own time: the tick taken out


def test_without_steal_a_late_solve_is_a_miss_and_exclude_steal_false_counts_the_steal(stat: Path) -> None:
    guard = MeasuredDeadline(StealingSolver(stat, cpu_s=0.008, ticks=0), 0.005, "cpu", stat=stat)
    assert guard.solve(None, _Kin(), 0.01).deadline_miss  # type: ignore[arg-type]
    plain = MeasuredDeadline(StealingSolver(stat, cpu_s=0.008, ticks=5), 0.005, "cpu", exclude_steal=False, stat=stat)
    assert not plain.excludes_steal
    assert plain.solve(None, _Kin(), 0.01).deadline_miss  # type: ignore[arg-type]
    assert plain.steal_excused == 0


def test_the_config_switch_reaches_the_guard() -> None:
    on = guard_solver(StealingSolver(Path("/nonexistent"), 0.0, 0), SolverLimitConfig(), 0.01)
    off = guard_solver(StealingSolver(Path("/nonexistent"), 0.0, 0), SolverLimitConfig(exclude_steal=False), 0.01)
    assert isinstance(on, MeasuredDeadline) and isinstance(off, MeasuredDeadline)
    assert not off.excludes_steal
    assert on.excludes_steal == StealClock().available


class FakeClock:
    """A :class:`~qp_baseline.time_limits.CallClock` that reports a fixed steal since its begin."""

    def __init__(self, stolen_s: float) -> None:
        self.stolen = stolen_s
        self.t0 = time.thread_time()

    def began_s(self) -> float:
        return self.t0

    def stolen_s(self) -> float:
        return self.stolen


def test_the_qp_budget_takes_out_the_steal_of_the_guards_clock_before_refusing_a_backend_call() -> None:
    budget = CallBudget(0.005, FakeClock(0.0))
    budget.start()
    _busy(0.006)
    with pytest.raises(TimeLimitReached):
        budget.backend_kwargs("daqp")
    budget = CallBudget(0.005, FakeClock(0.010))  # 6 ms taken, 10 ms of it stolen: time is left
    budget.start()
    _busy(0.006)
    assert budget.backend_kwargs("daqp") == {}  # a CPU clock: no backend limit, but no refusal
    # A clock not begun for this call (begun long before the budget's start) gives no excuse.
    stale = FakeClock(1.0)
    stale.t0 -= 10.0
    budget = CallBudget(0.005, stale)
    budget.start()
    _busy(0.006)
    with pytest.raises(TimeLimitReached):
        budget.backend_kwargs("daqp")


def test_the_steps_solve_time_is_the_methods_own_call_not_the_guards_counter_reads(stat: Path, monkeypatch) -> None:
    from compare.loop.closed_loop import timed_solve

    guard = MeasuredDeadline(StealingSolver(stat, cpu_s=0.0, ticks=0), 0.005, "cpu", stat=stat)
    if not guard.excludes_steal:
        pytest.skip("no sched_getcpu on this platform")
    slow_begin = guard._steal.begin  # type: ignore[union-attr]

    def begin() -> None:
        _busy(0.004)  # a counter read made slow: harness time, not the method's
        slow_begin()

    monkeypatch.setattr(guard._steal, "begin", begin)
    wall0 = time.perf_counter_ns()
    *_, missed, solve_us = timed_solve(guard, None, _Kin(), 0.01)  # type: ignore[arg-type]
    total_us = (time.perf_counter_ns() - wall0) * 1e-3
    assert not missed
    assert guard.last_call_wall_ns is not None
    assert solve_us == pytest.approx(guard.last_call_wall_ns * 1e-3)  # the method's own call, as the guard timed it
    assert total_us - solve_us >= 3500.0  # the 4 ms of CPU in the counter read are not in it (any machine load)
