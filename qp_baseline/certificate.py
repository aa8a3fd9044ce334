r"""Correctness certificate of one QP answer, judged as qpbenchmark judges a solver.

The QP is the qpsolvers form

.. math::
    \min_x\ f(x) = \tfrac12 x^TPx + q^Tx \quad\text{s.t.}\quad Gx \le h,\ Ax = b,\ lb \le x \le ub.

Given an answer :math:`x` and multipliers :math:`(y, z, z_{box})` (qpsolvers' ``Solution.y``,
``z``, ``z_box``: :math:`z \ge 0`, :math:`z_{box} < 0` on an active lower bound, > 0 on an
active upper one), the certificate holds

* the **primal residual** :math:`r_p = \max(0, [Gx-h]^+, |Ax-b|, [lb-x]^+, [x-ub]^+)`
  (qpsolvers ``Solution.primal_residual``);
* the **dual residual** :math:`r_d = \|Px + q + A^Ty + G^Tz^+ + z_{box}\|_\infty`
  (``Solution.dual_residual``, with :math:`z^+ = \max(z, 0)`, so a multiplier of the wrong sign
  shows up here instead of being trusted);
* the **duality gap** :math:`r_g = |x^TPx + q^Tx + b^Ty + h^Tz^+ + lb^Tz_{box}^- + ub^Tz_{box}^+|`
  (``Solution.duality_gap``);
* a **lower bound** on the optimum :math:`f^*` valid for *any* multipliers with
  :math:`z \ge 0` (weak duality, box kept as a set): with :math:`g = Px + q + A^Ty + G^Tz^+`
  the Lagrangian is convex, so for every feasible :math:`\hat x`

  .. math::
      f(\hat x) \ge L(\hat x) = L(x) + g^T(\hat x - x) + \tfrac12 (\hat x - x)^TP(\hat x - x)
      \ge L(x) + \textstyle\sum_i \min_{d_i \in [lb_i - x_i,\ ub_i - x_i]}
      \big(g_i d_i + \tfrac12 c_i d_i^2\big) =: f_{lo}

  for any :math:`c \ge 0` with :math:`P \succeq \mathrm{diag}(c)` (``curvature``; 0: the linear
  bound), sharpened along P's eigenvectors when that is not enough. :math:`f(x) - f_{lo}` bounds
  how far the answer is from the optimum; it is computed term by term (complementarity
  :math:`z^T(h - Gx)`, the equality residual, the box term), as products of multipliers and
  residuals, so no large numbers cancel. An upper bound is the objective of a known feasible
  point when the caller has one: an answer above it is certainly not the optimum.

**Verdict** (:class:`Tolerances`, scaled to the problem): the primal residual within ``primal``
(absolute: the constraints' unit); the objective not above the known feasible point; and
:math:`f(x) - f_{lo}` within tolerance — as the error of a level's residual norm when the QP is a
level of a cascade (``level_value``, :attr:`Tolerances.level`: the unit a user reads, m/s or
rad/s), as a distance to the optimum when the answer itself matters (``modulus``), else relative
to :math:`1 + |f|` (:attr:`Tolerances.gap`). The bound combines the dual residual and the
complementarity rigorously; the qpbenchmark dual residual and duality gap are reported but do not
decide alone (a backend's box multipliers may be off while its answer is optimal).

If the backend gave no multipliers, or its multipliers do not certify the answer, multipliers can
be **recovered** for the answer itself: a bounded least squares on the rows and bounds within
``active`` of binding, :math:`\min_{y,\ z_A \ge 0,\ \mu} \|Px + q + A^Ty + G_A^Tz_A + E\mu\|`
(scipy ``lsq_linear``; :math:`E\mu` the signed box multipliers of the active bounds), tried with
``active`` and with 100 × ``active``. The certificate reports which multipliers it used.

:func:`certify_dense` is :func:`certify` for the form the HQP cascade poses (dense P and G, no
equality rows, a finite box, every variable curved, the backend's multipliers): the arithmetic of
a passing verdict in one compiled call (:func:`_dense_judgement`), :func:`certify` itself for
everything else (a failing or doubtful verdict, recovered multipliers, other forms).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numba
import numpy as np
from scipy.optimize import lsq_linear

MultiplierSource = Literal["backend", "recovered", "none"]


@dataclass(frozen=True)
class Tolerances:
    r"""Acceptance thresholds of a certificate.

    Attributes:
        primal: Largest accepted constraint violation :math:`r_p` (absolute, the constraints'
            unit: rad/s, m/s).
        gap: Largest accepted :math:`(f - f_{lo}) / (1 + |f|)` of a plain QP (no level value).
        level: Largest accepted error of a level's residual norm, relative to ``1 + ρ``: with the
            level objective :math:`L = \tfrac12 (\|J\dot q - r\|^2 + \|w\|^2)` at the answer,
            :math:`ρ = \sqrt{2L}` [task units / s] and :math:`ρ_{lo} = \sqrt{2(L - (f - f_{lo}))}`,
            the answer passes when :math:`ρ - ρ_{lo} \le` ``level``·(1 + ρ).
        active: A row or bound within ``active``·(1 + |bound|) of binding takes part in the
            multiplier recovery.
    """

    primal: float = 1e-6
    gap: float = 1e-9
    level: float = 1e-6
    active: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("primal", "gap", "level", "active"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"certificate tolerance '{name}' must be a finite number > 0, got {value!r}")


@dataclass(frozen=True)
class Certificate:
    """What one answer was found to be.

    Attributes:
        primal_residual: :math:`r_p`.
        dual_residual: :math:`r_d` with the multipliers of ``multipliers``.
        duality_gap: :math:`r_g` with the same multipliers.
        objective: :math:`f(x)`.
        lower_bound: :math:`f_{lo}` (``-inf`` when no multipliers bound it).
        upper_bound: Objective of the known feasible point (``inf`` when none was given).
        multipliers: ``"backend"``, ``"recovered"`` or ``"none"`` (no multipliers made sense).
        passed: All tolerances met.
        reason: The first check that failed (empty when passed).
    """

    primal_residual: float
    dual_residual: float
    duality_gap: float
    objective: float
    lower_bound: float
    upper_bound: float
    multipliers: MultiplierSource
    passed: bool
    reason: str = ""

    def to_dict(self) -> dict[str, float | str | bool]:
        """JSON-ready fields (the qpbenchmark results columns plus the bounds)."""
        return {
            "primal_residual": self.primal_residual,
            "dual_residual": self.dual_residual,
            "duality_gap": self.duality_gap,
            "objective": self.objective,
            "lower_bound": self.lower_bound,
            "upper_bound": self.upper_bound,
            "multipliers": self.multipliers,
            "passed": self.passed,
            "reason": self.reason,
        }


@dataclass(frozen=True)
class _Qp:
    P: np.ndarray
    q: np.ndarray
    G: np.ndarray
    h: np.ndarray
    A: np.ndarray
    b: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    finite_lb: bool
    finite_ub: bool


def _as_qp(
    P: np.ndarray,
    q: np.ndarray,
    G: np.ndarray | None,
    h: np.ndarray | None,
    A: np.ndarray | None,
    b: np.ndarray | None,
    lb: np.ndarray | None,
    ub: np.ndarray | None,
) -> _Qp:
    n = q.shape[0]
    lb_ = np.full(n, -np.inf) if lb is None else np.asarray(lb, dtype=float)
    ub_ = np.full(n, np.inf) if ub is None else np.asarray(ub, dtype=float)
    return _Qp(
        _dense(P, n),
        np.asarray(q, dtype=float),
        np.zeros((0, n)) if G is None else _dense(G, n),
        np.zeros(0) if h is None else np.asarray(h, dtype=float).ravel(),
        np.zeros((0, n)) if A is None else _dense(A, n),
        np.zeros(0) if b is None else np.asarray(b, dtype=float).ravel(),
        lb_,
        ub_,
        math.isfinite(float(np.abs(lb_).max(initial=0.0))),
        math.isfinite(float(np.abs(ub_).max(initial=0.0))),
    )


def _dense(M: np.ndarray, n: int) -> np.ndarray:
    """``M`` as a dense float matrix with n columns (sparse matrices converted)."""
    if type(M) is np.ndarray and M.dtype == np.float64 and M.ndim == 2:
        return M
    return np.asarray(M.toarray() if hasattr(M, "toarray") else M, dtype=float).reshape(-1, n)


def primal_residual(qp: _Qp, x: np.ndarray, slack: np.ndarray | None = None) -> float:
    """:math:`r_p` of ``x`` (0 for a feasible point); ``slack`` = h − G x when already known."""
    parts = [0.0]
    if qp.h.size:
        parts.append(-float((qp.h - qp.G @ x if slack is None else slack).min()))
    if qp.b.size:
        parts.append(float(np.abs(qp.A @ x - qp.b).max()))
    parts.append(float((qp.lb - x).max()))
    parts.append(float((x - qp.ub).max()))
    return max(parts)


def _box_term(g: np.ndarray, x: np.ndarray, lb: np.ndarray, ub: np.ndarray, curvature: np.ndarray) -> float:
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


def _eigen_box_term(g: np.ndarray, x: np.ndarray, lb: np.ndarray, ub: np.ndarray, P: np.ndarray) -> float:
    r"""The drop of :func:`_box_term` bounded along the eigenvectors of P (sharper where P curves).

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


