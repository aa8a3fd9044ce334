r"""One level QP of the HQP cascade as a backend saw it, and the answer the cascade took.

:class:`LevelQp` records are what :attr:`qp_baseline.hqp.HqpSolver.qp_log` collects (when it
is a list) and what :mod:`compare.bench.qp_export` writes as a qpbenchmark test set.
:class:`LevelAnswer` is what :meth:`qp_baseline.hqp.HqpSolver.solve_qp` returns.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import qpsolvers

from qp_baseline.certificate import Certificate


@dataclass(frozen=True)
class LevelAnswer:
    """The answer of one checked level solve.

    Unpacks as ``x, solution, retried = hqp.solve_qp(...)`` (what ``solve_qp`` returned before
    the certificate), the way :class:`~tpik.step_result.StepResult` unpacks as ``qdot, report``.

    Attributes:
        x: The accepted answer. Shape (d,).
        solution: The backend's ``qpsolvers.Solution`` it came from.
        retried: 1 if the retry gave it, else 0.
        certificate: Its certificate (None when certification is off).
        certified: Whether it met the certificate's tolerances (True when certification is off
            and the answer passed the plain checks).
    """

    x: np.ndarray
    solution: Any
    retried: int
    certificate: Certificate | None
    certified: bool

    def __iter__(self) -> Iterator[Any]:
        yield self.x
        yield self.solution
        yield self.retried


@dataclass(frozen=True)
class LevelQp:
    r"""One level QP: :math:`\min \tfrac12 x^TPx + q^Tx` s.t. :math:`Gx \le h,\ lb \le x \le ub`.

    Attributes:
        level: Priority level index (the number of task levels for the min-norm level).
        P: Cost matrix. Shape (d, d).
        q: Cost vector. Shape (d,).
        G: Inequality matrix. Shape (m, d).
        h: Inequality bounds. Shape (m,).
        lb: Lower bounds. Shape (d,).
        ub: Upper bounds. Shape (d,).
        x_feasible: A feasible point known before the solve. Shape (d,).
        x: The answer the cascade took (None: the level was given up).
        certificate: Certificate of that answer (or of the last rejected one).
        level_offset: Constant :math:`c` with level objective :math:`\tfrac12 f_k \approx f(x) + c`
            at the answer (up to the regularisation term; task levels; None for the min-norm level).
        slacks: Number of slack variables, the last entries of x (one per row of the level).
    """

    level: int
    P: np.ndarray
    q: np.ndarray
    G: np.ndarray
    h: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    x_feasible: np.ndarray
    x: np.ndarray | None
    certificate: Certificate | None
    level_offset: float | None
    slacks: int = 0

    def problem(self) -> qpsolvers.Problem:
        """The QP as a dense ``qpsolvers.Problem`` (no equality constraints)."""
        has_rows = self.h.size > 0
        return qpsolvers.Problem(
            self.P, self.q, self.G if has_rows else None, self.h if has_rows else None, lb=self.lb, ub=self.ub
        )

    def objective(self, x: np.ndarray) -> float:
        r""":math:`\tfrac12 x^TPx + q^Tx`."""
        return float(x @ (0.5 * (self.P @ x) + self.q))
