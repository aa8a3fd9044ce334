"""Time budget of one solve call, and the QP backends' own time-limit settings.

A method's solve may take at most a budget (``[solver_limit]`` of the scenario, the same for
every method). One rule for every method: an answer counts when the whole call — its kinematics,
its problem, its solver, its bookkeeping — ends within the budget; nothing is held back from any
method's solver. A QP-based method checks the budget before each backend call and does not start
one once the budget is used up (the answer would be late whatever it is: the caller's guard
discards it, as it discards a late TPIK answer); it hands the backend what is left, where the
backend has a time limit of its own. The names and units, checked against
each backend's documentation and the installed versions (qpsolvers 4.13 passes them through), are
the records' ``time_limit_key`` (:data:`qp_baseline.backends.BACKENDS`):

========== ================ ===========================================================
backend    setting          notes
========== ================ ===========================================================
OSQP       ``time_limit``   seconds, 0 = none; checked between ADMM iterations (setup
                            and polishing are not interrupted)
Clarabel   ``time_limit``   seconds (fractional); checked between interior-point iterations
DAQP       ``time_limit``   seconds, 0 = none; checked between active-set iterations
ProxQP     —                proxsuite 0.8 has ``max_iter`` only
PIQP       —                piqp 0.7 has ``max_iter`` only
quadprog   —                no settings at all
========== ================ ===========================================================

A backend stops at the end of the iteration that crosses its limit, not at the limit: the
caller's wall-clock guard (``compare.loop.deadline``) still measures the whole solve. Backend
limits count wall time, so they are only set when the budget is on the wall clock
(:attr:`CallBudget.backend_limits`); on the CPU clock (simulation) the budget is checked
between calls only. The simulation's time-limit guard may share its own :class:`CallClock` (the
CPU clock that knows the hypervisor's steal, ``compare.loop.steal_clock``): before refusing a
backend call, the budget then takes out the steal counted since the guard began the call.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from qp_baseline.backends import BACKENDS
from qp_baseline.exceptions import HqpError
from tpik.step_result import SolverBase

CLOCKS: dict[str, Callable[[], float]] = {"wall": time.perf_counter, "cpu": time.thread_time}
"""Clocks a budget can be measured on [s]."""


class TimeLimitReached(HqpError):
    """The solve's time budget is used up before a backend call."""


class CallClock(Protocol):
    """The guard's CPU clock, begun at each solve call: it knows what the machine took meanwhile."""

    def began_s(self) -> float:
        """Thread CPU time (``time.thread_time``) when the current call began [s]."""
        ...

    def stolen_s(self) -> float:
        """CPU time the machine took from the thread since the call began [s] (may read the OS)."""
        ...


class CallBudget:
    """The time budget of one solve call: :meth:`start` at the call, :meth:`backend_kwargs` before each QP.

    Args:
        limit_s: Budget of one call [s].
        clock: ``wall`` (``time.perf_counter``), ``cpu`` (``time.thread_time``), or a
            :class:`CallClock` that the caller begins at every call (a CPU clock: no backend limits).
    """

    def __init__(self, limit_s: float, clock: str | CallClock = "wall") -> None:
        if not (math.isfinite(limit_s) and limit_s > 0.0):
            raise ValueError(f"time limit must be finite and > 0 s, got {limit_s}")
        self.shared: CallClock | None = None
        if not isinstance(clock, str):
            self.shared, clock = clock, "cpu"
        if clock not in CLOCKS:
            raise ValueError(f"unknown clock '{clock}'; available: {', '.join(CLOCKS)}")
        self.limit_s = float(limit_s)
        self.clock = clock
        self._now = CLOCKS[clock]
        self._start = self._now()

    @property
    def backend_limits(self) -> bool:
        """Whether backends get a time limit (only on the wall clock: theirs counts wall time)."""
        return self.clock == "wall"

    def start(self) -> None:
        """Start the budget of a new call."""
        self._start = self._now()

    def remaining_s(self) -> float:
        """Budget left [s] (negative once overrun)."""
        return self.limit_s - (self._now() - self._start)

    def _stolen_s(self) -> float:
        """What the machine took during this call, when the shared clock was begun for it [s]."""
        shared = self.shared
        if shared is None or not 0.0 <= self._start - shared.began_s() <= self.limit_s:
            return 0.0  # no shared clock, or one not begun for this call (a direct solve)
        return shared.stolen_s()

    def backend_kwargs(self, solver: str) -> dict[str, Any]:
        """Keyword arguments limiting one backend call to the budget left (no reserve: module docstring).

        Raises:
            TimeLimitReached: The budget is used up: the call's answer would be late.
        """
        left = self.remaining_s()
        if left <= 0.0:  # what the machine took is not the solver's
            left += self._stolen_s()
        if left <= 0.0:
            raise TimeLimitReached(f"time limit of {1e3 * self.limit_s:.3g} ms reached before the {solver} call")
        backend = BACKENDS.get(solver)
        key = backend.time_limit_key if backend is not None else None
        return {key: left} if key is not None and self.backend_limits else {}


class TimeLimited(SolverBase):
    """Mixin of the QP-based methods: :meth:`set_time_limit` gives every solve call a :class:`CallBudget`."""

    budget: CallBudget | None = None

    def set_time_limit(self, limit_s: float | None, clock: str | CallClock = "wall") -> None:
        """Limit every ``solve`` call to ``limit_s`` [s] (None: no limit).

        Each backend call gets what is left; with nothing left the backend is not called and the
        QP counts as failed (HQP: level 0 → FAILED, a later level → DEGRADED keeping the levels
        above; mink: FAILED). The call is then already past its limit: the guard around it
        (``compare.loop.deadline``) reports a FAILED deadline miss, as for every method.
        """
        self.budget = None if limit_s is None else CallBudget(limit_s, clock)

    def _budget_kwargs(self, solver: str, kwargs: Mapping[str, Any]) -> Mapping[str, Any]:
        """``kwargs`` with the backend's time limit for this call (unchanged without a budget)."""
        return kwargs if self.budget is None else {**kwargs, **self.budget.backend_kwargs(solver)}
