r"""Correctness certificate of one QP answer: qpbenchmark's residuals and a bound on the distance to the optimum.

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

:func:`qp_baseline.certificate_dense.certify_dense` gives the same verdict for the form the HQP
cascade poses, a passing one in one compiled call; :mod:`qp_baseline.dual_bound` holds the pieces
of the bound.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import qpsolvers

from qp_baseline.dual_bound import (
    Multipliers,
    backend_multipliers,
    box_term,
    eigen_box_term,
    primal_residual,
    recover_multipliers,
)
from qp_baseline.qp_problem import DenseProblem, dense_problem

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


def _judge(
    qp: DenseProblem,
    x: np.ndarray,
    Px: np.ndarray,
    slack: np.ndarray,
    multipliers: Multipliers,
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
    finite_lb = math.isfinite(float(np.abs(qp.lb).max(initial=0.0)))
    finite_ub = math.isfinite(float(np.abs(qp.ub).max(initial=0.0)))
    lo_part, hi_part = qp.lb @ zb_lo if finite_lb else math.nan, qp.ub @ zb_hi if finite_ub else math.nan
    if not finite_lb:
        fin = np.isfinite(qp.lb)
        lo_part = math.inf if (zb_lo[~fin] != 0.0).any() else float(qp.lb[fin] @ zb_lo[fin])
    if not finite_ub:
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
    sub = comp + eq + box_term(g, x, qp.lb, qp.ub, curvature)
    if x.size and too_far(sub, f, level_value, modulus, x, tol):
        sub = min(sub, comp + eq + eigen_box_term(g, x, qp.lb, qp.ub, qp.P))
    lower = f - sub if math.isfinite(sub) else -math.inf
    reason = ""
    if not math.isfinite(sub):
        reason = "no finite bound from these multipliers"
    elif too_far(sub, f, level_value, modulus, x, tol):
        reason = f"objective may be {sub:.3g} above the optimum ({_tolerance_text(level_value, modulus, x, tol)})"
    return Certificate(r_p, r_d, r_g, f, lower, upper, source, not reason, reason)


def too_far(
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
    """The tolerance a failed bound broke, as the certificate's reason names it."""
    if modulus is not None:
        return f"distance to the optimum > {tol.level:g}·(1 + ‖x‖∞)"
    if level_value is None:
        return f"> {tol.gap:g}·(1 + |f|)"
    rho = math.sqrt(2.0 * max(level_value, 0.0))
    return f"level residual {rho:.6g}, > {tol.level:g}·(1 + ρ) in it"


def certify(
    problem: qpsolvers.Problem,
    x: np.ndarray,
    *,
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
        problem: The QP (dense or sparse matrices; None fields: no such rows or bounds).
        x: The answer. Shape (n,).
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
    qp = dense_problem(problem)
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
    given = backend_multipliers(qp, y, z, z_box)
    early = early_reason(r_p, f, upper, level_value, modulus, x, tol)
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
    qp: DenseProblem, x: np.ndarray, tol: Tolerances, judge: Callable[[Multipliers], Certificate]
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


def early_reason(
    r_p: float, f: float, upper: float, level_value: float | None, modulus: float | None, x: np.ndarray, tol: Tolerances
) -> str:
    """Why the answer fails whatever its multipliers (primal residual, worse than a feasible point), or ""."""
    if r_p > tol.primal:
        return f"primal residual {r_p:.3g} > {tol.primal:g}"
    if too_far(f - upper, f, level_value, modulus, x, tol):
        return f"objective {f:.9g} above a known feasible point's {upper:.9g}"
    return ""


def _early_certificate(cert: Certificate | None, r_p: float, f: float, upper: float, early: str) -> Certificate:
    """The failed certificate of an early reason, with the backend multipliers' residuals when given."""
    if cert is None:
        return Certificate(r_p, math.inf, math.inf, f, -math.inf, upper, "none", False, early)
    return Certificate(r_p, cert.dual_residual, cert.duality_gap, f, cert.lower_bound, upper, "backend", False, early)
