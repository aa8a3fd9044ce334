"""Time budget of one solve call, and the QP backends' own time-limit settings.

A method's solve may take at most a budget (``[solver_limit]`` of the scenario, the same for
every method). A QP-based method checks it before each backend call and hands the backend what
is left, where the backend has a time limit of its own. The names and units, checked against
each backend's documentation and the installed versions (qpsolvers 4.13 passes them through):

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
between calls only.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from typing import Any

from qp_baseline.exceptions import HqpError

BACKEND_TIME_LIMIT: dict[str, str] = {"osqp": "time_limit", "clarabel": "time_limit", "daqp": "time_limit"}
"""Backend → name of its time-limit setting [s] (module docstring)."""

CLOCKS: dict[str, Callable[[], float]] = {"wall": time.perf_counter, "cpu": time.thread_time}
"""Clocks a budget can be measured on [s]."""

RESERVE_FRACTION = 0.1
"""Share of the budget kept back from the backend for the work after its answer (checks, the
levels' bookkeeping), so that an answer cut at the backend's limit still arrives in time."""


class TimeLimitReached(HqpError):
    """The solve's time budget is used up before a backend call."""


class CallBudget:
    """The time budget of one solve call: :meth:`start` at the call, :meth:`backend_kwargs` before each QP.

    Args:
        limit_s: Budget of one call [s].
        clock: ``wall`` (``time.perf_counter``) or ``cpu`` (``time.thread_time``).
    """

    def __init__(self, limit_s: float, clock: str = "wall") -> None:
        if not (math.isfinite(limit_s) and limit_s > 0.0):
            raise ValueError(f"time limit must be finite and > 0 s, got {limit_s}")
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

    def backend_kwargs(self, solver: str) -> dict[str, Any]:
        """Keyword arguments limiting one backend call to the budget left (minus a reserve).

        Raises:
            TimeLimitReached: Nothing is left for another backend call.
        """
        left = self.remaining_s() - RESERVE_FRACTION * self.limit_s
        if left <= 0.0:
            raise TimeLimitReached(f"time limit of {1e3 * self.limit_s:.3g} ms reached before the {solver} call")
        key = BACKEND_TIME_LIMIT.get(solver)
        return {key: left} if key is not None and self.backend_limits else {}


class TimeLimited:
    """Mixin of the QP-based methods: :meth:`set_time_limit` gives every solve call a :class:`CallBudget`."""

    budget: CallBudget | None = None

    def set_time_limit(self, limit_s: float | None, clock: str = "wall") -> None:
        """Limit every ``solve`` call to ``limit_s`` [s] (None: no limit).

        Each backend call gets what is left; with nothing left the backend is not called and the
        QP counts as failed (HQP: level 0 → FAILED, a later level → DEGRADED keeping the levels
        above; mink: FAILED).
        """
        self.budget = None if limit_s is None else CallBudget(limit_s, clock)

    def _budget_kwargs(self, solver: str, kwargs: Mapping[str, Any]) -> Mapping[str, Any]:
        """``kwargs`` with the backend's time limit for this call (unchanged without a budget)."""
        return kwargs if self.budget is None else {**kwargs, **self.budget.backend_kwargs(solver)}
