r"""One level of the cascade solved for :math:`\dot q = \dot q^*_{k-1} + Z z`.

A level's strictly convex QP has a unique solution: when its unconstrained minimiser (one linear
solve) meets every row and the box it *is* that solution and no backend is called
(``unconstrained_first``). A level that needed the backend at the previous step goes straight to
it (its active set usually persists; the answer is the same either way). Otherwise the level's
QP (:class:`~qp_baseline.hqp_level.LevelQpBuilder`) goes to the checked solve, optionally warm
started from the level's previous-step answer. The accepted q̇ is clipped into the box, and
violations of earlier rows within tolerance are absorbed into their bounds, so that every later
level stays feasible by construction.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from qp_baseline.backend_call import backend_iterations
from qp_baseline.cascade_kernels import binds, clip_into, feasible, raise_to
from qp_baseline.certificate import Certificate
from qp_baseline.exceptions import NoSolutionFound
from qp_baseline.hqp_level import CascadeLevel, LevelQpBuilder, warm_start_point
from qp_baseline.hqp_settings import CascadeSettings
from qp_baseline.level_qp import LevelAnswer, LevelQp, QpCheck
from qp_baseline.qp_problem import DenseProblem

LevelQpSolve = Callable[[DenseProblem, QpCheck, int, np.ndarray | None], LevelAnswer]
"""``(problem, check, level, initvals) -> LevelAnswer``: the checked solve of one level QP."""


@dataclass
class CascadeMemory:
    """What the cascade carries from one step to the next, per level (reset with the hierarchy).

    Attributes:
        previous: Each level's q̇ answer at the previous step (warm start).
        needed_backend: Whether a constraint bound the level's answer at the previous step.
    """

    previous: dict[int, np.ndarray] = field(default_factory=dict)
    needed_backend: dict[int, bool] = field(default_factory=dict)


@dataclass
class SolveTime:
    """Seconds of one step spent in backend calls and in the levels' unconstrained linear solves."""

    seconds: float = 0.0


class LevelOutcome(NamedTuple):
    """How one level was solved.

    Attributes:
        qdot: q̇ after the level, in the box. Shape (n,).
        backend_calls: 1 if the backend was called, else 0.
        iterations: Backend iterations, where reported.
        retried: 1 if the retry gave the answer, else 0.
        doubt: Why the answer is not certified; empty when it is, or when no backend was called.
    """

    qdot: np.ndarray
    backend_calls: int
    iterations: int | None
    retried: int
    doubt: str


class LevelSolver:
    """Solves the levels of one step (module docstring).

    Args:
        builder: Builds each level's QP.
        settings: The cascade's settings.
        memory: The levels' previous-step state (read and updated).
        clock: The step's solve time (the unconstrained solves are added to it).
        solve_problem: The checked solve of a level QP.
        log: When a list, every backend-solved level QP is appended to it.
    """

    def __init__(
        self,
        builder: LevelQpBuilder,
        settings: CascadeSettings,
        memory: CascadeMemory,
        clock: SolveTime,
        solve_problem: LevelQpSolve,
        log: list[LevelQp] | None,
    ) -> None:
        self.builder = builder
        self.settings = settings
        self.memory = memory
        self.clock = clock
        self.solve_problem = solve_problem
        self.log = log
        self.certificates: dict[int, Certificate] = {}
        """This step's certificate of each backend-solved level."""
        self._no_rows = np.zeros(0)

    def solve(self, lv: CascadeLevel) -> LevelOutcome:
        """Solve level ``lv``; ``lv.h_rel[:lv.c0]`` is raised in place by violations within tolerance.

        Raises:
            NoSolutionFound: Neither attempt gave a usable answer (feasible, no worse than the
                known feasible point).
        """
        lv.at_zero = lv.Z is None and not lv.qd.any()  # start of the cascade: spare the products with qd
        Pz, qz = self.builder.cost(lv)
        if self.settings.options.unconstrained_first and not self.memory.needed_backend.get(lv.k, False):
            cand = self._unconstrained(lv, Pz, qz)
            if cand is not None:
                self.memory.previous[lv.k] = cand
                return LevelOutcome(cand, 0, None, 0, "")
        problem, check, slacks = self.builder.build(lv, Pz, qz)
        answer = self._backend_answer(lv, problem, check, slacks)
        cand = self._accept(lv, answer.x)
        doubt = "" if answer.certified else ((answer.certificate.reason if answer.certificate else "") or "not checked")
        return LevelOutcome(cand, 1, backend_iterations(answer.solution), answer.retried, doubt)

    def _unconstrained(self, lv: CascadeLevel, Pz: np.ndarray | None, qz: np.ndarray | None) -> np.ndarray | None:
        """The level's unconstrained minimiser when it meets every row and the box, else None."""
        qd, Z = lv.qd, lv.Z
        if Pz is not None and qz is not None:
            t0 = time.perf_counter()
            z = np.linalg.solve(Pz, -qz)
            self.clock.seconds += time.perf_counter() - t0
            cand = z if lv.at_zero else (qd + z if Z is None else qd + Z @ z)
        else:
            # Pz = εI: the minimiser is qd without its component in span(Z).
            cand = np.zeros(qd.shape[0]) if Z is None else qd - Z @ (Z.T @ qd)
        c1 = lv.c1
        Gc = lv.G_all[:c1] @ cand if c1 else self._no_rows
        return cand if feasible(cand, lv.lb, lv.ub, Gc, lv.h_rel[:c1]) else None

    def _backend_answer(self, lv: CascadeLevel, problem: DenseProblem, check: QpCheck, slacks: int) -> LevelAnswer:
        """The level's QP through the checked solve (warm start, log, certificate kept).

        Raises:
            NoSolutionFound: As the checked solve.
        """
        k = lv.k
        start = None
        if self.settings.warm_start and k in self.memory.previous:
            start = warm_start_point(self.memory.previous[k], lv, problem)
        try:
            answer = self.solve_problem(problem, check, k, start)
        except NoSolutionFound as exc:
            if self.log is not None:
                self.log.append(LevelQp.record(k, problem, check, None, exc.certificate, slacks))
            raise
        if self.log is not None:
            self.log.append(LevelQp.record(k, problem, check, answer.x, answer.certificate, slacks))
        if answer.certificate is not None:
            self.certificates[k] = answer.certificate
        return answer

    def _accept(self, lv: CascadeLevel, x: np.ndarray) -> np.ndarray:
        """q̇ of the accepted answer, clipped into the box; earlier rows and the memory updated."""
        cand = lv.qdot(x[: lv.d])
        clip_into(cand, lv.lb, lv.ub)
        # Next step, go straight to the backend only if a constraint binds now.
        Gc = lv.G_all[: lv.c1] @ cand
        self.memory.needed_backend[lv.k] = binds(cand, lv.lb, lv.ub, Gc, lv.h_rel[: lv.c1], self.settings.tolerance)
        if lv.c0:
            # Absorb violations within tolerance, so later levels stay feasible by construction.
            raise_to(lv.h_rel[: lv.c0], Gc if lv.c0 == lv.c1 else lv.G_all[: lv.c0] @ cand)
        self.memory.previous[lv.k] = cand
        return cand
