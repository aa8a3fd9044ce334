r"""The certificate of :mod:`qp_baseline.certificate` for the HQP cascade's level QPs, a passing verdict compiled.

The cascade's level QPs have one form (a :class:`~qp_baseline.qp_problem.DenseProblem` without
equality rows, a finite box, every variable curved) and come with the backend's multipliers.
:func:`certify_dense` judges them in one compiled pass (:func:`_dense_judgement`) and returns
that certificate when it passes; every other verdict is :func:`~qp_baseline.certificate.certify`'s.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from qp_baseline.certificate import Certificate, Tolerances, certify, early_reason, too_far
from qp_baseline.qp_problem import DenseProblem

# Entries of the output vector of :func:`_dense_judgement`.
_R_P, _F, _R_D, _COMP, _BOX, _TERMS = 0, 1, 2, 3, 4, 5
_N_TERMS = 5  # xᵀPx, qᵀx, hᵀz⁺, lbᵀz_box⁻, ubᵀz_box⁺ (no equality rows: bᵀy = 0)
_DENSE_OUT = _TERMS + _N_TERMS


@numba.njit(cache=True, nogil=True)
def _dense_form(
    P: np.ndarray,
    q: np.ndarray,
    G: np.ndarray,
    h: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    x: np.ndarray,
    z: np.ndarray,
    z_box: np.ndarray,
    curvature: np.ndarray,
) -> bool:
    """Whether the inputs have the form of :func:`certify_dense`.

    That is: n ≥ 1 variables, consistent shapes, every entry finite, every curvature :math:`c_i > 0`.
    """
    n, m = x.shape[0], h.shape[0]
    if n == 0 or P.shape[0] != n or P.shape[1] != n or G.shape[0] != m or G.shape[1] != n or z.shape[0] != m:
        return False
    if q.shape[0] != n or lb.shape[0] != n or ub.shape[0] != n or z_box.shape[0] != n or curvature.shape[0] != n:
        return False
    for i in range(n):
        if not (
            np.isfinite(x[i])
            and np.isfinite(q[i])
            and np.isfinite(lb[i])
            and np.isfinite(ub[i])
            and np.isfinite(z_box[i])
            and curvature[i] > 0.0
        ):
            return False
        for j in range(n):
            if not np.isfinite(P[i, j]):
                return False
    for r in range(m):
        if not (np.isfinite(h[r]) and np.isfinite(z[r])):
            return False
        for j in range(n):
            if not np.isfinite(G[r, j]):
                return False
    return True


@numba.njit(cache=True, nogil=True)
def _dense_judgement(
    P: np.ndarray,
    q: np.ndarray,
    G: np.ndarray,
    h: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    x: np.ndarray,
    z: np.ndarray,
    z_box: np.ndarray,
    curvature: np.ndarray,
    out: np.ndarray,
) -> bool:
    r"""The numbers :func:`~qp_baseline.certificate.certify` computes for the backend's multipliers, in one pass.

    With :math:`s = h - Gx` and :math:`g = Px + q + G^Tz^+` (module docstring):
    ``out[_R_P]`` :math:`r_p = \max(0, -\min s, \max(lb - x), \max(x - ub))`,
    ``out[_F]`` :math:`f = x^T(\tfrac12 Px + q)`, ``out[_R_D]`` :math:`\|g + z_{box}\|_\infty`,
    ``out[_COMP]`` the complementarity :math:`z^{+T}s`, ``out[_BOX]`` the box term
    :math:`-\sum_i \min_{d_i \in [lb_i - x_i,\ ub_i - x_i]} (g_i d_i + \tfrac12 c_i d_i^2)` (all
    :math:`c_i > 0`, :func:`qp_baseline.dual_bound.box_term`), ``out[_TERMS:]`` the terms of the duality gap
    :math:`r_g` (summed exactly by the caller).

    Returns:
        False (``out`` not filled) when the inputs are not of that form (:func:`_dense_form`):
        :func:`certify` handles those.
    """
    n, m = x.shape[0], h.shape[0]
    if not _dense_form(P, q, G, h, lb, ub, x, z, z_box, curvature):
        return False
    r_p, f, xPx, qx = 0.0, 0.0, 0.0, 0.0
    g = np.empty(n)
    for i in range(n):
        px = 0.0
        for j in range(n):
            px += P[i, j] * x[j]
        f += x[i] * (0.5 * px + q[i])
        xPx += x[i] * px
        qx += q[i] * x[i]
        g[i] = px + q[i]
        r_p = max(r_p, lb[i] - x[i], x[i] - ub[i])
    hz, comp = 0.0, 0.0
    for r in range(m):
        gx = 0.0
        for j in range(n):
            gx += G[r, j] * x[j]
        slack = h[r] - gx
        r_p = max(r_p, -slack)
        zp = max(z[r], 0.0)
        hz += h[r] * zp
        comp += zp * slack
        for j in range(n):
            g[j] += G[r, j] * zp
    r_d, lo_part, hi_part, drop = 0.0, 0.0, 0.0, 0.0
    for i in range(n):
        r_d = max(r_d, abs(g[i] + z_box[i]))
        lo_part += lb[i] * min(z_box[i], 0.0)
        hi_part += ub[i] * max(z_box[i], 0.0)
        d = 0.0 if g[i] == 0.0 else min(max(-g[i] / curvature[i], lb[i] - x[i]), ub[i] - x[i])
        drop += g[i] * d + 0.5 * curvature[i] * (d * d)
    out[_R_P], out[_F], out[_R_D], out[_COMP], out[_BOX] = r_p, f, r_d, comp, -drop
    out[_TERMS], out[_TERMS + 1], out[_TERMS + 2], out[_TERMS + 3], out[_TERMS + 4] = xPx, qx, hz, lo_part, hi_part
    return True


def certify_dense(
    problem: DenseProblem,
    x: np.ndarray,
    z: np.ndarray | None,
    z_box: np.ndarray | None,
    curvature: np.ndarray,
    *,
    feasible_objective: float | None = None,
    level_value: float | None = None,
    modulus: float | None = None,
    tolerances: Tolerances | None = None,
    recover: bool = True,
) -> Certificate:
    r""":func:`certify` of ``x`` for dense ``P`` (n, n), ``G`` (m, n), a finite box and :math:`c > 0`.

    The backend's multipliers ``z``, ``z_box`` are judged in one compiled pass
    (:func:`_dense_judgement`: the same residuals, gap and bound :math:`f_{lo} = f - (z^{+T}s +
    \text{box term})` as :func:`certify`, to round-off). When they certify ``x`` directly (no
    early reason, the box term within tolerance) that certificate is returned; in every other case —
    a verdict that fails or needs the eigenvector bound, missing or non-finite multipliers, a
    non-finite input — :func:`certify` decides, with the same arguments. The verdict is
    therefore :func:`certify`'s.

    Args:
        problem: The QP (no equality rows for the compiled pass; G may have no row).
        x: The answer. Shape (n,).
        z: Backend multipliers of ``Gx ≤ h`` (None: not given). Shape (m,).
        z_box: Backend multipliers of the box (None: not given). Shape (n,).
        curvature: :math:`c` with :math:`P \succeq \mathrm{diag}(c)`, one entry per variable.
        feasible_objective: As :func:`certify`.
        level_value: As :func:`certify`.
        modulus: As :func:`certify`.
        tolerances: As :func:`certify`.
        recover: As :func:`certify`.

    Returns:
        The certificate :func:`certify` returns.
    """
    tol = tolerances or Tolerances()
    out = np.empty(_DENSE_OUT)
    P, q, G, h, lb, ub = problem.P, problem.q, problem.G, problem.h, problem.lb, problem.ub
    if (
        z is not None
        and z_box is not None
        and z.ndim == 1
        and z_box.ndim == 1
        and not problem.b.size
        and _dense_judgement(P, q, G, h, lb, ub, x, z, z_box, curvature, out)
    ):
        r_p, f = float(out[_R_P]), float(out[_F])
        upper = math.inf if feasible_objective is None else float(feasible_objective)
        sub = float(out[_COMP]) + float(out[_BOX])
        if not early_reason(r_p, f, upper, level_value, modulus, x, tol) and not too_far(
            sub, f, level_value, modulus, x, tol
        ):
            r_g = abs(math.fsum(out[_TERMS:].tolist()))
            return Certificate(r_p, float(out[_R_D]), r_g, f, f - sub, upper, "backend", True, "")
    return certify(
        problem,
        x,
        z=z,
        z_box=z_box,
        feasible_objective=feasible_objective,
        level_value=level_value,
        curvature=curvature,
        modulus=modulus,
        tolerances=tolerances,
        recover=recover,
    )


def warm_up() -> None:
    """Load :func:`_dense_judgement` into this process: no control step compiles it.

    Float64 C arrays, the answer and its row multipliers writeable or read-only (some backends'
    arrays are read-only through qpsolvers).
    """
    if _dense_judgement.signatures:
        return
    one, col = np.ones(1), np.ones((1, 1))
    for writeable in (True, False):
        x, z = np.ones(1), np.zeros(0)
        x.flags.writeable = z.flags.writeable = writeable
        _dense_judgement(col, one, np.zeros((0, 1)), np.zeros(0), -one, one, x, z, one, one, np.empty(_DENSE_OUT))