def _judge(
    qp: _Qp,
    x: np.ndarray,
    Px: np.ndarray,
    slack: np.ndarray,
    multipliers: tuple[np.ndarray, np.ndarray, np.ndarray],
    r_p: float,
    f: float,
    upper: float,
    level_value: float | None,
    curvature: np.ndarray,
    tol: Tolerances,
    source: MultiplierSource,
    modulus: float | None = None,
) -> Certificate:
    """Residuals, gap and bound of ``x`` with one set of multipliers ``(y, z, z_box)``; the verdict.

    ``Px`` = P x and ``slack`` = h − G x are the caller's (computed once per answer).
    """
    y, z, z_box = multipliers
    zp = np.maximum(z, 0.0)
    g = Px + qp.q
    if zp.size:
        g = g + qp.G.T @ zp
    if y.size:
        g = g + qp.A.T @ y
    r_d = float(np.abs(g + z_box).max()) if x.size else 0.0
    zb_lo, zb_hi = np.minimum(z_box, 0.0), np.maximum(z_box, 0.0)
    lo_part, hi_part = qp.lb @ zb_lo if qp.finite_lb else math.nan, qp.ub @ zb_hi if qp.finite_ub else math.nan
    if not qp.finite_lb:
        fin = np.isfinite(qp.lb)
        lo_part = math.inf if (zb_lo[~fin] != 0.0).any() else float(qp.lb[fin] @ zb_lo[fin])
    if not qp.finite_ub:
        fin = np.isfinite(qp.ub)
        hi_part = math.inf if (zb_hi[~fin] != 0.0).any() else float(qp.ub[fin] @ zb_hi[fin])
    terms = [
        float(x @ Px),
        float(qp.q @ x),
        float(qp.b @ y) if y.size else 0.0,
        float(qp.h @ zp) if zp.size else 0.0,
        float(lo_part),
        float(hi_part),
    ]
    r_g = abs(math.fsum(terms)) if math.isfinite(terms[4]) and math.isfinite(terms[5]) else math.inf
    # f(x) − f_lo, term by term: −y'(Ax − b) − z'(Gx − h) + the drop of the Lagrangian in the box.
    comp = float(zp @ slack) if zp.size else 0.0
    eq = -float(y @ (qp.A @ x - qp.b)) if y.size else 0.0
    sub = comp + eq + _box_term(g, x, qp.lb, qp.ub, curvature)
    if x.size and _too_far(sub, f, level_value, modulus, x, tol):
        sub = min(sub, comp + eq + _eigen_box_term(g, x, qp.lb, qp.ub, qp.P))
    lower = f - sub if math.isfinite(sub) else -math.inf
    reason = ""
    if not math.isfinite(sub):
        reason = "no finite bound from these multipliers"
    elif _too_far(sub, f, level_value, modulus, x, tol):
        reason = f"objective may be {sub:.3g} above the optimum ({_tolerance_text(level_value, modulus, x, tol)})"
    return Certificate(r_p, r_d, r_g, f, lower, upper, source, not reason, reason)


