r"""The verdict on one backend answer of a cascade QP: certified, usable, or rejected with a reason.

With ``certify`` on, an answer is judged by its certificate (:mod:`qp_baseline.certificate`),
whatever status the backend reported: with the backend's multipliers first, then — when it is
nearly optimal — after a KKT polish of its active set (:mod:`qp_baseline.polish`), then with
multipliers recovered for the answer itself. An answer that is not certified but feasible within
``tolerance`` and no worse than the known feasible point is kept as *usable* (the caller reports
the level). With ``certify`` off, an answer is accepted on the backend's status, the constraints
and the known feasible point alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import qpsolvers

from qp_baseline.certificate import Certificate, certify
from qp_baseline.certificate_dense import certify_dense
from qp_baseline.hqp_settings import CascadeSettings
from qp_baseline.level_qp import LevelAnswer, QpCheck
from qp_baseline.polish import polish
from qp_baseline.qp_problem import DenseProblem


@dataclass
class Trail:
    """What the attempts of one QP left: last backend answer, its certificate, why, a fallback."""

    solution: Any = None
    certificate: Certificate | None = None
    reason: str = ""
    usable: LevelAnswer | None = None


class AnswerJudge:
    """Judges the backend answers of the cascade's QPs.

    Args:
        solver: Backend name (in the reasons).
        settings: The cascade's settings (tolerances, ``certify``, ``kkt_polish``).
    """

    def __init__(self, solver: str, settings: CascadeSettings) -> None:
        self.solver = solver
        self.tolerance = settings.tolerance
        self.certify = settings.options.certify
        self.kkt_polish = settings.options.kkt_polish
        self.tolerances = settings.certificate_tolerances

    def judge(
        self, problem: DenseProblem, check: QpCheck, solution: qpsolvers.Solution, attempt: int, trail: Trail
    ) -> LevelAnswer | None:
        """The accepted answer of one backend call; None (and why, in ``trail``) when not accepted.

        ``attempt`` is 0 for the first call, 1 for the retry.
        """
        x = solution.x
        if x is None or (not solution.found and not self.certify):
            trail.reason = f"{self.solver} reported no solution"
            return None
        x = np.asarray(x, dtype=float)
        if x.shape != problem.q.shape or not np.isfinite(x).all():
            trail.reason = f"{self.solver} returned a non-finite or misshaped solution"
            return None
        if not self.certify:
            return self._accept_on_status(problem, check, x, solution, attempt, trail)
        if check.refine is not None:
            x = check.refine(x)
        return self._certified_answer(problem, check, x, solution, attempt, trail)

    def _accept_on_status(
        self,
        problem: DenseProblem,
        check: QpCheck,
        x: np.ndarray,
        solution: qpsolvers.Solution,
        attempt: int,
        trail: Trail,
    ) -> LevelAnswer | None:
        """The checks of ``certify = false``: constraints within tolerance, no worse than x0."""
        tol, f0 = self.tolerance, check.f0
        G, h = problem.G, problem.h
        viol = max((problem.lb - x).max(), (x - problem.ub).max(), (G @ x - h).max() if h.size else -math.inf)
        if viol > tol:
            trail.reason = f"{self.solver} answer violates its constraints by {viol:.3g} (tolerance {tol:g})"
            return None
        f = float(x @ (0.5 * (problem.P @ x) + problem.q))
        if f > f0 + tol * (1.0 + abs(f0)):
            trail.reason = f"{self.solver} answer is worse than a known feasible point ({f:.6g} > {f0:.6g})"
            return None
        return LevelAnswer(x, solution, attempt, None, True)

    def _certified_answer(
        self,
        problem: DenseProblem,
        check: QpCheck,
        x: np.ndarray,
        solution: qpsolvers.Solution,
        attempt: int,
        trail: Trail,
    ) -> LevelAnswer | None:
        """Judge ``x``: the backend's multipliers, then the KKT polish, then recovered multipliers.

        An answer that is not certified but usable (feasible within tolerance, no worse than x0)
        is kept in ``trail`` as the fallback.
        """
        tol, f0 = self.tolerance, check.f0
        z, z_box = getattr(solution, "z", None), getattr(solution, "z_box", None)
        cert = self.certificate(problem, check, x, z, z_box, recover=False)
        trail.certificate = cert
        if cert.passed:
            return LevelAnswer(x, solution, attempt, cert, True)
        polished = self._polished(problem, check, x, z, z_box, cert, solution, attempt)
        if polished is not None:
            return polished
        if cert.primal_residual <= tol:
            cert = self.certificate(problem, check, x, None, None, recover=True)
            trail.certificate = cert
            if cert.passed:
                return LevelAnswer(x, solution, attempt, cert, True)
        trail.reason = self._rejection(cert, solution, f0)
        if trail.usable is None and cert.primal_residual <= tol and cert.objective <= f0 + tol * (1.0 + abs(f0)):
            trail.usable = LevelAnswer(x, solution, attempt, cert, False)
        return None

    def _polished(
        self,
        problem: DenseProblem,
        check: QpCheck,
        x: np.ndarray,
        z: np.ndarray | None,
        z_box: np.ndarray | None,
        cert: Certificate,
        solution: qpsolvers.Solution,
        attempt: int,
    ) -> LevelAnswer | None:
        """A certified KKT polish of a near-optimal answer (nearly feasible, no worse than x0), or None."""
        tol, f0 = self.tolerance, check.f0
        near = cert.primal_residual <= 100.0 * tol and cert.objective <= f0 + tol * (1.0 + abs(f0))
        if not (self.kkt_polish and near):
            return None
        # The active set from the answer alone first (rows it meets within 1e-9: interior-point
        # multipliers of nearly active rows mislead), then from its multipliers.
        for z_start, zb_start, active in ((None, None, 1e-9), (z, z_box, tol)):
            polished = polish(problem, x, z_start, zb_start, active=active)
            if polished is None or polished.x is None:
                continue
            xp = check.refine(polished.x) if check.refine is not None else polished.x
            cert_p = self.certificate(problem, check, xp, polished.z, polished.z_box, recover=False)
            if cert_p.passed:
                return LevelAnswer(xp, solution, attempt, cert_p, True)
        return None

    def _rejection(self, cert: Certificate, solution: qpsolvers.Solution, f0: float) -> str:
        """Why an answer with certificate ``cert`` is not accepted (the message of the failure)."""
        tol = self.tolerance
        if cert.primal_residual > tol:
            reason = f"{self.solver} answer violates its constraints by {cert.primal_residual:.3g} (tolerance {tol:g})"
        elif cert.objective > f0 and "known feasible point" in cert.reason:
            reason = f"{self.solver} answer is worse than a known feasible point ({cert.objective:.6g} > {f0:.6g})"
        else:
            reason = f"{self.solver} answer not certified: {cert.reason}"
        return reason + ("" if solution.found else f" ({self.solver} reported no solution)")

    def certificate(
        self,
        problem: DenseProblem,
        check: QpCheck,
        x: np.ndarray,
        z: np.ndarray | None,
        z_box: np.ndarray | None,
        recover: bool,
    ) -> Certificate:
        """:func:`~qp_baseline.certificate.certify` of ``x`` with the cascade's tolerances.

        The cascade's level QPs (dense, finite box, a curvature on every variable) go through
        :func:`~qp_baseline.certificate_dense.certify_dense`: the same verdict, a passing one compiled.
        """
        level_value = None if check.level_value is None else check.level_value(x)
        if isinstance(check.curvature, np.ndarray):
            return certify_dense(
                problem,
                x,
                z,
                z_box,
                check.curvature,
                feasible_objective=check.f0,
                level_value=level_value,
                modulus=check.modulus,
                tolerances=self.tolerances,
                recover=recover,
            )
        return certify(
            problem,
            x,
            z=z,
            z_box=z_box,
            feasible_objective=check.f0,
            level_value=level_value,
            curvature=check.curvature,
            modulus=check.modulus,
            tolerances=self.tolerances,
            recover=recover,
        )
