r"""The one QP type of the package: a :class:`qpsolvers.Problem`, in a dense form where arithmetic needs one.

.. math::
    \min_x\ \tfrac12 x^TPx + q^Tx \quad\text{s.t.}\quad Gx \le h,\ Ax = b,\ lb \le x \le ub.

:class:`DenseProblem` is a ``qpsolvers.Problem`` whose every field is a dense float array: no
row is an empty ``(0, n)`` matrix instead of None, a missing bound is ``∓inf``. The cascade's
level QPs, the certificate and the reference compute on it; :func:`without_empty_rows` gives
the form a backend or a saved file takes (None where there is no row).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import qpsolvers


class DenseProblem(qpsolvers.Problem):
    """A :class:`qpsolvers.Problem` with every field a dense float array.

    Args:
        P: Cost matrix, dense or sparse. Shape (n, n).
        q: Cost vector. Shape (n,).
        G: Inequality matrix; None: no row. Shape (m, n).
        h: Inequality bounds; None: no row. Shape (m,).
        A: Equality matrix; None: no row. Shape (p, n).
        b: Equality right-hand side; None: no row. Shape (p,).
        lb: Lower bounds; None: ``-inf``. Shape (n,).
        ub: Upper bounds; None: ``+inf``. Shape (n,).
    """

    P: np.ndarray
    q: np.ndarray
    G: np.ndarray
    h: np.ndarray
    A: np.ndarray
    b: np.ndarray
    lb: np.ndarray
    ub: np.ndarray

    def __init__(
        self,
        P: Any,
        q: np.ndarray,
        G: Any = None,
        h: np.ndarray | None = None,
        A: Any = None,
        b: np.ndarray | None = None,
        lb: np.ndarray | None = None,
        ub: np.ndarray | None = None,
    ) -> None:
        q = np.asarray(q, dtype=float)
        n = q.shape[0]
        super().__init__(
            _dense(P, n),
            q,
            np.zeros((0, n)) if G is None else _dense(G, n),
            np.zeros(0) if h is None else np.asarray(h, dtype=float).ravel(),
            np.zeros((0, n)) if A is None else _dense(A, n),
            np.zeros(0) if b is None else np.asarray(b, dtype=float).ravel(),
            np.full(n, -np.inf) if lb is None else np.asarray(lb, dtype=float),
            np.full(n, np.inf) if ub is None else np.asarray(ub, dtype=float),
        )

    def objective(self, x: np.ndarray) -> float:
        r""":math:`\tfrac12 x^TPx + q^Tx`."""
        return float(x @ (0.5 * (self.P @ x) + self.q))


def dense_problem(problem: qpsolvers.Problem) -> DenseProblem:
    """``problem`` as a :class:`DenseProblem` (itself when it is one)."""
    if isinstance(problem, DenseProblem):
        return problem
    return DenseProblem(*problem.unpack())


def without_empty_rows(problem: DenseProblem) -> qpsolvers.Problem:
    """The same QP with None for what it does not have: the form backends and ``Problem.save`` take.

    None for an empty G and h, an empty A and b, a lower bound that is ``-inf`` everywhere, an
    upper bound that is ``+inf`` everywhere; the other fields are ``problem``'s own arrays.
    """
    has_rows, has_eq = problem.h.size > 0, problem.b.size > 0
    return qpsolvers.Problem(
        problem.P,
        problem.q,
        problem.G if has_rows else None,
        problem.h if has_rows else None,
        problem.A if has_eq else None,
        problem.b if has_eq else None,
        lb=None if np.isneginf(problem.lb).all() else problem.lb,
        ub=None if np.isposinf(problem.ub).all() else problem.ub,
    )


def _dense(M: Any, n: int) -> np.ndarray:
    """``M`` as a dense float matrix with n columns (sparse matrices converted; itself when it is one)."""
    if type(M) is np.ndarray and M.dtype == np.float64 and M.ndim == 2:
        return M
    return np.asarray(M.toarray() if hasattr(M, "toarray") else M, dtype=float).reshape(-1, n)
