"""Per-call time limit of every method's solve (``[solver_limit]``), the same for all methods.

A solve that has not answered within its limit is treated as *not having arrived*: the step
is FAILED, the loop's fallback acts, and the step counts as a deadline miss (per-step
``deadline_miss``, ``deadline_misses`` in ``summary.json``). Two guards, one per kind of clock:

* **Simulation** (:class:`MeasuredDeadline`): simulated time does not wait for the solver, so the
  call is simply measured and a late answer discarded. The measure is the solver thread's CPU
  time by default (``simulation_clock = "cpu"``): what the solve costs on a core of its own,
  whatever else the machine runs, so the verdict — and every result that depends on it — is
  the same on a loaded laptop and on an idle cluster node. In a virtual machine that clock also
  runs while the hypervisor has taken the CPU away; that steal is taken out of a call that looks
  late (:mod:`compare.loop.steal_clock`). ``"wall"`` measures elapsed time.
* **Hardware** (:class:`ThreadedDeadline`): wall clock, and the loop must not block. The solve
  runs in a worker thread; the loop waits for it at most the limit, then sends the fallback.
  While a stalled solve is still running, later steps do not wait at all (they use the
  fallback at once, and count as misses); its answer, when it comes, is dropped. No step is
  therefore delayed by more than the limit (plus the thread hand-off), however long the
  backend stalls. A backend that holds Python's GIL while it stalls cannot be preempted by a
  thread: that is what the QP backends' own time limits are for
  (:mod:`qp_baseline.time_limits`), set on the wall clock to what is left of the budget.

One rule for every method: the call is timed whole (the loop hands over a kinematics snapshot
with nothing computed, so each method's kinematics are inside it) and its answer counts when the
call ends within the limit. Methods with a QP backend (HQP, mink) also get the budget itself
(``set_time_limit``): they check it before every backend call and start none once it is used up
(no share is held back: :mod:`qp_baseline.time_limits`), an answer that would be late anyway.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from compare.config import SolverLimitConfig
from compare.loop.steal_clock import STAT, StealClock
from robots import Kinematics
from tpik.hierarchy import Hierarchy
from tpik.step_result import IkSolver, StepResult, failed

CLOCKS: dict[str, Callable[[], float]] = {"cpu": time.thread_time, "wall": time.perf_counter}
"""What a :class:`MeasuredDeadline` measures a solve on."""


def late_result(nq: int, limit_s: float, why: str) -> StepResult:
    """The FAILED deadline miss that stands for an answer later than ``limit_s`` [s] (zero velocity)."""
    # The message names the configured limit only, so that events stay reproducible.
    return failed(nq, f"deadline: {why} within the {1e3 * limit_s:.3g} ms solver time limit", deadline_miss=True)


class DeadlineGuard:
    """What the loop reads of a time-limit guard around a method (both guards below are one).

    Attributes:
        deadline_s: The limit [s].
        last_call_wall_ns: Wall time of the method's own call in the last solve [ns] (the
            guard's bookkeeping left out), or None when not measured separately.
    """

    deadline_s: float
    last_call_wall_ns: int | None = None


class MeasuredDeadline(DeadlineGuard):
    """Simulation guard: measure the call, discard an answer later than the limit.

    On the CPU clock the hypervisor's steal is taken out of a call that looks late
    (:mod:`compare.loop.steal_clock`, ``[solver_limit] exclude_steal``): a call whose own time,
    without the steal counted on its virtual CPU meanwhile, is within the limit keeps its answer
    and counts in :attr:`steal_excused`, not as a deadline miss.

    Args:
        solver: The method (wrapped; its ``set_time_limit`` is called when it has one).
        limit_s: The limit [s].
        clock: ``cpu`` (the calling thread's CPU time) or ``wall``.
        exclude_steal: On the CPU clock, take the hypervisor's steal out (where it can be read).
        stat: Where the steal is read (a test's own file; default ``/proc/stat``).
    """

    def __init__(
        self, solver: IkSolver, limit_s: float, clock: str = "cpu", exclude_steal: bool = True, stat: Path = STAT
    ) -> None:
        self._inner = solver
        self.name = solver.name
        self.deadline_s = float(limit_s)
        self.clock = clock
        self._now = CLOCKS[clock]
        self._steal: StealClock | None = None
        if clock == "cpu" and exclude_steal:
            steal = StealClock(stat)
            self._steal = steal if steal.available else None
        self.worst_s = 0.0
        """Longest solve so far on ``clock`` [s], steal taken out (the guard wraps the solver after its warm-up)."""
        self.steal_excused = 0
        """Calls late on the raw CPU clock but within the limit once the steal is taken out."""
        self.stolen_s = 0.0
        """Steal taken out of those calls [s]."""
        self.last_call_wall_ns: int | None = None
        """Wall time of the method's own call in the last :meth:`solve` [ns] (the guard's reads left out)."""
        solver.set_time_limit(self.deadline_s, self._steal if self._steal is not None else clock)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    @property
    def steal_clock(self) -> StealClock | None:
        """The clock of the calls when it takes steal out (shared with the method's own budget), else None."""
        return self._steal

    @property
    def excludes_steal(self) -> bool:
        """Whether the hypervisor's steal is taken out of late calls (CPU clock, counter readable)."""
        return self._steal is not None

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """The method's solve, or a FAILED deadline miss when it took longer than the limit."""
        steal = self._steal
        self.last_call_wall_ns = None
        # The wall window encloses the CPU window (CPU time <= the elapsed time around it); the
        # steal counters are read before both (harness time, not the method's).
        if steal is None:
            wall0 = time.perf_counter_ns()
            start = self._now()
            result = self._inner.solve(hierarchy, kin, dt)
            took = self._now() - start
        else:
            steal.begin()
            wall0 = steal.began_wall_ns()
            result = self._inner.solve(hierarchy, kin, dt)
            took = steal.elapsed_s()
        self.last_call_wall_ns = time.perf_counter_ns() - wall0
        if steal is not None and took > self.deadline_s:
            took, stolen = steal.own_elapsed_s()
            if took <= self.deadline_s:
                self.steal_excused += 1
                self.stolen_s += stolen
                result.extras["stolen_s"] = stolen
        if took > self.worst_s:
            self.worst_s = took
        if took > self.deadline_s:
            late = late_result(kin.nq, self.deadline_s, f"no answer ({self.clock} time)")
            late.extras["took_s"] = took
            return late
        return result

    def close(self) -> None:
        """Nothing to release (same interface as :class:`ThreadedDeadline`)."""


@dataclass
class _Call:
    args: tuple[Any, ...]
    done: threading.Event = field(default_factory=threading.Event)
    result: StepResult | None = None
    error: BaseException | None = None


class ThreadedDeadline(DeadlineGuard):
    """Hardware guard: the solve runs in a worker thread; the loop never waits past the limit.

    Args:
        solver: The method (its ``set_time_limit`` is called with the wall clock when it has one).
        limit_s: The limit [s].
    """

    clock = "wall"

    def __init__(self, solver: IkSolver, limit_s: float) -> None:
        self._inner = solver
        self.name = solver.name
        self.deadline_s = float(limit_s)
        solver.set_time_limit(self.deadline_s, "wall")
        self._requests: queue.SimpleQueue[_Call | None] = queue.SimpleQueue()
        self._running: _Call | None = None  # a call past its limit that has not returned yet
        # A daemon thread: a backend stalled for good must not keep the process alive at exit.
        self._thread = threading.Thread(target=self._serve, name=f"{self.name}-solve", daemon=True)
        self._thread.start()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def _serve(self) -> None:
        while True:
            call = self._requests.get()
            if call is None:
                return
            try:
                call.result = self._inner.solve(*call.args)
            except BaseException as exc:  # handed to the caller, who decides (as without a thread)
                call.error = exc
            call.done.set()

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """The method's answer if it comes within the limit; a FAILED deadline miss otherwise.

        Raises:
            Whatever the method raised (re-raised here, as if called directly).
        """
        if self._running is not None:
            if not self._running.done.is_set():
                return late_result(kin.nq, self.deadline_s, "the previous solve is still running: no answer")
            self._running = None  # its late answer is dropped
        call = _Call((hierarchy, kin, dt))
        self._requests.put(call)
        if not call.done.wait(self.deadline_s):
            self._running = call
            return late_result(kin.nq, self.deadline_s, "no answer")
        if call.error is not None:
            raise call.error
        assert call.result is not None
        return call.result

    def close(self) -> None:
        """Stop the worker thread once it is idle (a stalled one is left to die with the process)."""
        self._requests.put(None)


def guard_solver(solver: IkSolver, config: SolverLimitConfig, dt: float, realtime: bool = False) -> IkSolver:
    """``solver`` behind the time limit of ``config`` for control period ``dt`` [s].

    Args:
        solver: The method (possibly already wrapped by the fault injector).
        config: ``[solver_limit]``.
        dt: Control period [s].
        realtime: Hardware (wall clock, :class:`ThreadedDeadline`); else simulation
            (:class:`MeasuredDeadline` on ``config.simulation_clock``).

    Returns:
        The guarded solver, or ``solver`` itself when the limit is disabled.
    """
    limit = config.limit_s(dt)
    if limit is None:
        return solver
    if realtime:
        return ThreadedDeadline(solver, limit)
    return MeasuredDeadline(solver, limit, config.simulation_clock, config.exclude_steal)
