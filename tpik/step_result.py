"""What every solver returns for one control step, and the interface they share (DESIGN §2–3)."""

from __future__ import annotations

import enum
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

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
    """

    qdot: np.ndarray
    status: SolveStatus = SolveStatus.OK
    active_set: tuple[str, ...] = ()
    build_time_s: float = 0.0
    solve_time_s: float = 0.0
    damping: dict[str, float] = field(default_factory=dict)
    message: str = ""
    extras: dict[str, Any] = field(default_factory=dict)

    def __iter__(self) -> Iterator[Any]:
        yield self.qdot
        yield self

    @property
    def ok(self) -> bool:
        """Whether a usable velocity was produced (OK or DEGRADED)."""
        return self.status is not SolveStatus.FAILED

    @property
    def total_time_s(self) -> float:
        """Build + solve time [s]."""
        return self.build_time_s + self.solve_time_s


class IkSolver(Protocol):
    """The one interface of TPIK, HQP and the mink peer: ``solve(hierarchy, kin, dt)``."""

    name: str

    def solve(self, hierarchy: Hierarchy, kin: Kinematics, dt: float) -> StepResult:
        """One control step: joint velocities for the hierarchy at ``kin.q`` over ``dt`` [s]."""
        ...


def failed(n: int, message: str, **extras: Any) -> StepResult:
    """A FAILED result with a zero (safe) velocity of size ``n``."""
    return StepResult(np.zeros(n), SolveStatus.FAILED, message=message, extras=dict(extras))