def _too_far(
    excess: float, f: float, level_value: float | None, modulus: float | None, x: np.ndarray, tol: Tolerances
) -> bool:
    """Whether an objective ``excess`` over a bound breaks the tolerance (distance, level units or relative)."""
    if excess <= 0.0:
        return False
    if modulus is not None:
        # f strongly convex with modulus μ: ‖x − x*‖ ≤ √(2(f − f*)/μ).
        return math.sqrt(2.0 * excess / modulus) > tol.level * (1.0 + float(np.abs(x).max(initial=0.0)))
    if level_value is None:
        return excess > tol.gap * (1.0 + abs(f))
    rho = math.sqrt(2.0 * max(level_value, 0.0))
    rho_lo = math.sqrt(2.0 * max(level_value - excess, 0.0))
    return rho - rho_lo > tol.level * (1.0 + rho)


def _tolerance_text(level_value: float | None, modulus: float | None, x: np.ndarray, tol: Tolerances) -> str:
    if modulus is not None:
        return f"distance to the optimum > {tol.level:g}·(1 + ‖x‖∞)"
    if level_value is None:
        return f"> {tol.gap:g}·(1 + |f|)"
    rho = math.sqrt(2.0 * max(level_value, 0.0))
    return f"level residual {rho:.6g}, > {tol.level:g}·(1 + ρ) in it"


