r"""Active-set polish of an approximate QP answer (OSQP's polishing idea, for any backend).

For :math:`\min \tfrac12 x^TPx + q^Tx` s.t. :math:`Gx \le h,\ Ax = b,\ lb \le x \le ub`, the box
is taken as rows and, from an approximate primal-dual pair :math:`(x, z)` (or :math:`x` alone),
a primal-dual active-set iteration runs: rows with :math:`z_i > h_i - G_i x` (or within ``active``
of binding) are active; the equality-constrained QP of the active rows is solved exactly through its KKT
system (least squares, so dependent active rows are fine, plus one step of iterative
refinement); repeat from the new pair until the active set repeats. With the right active set —
which an interior-point or first-order answer near the optimum usually identifies — the result
is the optimum to machine precision. Nothing here decides whether it is: the caller certifies
the polished answer (:func:`qp_baseline.certificate.certify`) and keeps it only if it passes.
"""

from __future__ import annotations

import numpy as np
import qpsolvers

from qp_baseline.qp_problem import DenseProblem


def polish(
    problem: DenseProblem,
    x: np.ndarray,
    z: np.ndarray | None = None,
    z_box: np.ndarray | None = None,
    active: float = 1e-9,
    max_rounds: int = 25,
) -> qpsolvers.Solution | None:
    """Polish ``x`` (module docstring).

    Args:
        problem: The QP; finite entries of its box are taken as rows.
        x: Approximate answer. Shape (n,).
        z: Its row multipliers (None: unknown). Shape (m,).
        z_box: Its box multipliers, qpsolvers' sign convention (None: unknown). Shape (n,).
        active: A row within this of binding starts active.
        max_rounds: Largest number of KKT solves.

    Returns:
        The last round's answer and multipliers ``x, y, z, z_box`` (``found`` set), or None when
        it is not finite. Nothing says it is optimal: the caller certifies it.
    """
    P, q, G, h, lb, ub = problem.P, problem.q, problem.G, problem.h, problem.lb, problem.ub
    A_, b_ = problem.A, problem.b
    n = x.shape[0]
    lo_rows, hi_rows = np.flatnonzero(np.isfinite(lb)), np.flatnonzero(np.isfinite(ub))
    Gb = np.vstack([G, np.eye(n)[hi_rows], -np.eye(n)[lo_rows]])
    hb = np.concatenate([h, ub[hi_rows], -lb[lo_rows]])
    m, p = h.shape[0], A_.shape[0]
    mult = _row_multipliers(z, z_box, m, n, lo_rows, hi_rows)
    y = np.zeros(p)
    previous: np.ndarray | None = None
    for _ in range(max_rounds):
        gap = hb - Gb @ x
        act = (mult > gap) | (gap <= active)
        if previous is not None and np.array_equal(act, previous):
            break
        previous = act
        sol = _kkt_solve(P, q, np.vstack([A_, Gb[act]]), np.concatenate([b_, hb[act]]))
        if sol is None:
            return None
        x = sol[:n]
        y = sol[n : n + p]
        mult = np.zeros(Gb.shape[0])
        mult[act] = sol[n + p :]
    z_box_out = np.zeros(n)
    z_box_out[hi_rows] += mult[m : m + hi_rows.size]
    z_box_out[lo_rows] -= mult[m + hi_rows.size :]
    return qpsolvers.Solution(problem, found=True, x=x, y=y, z=mult[:m], z_box=z_box_out)


def _row_multipliers(
    z: np.ndarray | None, z_box: np.ndarray | None, m: int, n: int, lo_rows: np.ndarray, hi_rows: np.ndarray
) -> np.ndarray:
    """Starting multipliers of the rows [G; upper box; lower box] (≥ 0; zero where unknown)."""
    zb = np.zeros(n) if z_box is None else np.asarray(z_box, dtype=float)
    return np.concatenate(
        [
            np.zeros(m) if z is None else np.maximum(np.asarray(z, dtype=float), 0.0),
            zb[hi_rows].clip(0.0),
            (-zb[lo_rows]).clip(0.0),
        ]
    )


def _kkt_solve(P: np.ndarray, q: np.ndarray, E: np.ndarray, e: np.ndarray) -> np.ndarray | None:
    r"""[x; λ] of :math:`\min \tfrac12 x^TPx + q^Tx` s.t. :math:`Ex = e`, or None when not finite.

    Least squares on the KKT system (dependent rows are fine), plus one step of refinement.
    """
    n, k = P.shape[0], E.shape[0]
    K = np.zeros((n + k, n + k))
    K[:n, :n] = P
    K[:n, n:] = E.T
    K[n:, :n] = E
    rhs = np.concatenate([-q, e])
    sol = np.linalg.lstsq(K, rhs, rcond=1e-14)[0]
    sol += np.linalg.lstsq(K, rhs - K @ sol, rcond=1e-14)[0]
    return sol if np.isfinite(sol).all() else None
