"""What every solver returns for one control step, and the interface they share (docs/design.md §2–3)."""

from __future__ import annotations

import enum
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from tpik.reference import DEFAULT_REFERENCE, ControlReference

if TYPE_CHECKING:
    from robots import Kinematics
    from tpik.hierarchy import Hierarchy


class SolveStatus(enum.Enum):
    """Outcome of one solve.

    OK: the solution is exact for every feasible level.
    DEGRADED: a valid, safe velocity, but some level was relaxed (slack > 0, damping,
        velocity scaling or an exhausted active-set search): see ``StepResult.message``.
    FAILED: no valid solution; ``qdot`` is zero and the caller applies its fallback.
    """

    OK = "ok"
    DEGRADED = "degraded"
    FAILED = "failed"


@dataclass
class StepResult:
    """Joint velocity command and report of one solve (the qpsolvers ``Solution`` idea).

    Unpacks as ``qdot, report = solver.solve(hierarchy, kin, dt)``.

    Attributes:
        qdot: Joint velocity [rad/s], always finite and within the limits. Shape (n,).
        status: :class:`SolveStatus`.
        active_set: Names of the set-based tasks inserted as equality tasks this step.
        build_time_s: Time spent building the problem (kinematics excluded) [s].
        solve_time_s: Time spent solving [s].
        damping: Damping λ used per level name (DLS; 0 = undamped).
        message: Why the status is not OK (empty otherwise).
        extras: Solver-specific data (slacks, iterations, candidate count, ...).
        deadline_miss: No answer within the time limit (the velocity is the fallback's zero).
    """

    qdot: np.ndarray
    status: SolveStatus = SolveStatus.OK
    active_set: tuple[str, ...] = ()
    build_time_s: float = 0.0
    solve_time_s: float = 0.0
    damping: dict[str, float] = field(default_factory=dict)
    message: str = ""
    extras: dict[str, Any] = field(default_factory=dict)
    deadline_miss: bool = False

    def __iter__(self) -> Iterator[Any]:
        yield self.qdot
        yield self

    @property
    def ok(self) -> bool:
        """Whether a usable velocity was produced (OK or DEGRADED)."""
        return self.status is not SolveStatus.FAILED


class IkSolver(Protocol):
    """The one interface of TPIK, HQP, the mink peer and every wrapper the loop puts around them.

    Attributes:
        name: The method's name.
        reference: The control reference it tracks (:mod:`tpik.reference`); the loop judges its
            steps against the same one.
    """

    name: str
    reference: ControlReference

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """One control step: joint velocities for the hierarchy at ``kin.q`` over ``dt`` [s]."""
        ...

    def set_time_limit(self, limit_s: float | None, clock: Any = "wall") -> None:
        """Limit every later ``solve`` to ``limit_s`` [s] on ``clock`` (None: no limit)."""
        ...

    def close(self) -> None:
        """Release what the solver holds (threads, processes); it is not used afterwards."""
        ...


class SolverBase:
    """The parts of :class:`IkSolver` a solver may leave as they are.

    The default reference, no time budget of its own (a time limit is then enforced around it
    only), nothing to release.
    """

    name: str = "solver"
    reference: ControlReference = DEFAULT_REFERENCE

    def set_time_limit(self, limit_s: float | None, clock: Any = "wall") -> None:
        """Nothing to do: the solver has no budget of its own."""

    def close(self) -> None:
        """Nothing to release."""


def failed(n: int, message: str, deadline_miss: bool = False, **extras: Any) -> StepResult:
    """A FAILED result with a zero (safe) velocity of size ``n``."""
    return StepResult(
        np.zeros(n), SolveStatus.FAILED, message=message, deadline_miss=deadline_miss, extras=dict(extras)
    )