def recover_multipliers(qp: _Qp, x: np.ndarray, active: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
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


def certify(
    P: np.ndarray,
    q: np.ndarray,
    G: np.ndarray | None,
    h: np.ndarray | None,
    x: np.ndarray,
    *,
    A: np.ndarray | None = None,
    b: np.ndarray | None = None,
    lb: np.ndarray | None = None,
    ub: np.ndarray | None = None,
    y: np.ndarray | None = None,
    z: np.ndarray | None = None,
    z_box: np.ndarray | None = None,
    feasible_objective: float | None = None,
    level_value: float | None = None,
    curvature: np.ndarray | float | None = None,
    modulus: float | None = None,
    tolerances: Tolerances | None = None,
    recover: bool = True,
) -> Certificate:
    r"""Certify ``x`` as the optimum of the QP, with the backend's multipliers or recovered ones.

    The verdict: the primal residual is within ``tolerances.primal``, the objective is not above
    ``feasible_objective``, and the objective is within tolerance of the lower bound
    :math:`f_{lo}` — in the level's residual norm when ``level_value`` is given
    (:attr:`Tolerances.level`), relative to :math:`1 + |f|` otherwise (:attr:`Tolerances.gap`).
    The bound combines the dual residual and the complementarity of the multipliers rigorously,
    so the qpbenchmark dual residual and duality gap are reported but do not decide on their own
    (a backend's box multipliers may be off while its answer is optimal).

    Args:
        P: Cost matrix (dense or sparse). Shape (n, n).
        q: Cost vector. Shape (n,).
        G: Inequality matrix, or None. Shape (m, n).
        h: Inequality bounds, or None. Shape (m,).
        x: The answer. Shape (n,).
        A: Equality matrix, or None. Shape (p, n).
        b: Equality right-hand side, or None. Shape (p,).
        lb: Lower bounds of x, or None. Shape (n,).
        ub: Upper bounds of x, or None. Shape (n,).
        y: Backend multipliers of ``Ax = b`` (None: not given).
        z: Backend multipliers of ``Gx ≤ h`` (None: not given).
        z_box: Backend multipliers of the box (None: not given).
        feasible_objective: :math:`f` at a known feasible point (upper bound on the optimum).
        level_value: Level objective :math:`L` at ``x`` (½-scaled, :attr:`Tolerances.level`), when
            the QP is a level of a cascade; its optimum is :math:`L - (f(x) - f^*)`.
        curvature: :math:`c \ge 0` with :math:`P \succeq \mathrm{diag}(c)` (a vector, or one number
            for all); sharpens the bound. 0 (no curvature used) when None.
        modulus: :math:`\mu > 0` with :math:`P \succeq \mu I`: judge the distance
            :math:`\|x - x^*\| \le \sqrt{2(f - f_{lo})/\mu}` against ``tolerances.level``·(1 + ‖x‖∞)
            instead of the objective (a QP whose answer itself matters, not its objective).
        tolerances: Thresholds (:class:`Tolerances` defaults when None).
        recover: Try recovered multipliers when the backend's are missing or do not certify.

    Returns:
        The certificate with the first multipliers that pass, else the one with the backend's
        multipliers (or the recovered ones when the backend gave none).
    """
    tol = tolerances or Tolerances()
    qp = _as_qp(P, q, G, h, A, b, lb, ub)
    x = np.asarray(x, dtype=float)
    n = qp.q.shape[0]
    upper = math.inf if feasible_objective is None else float(feasible_objective)
    if x.shape != (n,) or not np.isfinite(x).all():
        return Certificate(math.inf, math.inf, math.inf, math.nan, -math.inf, upper, "none", False, "non-finite answer")
    Px = qp.P @ x
    slack = qp.h - qp.G @ x
    r_p = primal_residual(qp, x, slack)
    f = float(x @ (0.5 * Px + qp.q))
    curv = _curvature_vector(curvature, n)
    judge = functools.partial(
        _judge, qp, x, Px, slack, r_p=r_p, f=f, upper=upper, level_value=level_value, curvature=curv, tol=tol
    )
    given = _backend_multipliers(qp, y, z, z_box)
    early = _early_reason(r_p, f, upper, level_value, modulus, x, tol)
    if early:
        return _early_certificate(
            judge(given, source="backend", modulus=modulus) if given is not None else None, r_p, f, upper, early
        )
    first: Certificate | None = None
    if given is not None:
        first = judge(given, source="backend", modulus=modulus)
        if first.passed or not recover:
            return first
    if recover:
        cert = _with_recovered_multipliers(qp, x, tol, functools.partial(judge, source="recovered", modulus=modulus))
        if cert is not None and (cert.passed or first is None):
            return cert
    if first is not None:
        return first
    return Certificate(r_p, math.inf, math.inf, f, -math.inf, upper, "none", False, "no multipliers")


def _with_recovered_multipliers(
    qp: _Qp, x: np.ndarray, tol: Tolerances, judge: Callable[[tuple[np.ndarray, np.ndarray, np.ndarray]], Certificate]
) -> Certificate | None:
    """The first passing certificate with recovered multipliers, else the first one tried, else None.

    A row the answer leaves slightly open may still bind at the optimum: a wider active set
    second (extra rows only cost their complementarity in the bound).
    """
    first: Certificate | None = None
    for active in (tol.active, 100.0 * tol.active):
        recovered = recover_multipliers(qp, x, active)
        if recovered is None:
            continue
        cert = judge(recovered)
        if cert.passed:
            return cert
        if first is None:
            first = cert
    return first


def _curvature_vector(curvature: np.ndarray | float | None, n: int) -> np.ndarray:
    """The ``curvature`` argument of :func:`certify` as one entry per variable (0 when None)."""
    if curvature is None:
        return np.zeros(n)
    if np.ndim(curvature) == 0:
        return np.full(n, float(curvature))  # type: ignore[arg-type]
    return np.asarray(curvature, dtype=float)


def _early_reason(
    r_p: float, f: float, upper: float, level_value: float | None, modulus: float | None, x: np.ndarray, tol: Tolerances
) -> str:
    """Why the answer fails whatever its multipliers (primal residual, worse than a feasible point), or ""."""
    if r_p > tol.primal:
        return f"primal residual {r_p:.3g} > {tol.primal:g}"
    if _too_far(f - upper, f, level_value, modulus, x, tol):
        return f"objective {f:.9g} above a known feasible point's {upper:.9g}"
    return ""


def _early_certificate(cert: Certificate | None, r_p: float, f: float, upper: float, early: str) -> Certificate:
    """The failed certificate of an early reason, with the backend multipliers' residuals when given."""
    if cert is None:
        return Certificate(r_p, math.inf, math.inf, f, -math.inf, upper, "none", False, early)
    return Certificate(r_p, cert.dual_residual, cert.duality_gap, f, cert.lower_bound, upper, "backend", False, early)


def _backend_multipliers(
    qp: _Qp, y: np.ndarray | None, z: np.ndarray | None, z_box: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
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
    r"""The numbers :func:`_judge` computes for the backend's multipliers, in one pass (dense form).

    With :math:`s = h - Gx` and :math:`g = Px + q + G^Tz^+` (module docstring):
    ``out[_R_P]`` :math:`r_p = \max(0, -\min s, \max(lb - x), \max(x - ub))`,
    ``out[_F]`` :math:`f = x^T(\tfrac12 Px + q)`, ``out[_R_D]`` :math:`\|g + z_{box}\|_\infty`,
    ``out[_COMP]`` the complementarity :math:`z^{+T}s`, ``out[_BOX]`` the box term
    :math:`-\sum_i \min_{d_i \in [lb_i - x_i,\ ub_i - x_i]} (g_i d_i + \tfrac12 c_i d_i^2)` (all
    :math:`c_i > 0`, :func:`_box_term`), ``out[_TERMS:]`` the terms of the duality gap
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
    P: np.ndarray,
    q: np.ndarray,
    G: np.ndarray,
    h: np.ndarray,
    x: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
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
    \text{box term})` as :func:`_judge`, to round-off). When they certify ``x`` directly (no early
    reason, the box term within tolerance) that certificate is returned; in every other case —
    a verdict that fails or needs the eigenvector bound, missing or non-finite multipliers, a
    non-finite input — :func:`certify` decides, with the same arguments. The verdict is
    therefore :func:`certify`'s.

    Args:
        P: Cost matrix, a dense float array. Shape (n, n).
        q: Cost vector. Shape (n,).
        G: Inequality matrix, a dense float array (it may have no row). Shape (m, n).
        h: Inequality bounds. Shape (m,).
        x: The answer. Shape (n,).
        lb: Lower bounds of x. Shape (n,).
        ub: Upper bounds of x. Shape (n,).
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
    if (
        z is not None
        and z_box is not None
        and z.ndim == 1
        and z_box.ndim == 1
        and _dense_judgement(P, q, G, h, lb, ub, x, z, z_box, curvature, out)
    ):
        r_p, f = float(out[_R_P]), float(out[_F])
        upper = math.inf if feasible_objective is None else float(feasible_objective)
        sub = float(out[_COMP]) + float(out[_BOX])
        if not _early_reason(r_p, f, upper, level_value, modulus, x, tol) and not _too_far(
            sub, f, level_value, modulus, x, tol
        ):
            r_g = abs(math.fsum(out[_TERMS:].tolist()))
            return Certificate(r_p, float(out[_R_D]), r_g, f, f - sub, upper, "backend", True, "")
    return certify(
        P,
        q,
        G,
        h,
        x,
        lb=lb,
        ub=ub,
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
