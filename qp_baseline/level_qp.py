r"""What the HQP cascade keeps beside one QP (a :class:`~qp_baseline.qp_problem.DenseProblem`).

* :class:`QpCheck`: what judging an answer needs that the QP does not carry (a feasible point,
  the level objective, the curvature of the bound);
* :class:`LevelAnswer`: the answer the checked solve took (:meth:`qp_baseline.hqp.HqpSolver.solve_problem`);
* :class:`LevelQp`: one level QP as the backend saw it and the answer taken, what
  :attr:`qp_baseline.hqp.HqpSolver.qp_log` collects (when it is a list) and
  :mod:`compare.bench.qp_export` writes as a qpbenchmark test set.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import qpsolvers

from qp_baseline.certificate import Certificate
from qp_baseline.qp_problem import DenseProblem, without_empty_rows


@dataclass(frozen=True)
class QpCheck:
    r"""How the answers of one QP are judged, beyond the QP itself.

    Attributes:
        x0: A feasible point. Shape (d,).
        f0: The objective at ``x0``.
        level_value: ½-scaled level objective of an answer (see
            :attr:`~qp_baseline.certificate.Tolerances.level`), None for a plain QP.
        refine: Exact map applied to an answer before it is judged (the cascade sets the
            slacks of the level's rows to their minimal value ``max(0, G q̇ − h)``), or None.
        curvature: :math:`c` with :math:`P \succeq \mathrm{diag}(c)`, sharpening the certificate's
            bound (:func:`~qp_baseline.certificate.certify`), or None.
        modulus: :math:`\mu` with :math:`P \succeq \mu I` when the answer itself must be within
            tolerance of the optimum (the min-norm level), not only its objective; or None.
    """

    x0: np.ndarray
    f0: float
    level_value: Callable[[np.ndarray], float] | None = None
    refine: Callable[[np.ndarray], np.ndarray] | None = None
    curvature: np.ndarray | None = None
    modulus: float | None = None


@dataclass(frozen=True)
class LevelAnswer:
    """The answer of one checked QP solve.

    Unpacks as ``x, solution, retried = hqp.solve_qp(...)``, the way
    :class:`~tpik.step_result.StepResult` unpacks as ``qdot, report``.

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
    r"""One level QP: :math:`\min \tfrac12 x^TPx + q^Tx` s.t. :math:`Gx \le h,\ lb \le x \le ub`, and its answer.

    Attributes:
        level: Priority level index (the number of task levels for the min-norm level).
        qp: The QP (copies of the cascade's arrays).
        x_feasible: A feasible point known before the solve. Shape (d,).
        x: The answer the cascade took (None: the level was given up).
        certificate: Certificate of that answer (or of the last rejected one).
        level_offset: Constant :math:`c` with level objective :math:`\tfrac12 f_k \approx f(x) + c`
            at the answer (up to the regularisation term; task levels; None for the min-norm level).
        slacks: Number of slack variables, the last entries of x (one per row of the level).
    """

    level: int
    qp: DenseProblem
    x_feasible: np.ndarray
    x: np.ndarray | None
    certificate: Certificate | None
    level_offset: float | None
    slacks: int = 0

    @classmethod
    def record(
        cls,
        level: int,
        problem: DenseProblem,
        check: QpCheck,
        x: np.ndarray | None,
        certificate: Certificate | None,
        slacks: int,
    ) -> LevelQp:
        """The record of a solved (or given up, ``x`` None) level QP; copies, the cascade reuses its buffers."""
        offset = None
        if check.level_value is not None:
            probe = x if x is not None else check.x0
            offset = check.level_value(probe) - problem.objective(probe)
        copied = DenseProblem(
            problem.P.copy(),
            problem.q.copy(),
            problem.G.copy(),
            problem.h.copy(),
            lb=problem.lb.copy(),
            ub=problem.ub.copy(),
        )
        return cls(level, copied, check.x0.copy(), None if x is None else x.copy(), certificate, offset, slacks)

    @property
    def P(self) -> np.ndarray:
        """Cost matrix. Shape (d, d)."""
        return self.qp.P

    @property
    def q(self) -> np.ndarray:
        """Cost vector. Shape (d,)."""
        return self.qp.q

    @property
    def G(self) -> np.ndarray:
        """Inequality matrix. Shape (m, d)."""
        return self.qp.G

    @property
    def h(self) -> np.ndarray:
        """Inequality bounds. Shape (m,)."""
        return self.qp.h

    @property
    def lb(self) -> np.ndarray:
        """Lower bounds. Shape (d,)."""
        return self.qp.lb

    @property
    def ub(self) -> np.ndarray:
        """Upper bounds. Shape (d,)."""
        return self.qp.ub

    def problem(self) -> qpsolvers.Problem:
        """The QP as qpsolvers saves it: no equality rows, G and h None when there is no row."""
        return without_empty_rows(self.qp)

    def objective(self, x: np.ndarray) -> float:
        r""":math:`\tfrac12 x^TPx + q^Tx`."""
        return self.qp.objective(x)
