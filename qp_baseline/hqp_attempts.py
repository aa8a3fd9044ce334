"""One QP of the cascade solved and checked: the attempts in order, the first accepted answer.

The first attempt uses the backend's settings (and the caller's warm start); the retry, when on,
the backend's retry settings (:data:`qp_baseline.backends.BACKENDS`), :data:`RETRY_REGULARIZATION`
added to the diagonal of P (the answer is still judged against the original P) and the first
attempt's usable answer, or the known feasible point, as its start. Each answer is judged by
:class:`~qp_baseline.hqp_verify.AnswerJudge`. When none is accepted, the first usable one is
returned uncertified; when none is usable, :class:`~qp_baseline.exceptions.NoSolutionFound`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import qpsolvers

from qp_baseline.exceptions import NoSolutionFound
from qp_baseline.hqp_verify import AnswerJudge, Trail
from qp_baseline.level_qp import LevelAnswer, QpCheck
from qp_baseline.qp_problem import DenseProblem

RETRY_REGULARIZATION = 1e-7
"""Extra diagonal added to the Hessian on the retry (near-singular Hessians: DAQP, quadprog). Small
enough that the retry's answer still passes the certificate of the original problem (1e-6 shifted
well-conditioned levels by about the certificate's tolerance)."""

BackendCall = Callable[[DenseProblem, np.ndarray | None, Mapping[str, Any]], qpsolvers.Solution]
"""``(problem, initvals, kwargs) -> Solution``: one backend call."""


def solve_checked(
    problem: DenseProblem,
    check: QpCheck,
    level: int,
    initvals: np.ndarray | None,
    attempts: Sequence[Mapping[str, Any]],
    call_backend: BackendCall,
    judge: AnswerJudge,
) -> LevelAnswer:
    """Solve ``problem`` (module docstring).

    Args:
        problem: The QP.
        check: How its answers are judged.
        level: Priority level reported by :class:`NoSolutionFound`.
        initvals: Warm start of the first attempt, or None.
        attempts: Backend keyword arguments of the first attempt, then of the retry (if any).
        call_backend: The backend call.
        judge: The judge of the answers.

    Raises:
        NoSolutionFound: No attempt gave a usable answer (``solution`` holds the last answer,
            ``certificate`` its certificate).
    """
    trail = Trail()
    for attempt, kwargs in enumerate(attempts):
        start = initvals
        if attempt:
            # The retry starts from the first attempt's usable answer, when there is one.
            start = trail.usable.x if trail.usable is not None else check.x0
        answer = _attempt(problem, check, attempt, kwargs, start, trail, call_backend, judge)
        if answer is not None:
            return answer
    if trail.usable is not None:
        return trail.usable
    raise NoSolutionFound(level, trail.solution, trail.reason, trail.certificate)


def _attempt(
    problem: DenseProblem,
    check: QpCheck,
    attempt: int,
    kwargs: Mapping[str, Any],
    start: np.ndarray | None,
    trail: Trail,
    call_backend: BackendCall,
    judge: AnswerJudge,
) -> LevelAnswer | None:
    """One backend call (the retry's Hessian regularised) and its judgement; None when not accepted."""
    posed = problem
    if attempt:
        P_try = problem.P.copy()
        P_try.flat[:: problem.q.shape[0] + 1] += RETRY_REGULARIZATION
        posed = DenseProblem(P_try, problem.q, problem.G, problem.h, lb=problem.lb, ub=problem.ub)
    try:
        solution = call_backend(posed, start, kwargs)
    except Exception as exc:  # noqa: BLE001 - a backend error is a failure of this QP
        trail.solution, trail.reason = None, f"{judge.solver} raised {type(exc).__name__}: {exc}"
        return None
    trail.solution = solution
    return judge.judge(problem, check, solution, attempt, trail)
