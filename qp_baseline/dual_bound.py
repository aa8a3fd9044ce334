r"""The pieces of a certificate's bound (:mod:`qp_baseline.certificate`) for a QP and an answer x.

For :math:`\min \tfrac12 x^TPx + q^Tx` s.t. :math:`Gx \le h,\ Ax = b,\ lb \le x \le ub`
(a :class:`~qp_baseline.qp_problem.DenseProblem`): the primal residual of x, how much the
Lagrangian can drop inside the box (per variable with a curvature :math:`c`, or along the
eigenvectors of P), the backend's multipliers in the problem's shapes, and multipliers
recovered for x itself (a bounded least squares on the rows and bounds that nearly bind).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import lsq_linear

from qp_baseline.qp_problem import DenseProblem

Multipliers = tuple[np.ndarray, np.ndarray, np.ndarray]
"""(y, z, z_box): multipliers of Ax = b, Gx ≤ h and the box, qpsolvers' sign convention."""


def primal_residual(qp: DenseProblem, x: np.ndarray, slack: np.ndarray | None = None) -> float:
    """:math:`r_p` of ``x`` (0 for a feasible point); ``slack`` = h − G x when already known."""
    parts = [0.0]
    if qp.h.size:
        parts.append(-float((qp.h - qp.G @ x if slack is None else slack).min()))
    if qp.b.size:
        parts.append(float(np.abs(qp.A @ x - qp.b).max()))
    parts.append(float((qp.lb - x).max()))
    parts.append(float((x - qp.ub).max()))
    return max(parts)


def box_term(g: np.ndarray, x: np.ndarray, lb: np.ndarray, ub: np.ndarray, curvature: np.ndarray) -> float:
    r"""How much the Lagrangian can drop in the box: :math:`-\sum_i \min_{d_i} (g_i d_i + \tfrac12 c_i d_i^2)`.

    Over :math:`d_i \in [lb_i - x_i, ub_i - x_i]`, with :math:`P \succeq \mathrm{diag}(c)`; for
    :math:`c_i = 0` this is :math:`\max(g_i(x_i - lb_i), g_i(x_i - ub_i))`. Infinite when a
    gradient component points out of an unbounded side.
    """
    lo = lb - x
    hi = ub - x
    curved = curvature > 0.0
    if curved.all():  # the cascade's levels: every variable curved (ε on q̇, 1 on slacks)
        d = np.minimum(np.maximum(-g / curvature, lo), hi)
    else:
        d = np.where(g > 0.0, lo, hi)  # the linear minimiser (c = 0)
        if curved.any():
            d[curved] = np.clip(-g[curved] / curvature[curved], lo[curved], hi[curved])
    if not g.all():
        d[g == 0.0] = 0.0
    if not np.isfinite(d).all():
        return math.inf
    return float(-(g @ d) - 0.5 * float(curvature @ (d * d)))


def eigen_box_term(g: np.ndarray, x: np.ndarray, lb: np.ndarray, ub: np.ndarray, P: np.ndarray) -> float:
    r"""The drop of :func:`box_term` bounded along the eigenvectors of P (sharper where P curves).

    With :math:`P = U\Lambda U^T`, :math:`\gamma = U^Tg` and :math:`e = U^Td`, the box gives
    :math:`|e_j| \le R_j = \sum_i |U_{ij}| \max(|lb_i - x_i|, |ub_i - x_i|)`, and
    :math:`\min_d g^Td + \tfrac12 d^TPd \ge \sum_j \min_{|e_j| \le R_j} (\gamma_j e_j + \tfrac12\lambda_j e_j^2)`.
    """
    lam, U = np.linalg.eigh(0.5 * (P + P.T))
    lam = np.maximum(lam, 0.0)
    gamma = U.T @ g
    reach = np.maximum(np.abs(lb - x), np.abs(ub - x))
    with np.errstate(invalid="ignore"):
        R = np.abs(U).T @ reach
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where(lam > 0.0, -gamma / lam, -np.sign(gamma) * R)
    e = np.clip(e, -R, R)
    with np.errstate(invalid="ignore"):
        value = gamma * e + 0.5 * lam * e * e
    value = np.where(gamma == 0.0, 0.0, value)
    return float(-value.sum())


def recover_multipliers(qp: DenseProblem, x: np.ndarray, active: float) -> Multipliers | None:
    r"""Multipliers :math:`(y, z, z_{box})` that best explain ``x`` as an optimum (see module doc).

    Returns None when the least squares fails.
    """
    n = x.shape[0]
    grad = qp.P @ x + qp.q
    rows = np.flatnonzero(qp.G @ x - qp.h >= -active * (1.0 + np.abs(qp.h))) if qp.h.size else np.zeros(0, int)
    at_lo = np.flatnonzero(np.isfinite(qp.lb) & (x - qp.lb <= active * (1.0 + np.abs(np.nan_to_num(qp.lb)))))
    at_hi = np.flatnonzero(np.isfinite(qp.ub) & (qp.ub - x <= active * (1.0 + np.abs(np.nan_to_num(qp.ub)))))
    m_eq, m_in = qp.b.size, rows.size
    cols = [qp.A.T, qp.G[rows].T, -np.eye(n)[:, at_lo], np.eye(n)[:, at_hi]]
    M = np.hstack(cols)
    if M.shape[1] == 0:
        return np.zeros(m_eq), np.zeros(qp.h.size), np.zeros(n)
    lo = np.concatenate([np.full(m_eq, -np.inf), np.zeros(M.shape[1] - m_eq)])
    hi = np.full(M.shape[1], np.inf)
    try:
        sol = lsq_linear(M, -grad, bounds=(lo, hi), method="bvls", lsmr_tol=None, tol=1e-14)
    except (ValueError, np.linalg.LinAlgError):
        return None
    v = sol.x
    y = v[:m_eq]
    z = np.zeros(qp.h.size)
    z[rows] = v[m_eq : m_eq + m_in]
    z_box = np.zeros(n)
    k = m_eq + m_in
    z_box[at_lo] = -v[k : k + at_lo.size]
    z_box[at_hi] += v[k + at_lo.size :]
    return y, z, z_box


def backend_multipliers(
    qp: DenseProblem, y: np.ndarray | None, z: np.ndarray | None, z_box: np.ndarray | None
) -> Multipliers | None:
    """The backend's (y, z, z_box) with the problem's shapes, or None when missing or non-finite."""
    n = qp.q.shape[0]
    if (y is None and qp.b.size) or (z is None and qp.h.size):
        return None
    ys = np.zeros(qp.b.size) if y is None or not qp.b.size else np.asarray(y, dtype=float).ravel()
    zs = np.zeros(qp.h.size) if z is None or not qp.h.size else np.asarray(z, dtype=float).ravel()
    zb = np.zeros(n) if z_box is None or np.size(z_box) == 0 else np.asarray(z_box, dtype=float).ravel()
    if ys.shape != (qp.b.size,) or zs.shape != (qp.h.size,) or zb.shape != (n,):
        return None
    if not (np.isfinite(ys).all() and np.isfinite(zs).all() and np.isfinite(zb).all()):
        return None
    return ys, zs, zb
