r"""Independent lexicographic reference of the HQP cascade, solved to high accuracy.

The problem is the one :mod:`qp_baseline.hqp` solves (docs/design.md §3 "HQP"), written again from the
tasks, without any of the cascade's implementation choices: no null-space elimination, no
dropped rows, no unconstrained shortcut, no min-norm level option. Level :math:`k` (highest
first) is one QP on :math:`x = [\dot q;\ w_k]` with explicit slacks:

.. math::
    \min_{\dot q,\ w_k}\ \|J_k\dot q - r_k\|^2 + \|w_k\|^2 + \epsilon\|\dot q\|^2
    \quad\text{s.t.}\quad
    \begin{cases}
      G_k\dot q - w_k \le h_k,\ \ w_k \ge 0 \\
      G_j\dot q \le h_j + w_j^*,\ \ j < k & \text{(each level's optimal slacks fixed)}\\
      J_j\dot q = J_j\dot q_j^*,\ \ j < k & \text{(equality constraints, independent rows)}\\
      \underline v \le \dot q \le \overline v
    \end{cases}

then one last level :math:`\min \|\dot q\|^2` under every constraint picks the unique
minimum-norm answer among the lexicographic optima. :math:`r = \dot\sigma_d + K\tilde\sigma`
(paper eq. 2); a set task gives the rows of :meth:`~tpik.tasks.SetTask.velocity_bounds`
(:math:`J\dot q \le \dot\sigma_u`, :math:`-J\dot q \le -\dot\sigma_l`, the finite ones); the
box is the cascade's hard joint box (velocity limits and one-step position limits).

Each level QP is solved by Clarabel at tight tolerances (then Clarabel's defaults, then DAQP:
:data:`FIRST_PASSES`), then **polished** (:func:`qp_baseline.polish.polish`: exact KKT solves of
the active set until it repeats); an answer is kept only if its optimality conditions hold
(:func:`qp_baseline.certificate.certify`, tolerances :data:`REFERENCE_TOLERANCES`). A level whose
QP cannot be certified raises :class:`ReferenceSolutionError`: the reference is never a guess.

The level objective compared across methods is a function of the command alone,
:math:`f_k(\dot q) = \|J_k\dot q - r_k\|^2 + \|[G_k\dot q - h_k]^+\|^2` (the smallest slacks
that :math:`\dot q` needs), without :math:`\epsilon`; :func:`level_objectives` evaluates it for any
method's answer.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import qpsolvers

from qp_baseline.certificate import Certificate, Tolerances, certify
from qp_baseline.exceptions import HqpError
from qp_baseline.polish import polish
from qp_baseline.qp_problem import DenseProblem, without_empty_rows
from robots import Kinematics, Robot
from tpik.hierarchy import Hierarchy
from tpik.tasks import SetTask

REFERENCE_TOLERANCES = Tolerances(primal=1e-10, gap=1e-11, level=1e-10, active=1e-9)
"""Optimality conditions every level of the reference meets (see :mod:`qp_baseline.certificate`)."""

FIRST_PASSES: tuple[tuple[str, dict[str, Any]], ...] = (
    (
        "clarabel",
        {"tol_feas": 1e-12, "tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12, "tol_ktratio": 1e-10, "max_iter": 400},
    ),
    ("clarabel", {}),
    ("daqp", {}),
)
"""Backends and settings tried, in order, for the first pass of a reference level; each answer is
polished and certified, the first certified one is kept."""


class ReferenceSolutionError(HqpError):
    """A level of the reference could not be solved to its optimality tolerances."""


@dataclass(frozen=True)
class LevelRows:
    r"""One priority level as rows on :math:`\dot q`.

    Attributes:
        name: Level name.
        J: Stacked equality Jacobians. Shape (m_eq, n).
        r: Their CLIK references :math:`\dot\sigma_d + K\tilde\sigma`. Shape (m_eq,).
        G: Set-task rows :math:`G\dot q \le h`. Shape (m_set, n).
        h: Their bounds. Shape (m_set,).
        owners: Set task of each row. Length m_set.
    """

    name: str
    J: np.ndarray
    r: np.ndarray
    G: np.ndarray
    h: np.ndarray
    owners: tuple[str, ...]


def level_rows(hierarchy: Hierarchy, kin: Kinematics, dt: float) -> list[LevelRows]:
    """Evaluate every task of ``hierarchy`` at ``kin`` into its level's rows.

    Raises:
        ReferenceSolutionError: A task gives a non-finite Jacobian or reference.
    """
    n = kin.nq
    out = []
    for level in hierarchy.levels:
        Js, rs, Gs, hs, owners = [], [], [], [], []
        for task in level.tasks:
            state = task.compute_state(kin)
            if isinstance(task, SetTask):
                lo, hi = task.velocity_bounds(state, dt)
                row = state.jacobian[0]
                if math.isfinite(hi):
                    Gs.append(row)
                    hs.append(hi)
                    owners.append(task.name)
                if math.isfinite(lo):
                    Gs.append(-row)
                    hs.append(-lo)
                    owners.append(task.name)
            else:
                Js.append(state.jacobian)
                rs.append(state.feedforward + task.gain * state.error)
        J = np.vstack(Js) if Js else np.zeros((0, n))
        r = np.concatenate(rs) if rs else np.zeros(0)
        G = np.array(Gs).reshape(-1, n)
        h = np.array(hs, dtype=float)
        if not (np.isfinite(J).all() and np.isfinite(r).all() and np.isfinite(G).all() and np.isfinite(h).all()):
            raise ReferenceSolutionError(f"level '{level.name}': non-finite task Jacobian or reference")
        out.append(LevelRows(level.name, J, r, G, h, tuple(owners)))
    return out


def joint_box(robot: Robot, q: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    r"""The hard joint box [rad/s] of the cascade, from velocity and one-step position limits.

    :math:`\max(-v, \min(v, (q_{min}-q)/dt)) \le \dot q \le \min(v, \max(-v, (q_{max}-q)/dt))`.
    """
    v = np.asarray(robot.v_max, dtype=float)
    with np.errstate(invalid="ignore"):
        lower = np.clip((robot.q_lower - q) / dt, -v, v)
        upper = np.clip((robot.q_upper - q) / dt, -v, v)
    return np.where(np.isfinite(robot.q_lower), lower, -v), np.where(np.isfinite(robot.q_upper), upper, v)


def level_objectives(rows: Sequence[LevelRows], qdot: np.ndarray) -> np.ndarray:
    r""":math:`f_k(\dot q) = \|J_k\dot q - r_k\|^2 + \|[G_k\dot q - h_k]^+\|^2` for every level. Shape (levels,)."""
    out = np.empty(len(rows))
    for k, lv in enumerate(rows):
        e = lv.J @ qdot - lv.r
        w = np.maximum(lv.G @ qdot - lv.h, 0.0)
        out[k] = float(e @ e + w @ w)
    return out


@dataclass
class ReferenceSolution:
    """The lexicographic optimum of one state.

    Attributes:
        qdot: Minimum-norm lexicographic optimum [rad/s]. Shape (n,).
        objectives: :func:`level_objectives` of ``qdot``, one per task level.
        slacks: Optimal slack of every set row, per level (task units / s).
        certificates: Certificate of every level QP (task levels, then the min-norm level).
    """

    qdot: np.ndarray
    objectives: np.ndarray
    slacks: list[np.ndarray] = field(default_factory=list)
    certificates: list[Certificate] = field(default_factory=list)

    @property
    def worst_kkt(self) -> float:
        """Largest primal or dual residual or duality gap over the level QPs."""
        return max(max(c.primal_residual, c.dual_residual, c.duality_gap) for c in self.certificates)


def _independent_rows(J: np.ndarray, v: np.ndarray, rtol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """Rows U_rᵀJ, U_rᵀv spanning the row space of J (linearly independent equality constraints)."""
    if J.shape[0] == 0:
        return J, v
    U, s, _ = np.linalg.svd(J, full_matrices=False)
    rank = int(np.count_nonzero(s > rtol * max(1.0, float(s[0]))))
    Ur = U[:, :rank]
    return Ur.T @ J, Ur.T @ v


def _kkt_ok(cert: Certificate, tolerances: Tolerances) -> bool:
    """Dual residual and duality gap of the certificate's multipliers within 10× the gap tolerance (scaled)."""
    scale = 1.0 + abs(cert.objective)
    return cert.dual_residual <= 10 * tolerances.gap * scale and cert.duality_gap <= 10 * tolerances.gap * scale


def solve_level_qp(
    P: np.ndarray,
    c: np.ndarray,
    G: np.ndarray,
    h: np.ndarray,
    A: np.ndarray,
    b: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    tolerances: Tolerances = REFERENCE_TOLERANCES,
) -> tuple[np.ndarray, Certificate]:
    """:func:`solve_reference_qp` of the QP given by its arrays.

    Raises:
        ReferenceSolutionError: Neither the polished nor the raw answer meets ``tolerances``.
    """
    return solve_reference_qp(DenseProblem(P, c, G, h, A, b, lb, ub), tolerances)


def solve_reference_qp(
    problem: DenseProblem, tolerances: Tolerances = REFERENCE_TOLERANCES
) -> tuple[np.ndarray, Certificate]:
    """Solve one QP to the reference's accuracy: Clarabel, then active-set polish, then certify.

    Raises:
        ReferenceSolutionError: Neither the polished nor the raw answer meets ``tolerances``.
    """
    as_given = without_empty_rows(problem)
    best: Certificate | None = None
    certified: tuple[np.ndarray, Certificate] | None = None
    for solver, settings in FIRST_PASSES:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                sol = qpsolvers.solve_problem(as_given, solver=solver, **settings)
            except Exception:  # noqa: BLE001 - a backend error only means: try the next first pass
                continue
        if sol.x is None or not np.isfinite(sol.x).all():
            continue
        candidates = [sol]
        polished = polish(problem, sol.x.copy(), sol.z, sol.z_box)
        if polished is not None:
            candidates.insert(0, polished)
        for answer in candidates:
            x = answer.x
            if x is None:
                continue
            cert = certify(problem, x, y=answer.y, z=answer.z, z_box=answer.z_box, tolerances=tolerances)
            if cert.passed and not _kkt_ok(cert, tolerances):
                # The bound holds but the multipliers' own residuals are off: recover them for x.
                cert = certify(problem, x, tolerances=tolerances)
            if cert.passed and _kkt_ok(cert, tolerances):
                return x, cert
            if cert.passed and certified is None:
                certified = (x, cert)  # the bound holds; the qpbenchmark residuals are looser
            if best is None or cert.primal_residual < best.primal_residual:
                best = cert
    if certified is not None:
        return certified
    if best is None:
        raise ReferenceSolutionError("no backend found a solution of a reference level QP (feasible by construction)")
    raise ReferenceSolutionError(f"reference level QP not certified: {best.reason}")


def _task_level_qp(
    lv: LevelRows,
    fixed_G: np.ndarray,
    fixed_h: np.ndarray,
    A: np.ndarray,
    b: np.ndarray,
    lb: np.ndarray,
    ub: np.ndarray,
    regularization: float,
) -> DenseProblem:
    r"""The QP of one task level in x = [q̇; w] (module docstring).

    :math:`\min \|J\dot q - r\|^2 + \epsilon\|\dot q\|^2 + \|w\|^2` under the earlier levels'
    fixed rows, this level's rows with slack w ≥ 0, the earlier equality rows ``A q̇ = b`` and the box.
    """
    n, m = lb.shape[0], lv.h.size
    d = n + m
    P = np.zeros((d, d))
    P[:n, :n] = 2.0 * (lv.J.T @ lv.J + regularization * np.eye(n))
    P[n:, n:] = 2.0 * np.eye(m)
    c = np.concatenate([-2.0 * lv.J.T @ lv.r, np.zeros(m)])
    G = np.zeros((fixed_h.size + m, d))
    G[: fixed_h.size, :n] = fixed_G
    G[fixed_h.size :, :n] = lv.G
    G[fixed_h.size :, n:] = -np.eye(m)
    h = np.concatenate([fixed_h, lv.h])
    A_x = np.hstack([A, np.zeros((A.shape[0], m))])
    x_lb = np.concatenate([lb, np.zeros(m)])
    # A finite slack bound every backend accepts: above the largest violation the box allows.
    reach = lv.G @ (0.5 * (ub + lb)) + np.abs(lv.G) @ (0.5 * (ub - lb)) - lv.h
    x_ub = np.concatenate([ub, np.maximum(reach, 0.0) + 1.0])
    return DenseProblem(P, c, G, h, A_x, b, x_lb, x_ub)


def solve_reference(
    rows: Sequence[LevelRows],
    lb: np.ndarray,
    ub: np.ndarray,
    regularization: float = 1e-9,
    tolerances: Tolerances = REFERENCE_TOLERANCES,
) -> ReferenceSolution:
    """The lexicographic optimum of ``rows`` in the box ``[lb, ub]`` (module docstring).

    Args:
        rows: Levels, highest first (:func:`level_rows`).
        lb: Lower velocity bounds [rad/s]. Shape (n,).
        ub: Upper velocity bounds [rad/s]. Shape (n,).
        regularization: ε of every task level (the cascade's default).
        tolerances: Optimality tolerances of every level QP.

    Raises:
        ReferenceSolutionError: A level QP could not be certified.
    """
    n = lb.shape[0]
    qdot = np.clip(np.zeros(n), lb, ub)
    fixed_G = np.zeros((0, n))
    fixed_h = np.zeros(0)
    eq_J = np.zeros((0, n))
    slacks: list[np.ndarray] = []
    certs: list[Certificate] = []
    for lv in rows:
        m = lv.h.size
        if lv.r.size == 0 and m == 0:
            slacks.append(np.zeros(0))
            continue
        A, b = _independent_rows(eq_J, eq_J @ qdot)
        x, cert = solve_reference_qp(_task_level_qp(lv, fixed_G, fixed_h, A, b, lb, ub, regularization), tolerances)
        qdot = np.clip(x[:n], lb, ub)
        w = np.maximum(lv.G @ qdot - lv.h, 0.0)
        slacks.append(w)
        certs.append(cert)
        # Fix this level's slacks (and absorb any round-off of the earlier rows) for the levels below.
        fixed_G = np.vstack([fixed_G, lv.G])
        fixed_h = np.concatenate([np.maximum(fixed_h, fixed_G[: fixed_h.size] @ qdot), lv.h + w])
        if lv.r.size:
            eq_J = np.vstack([eq_J, lv.J])
    # Min-norm level.
    A, b = _independent_rows(eq_J, eq_J @ qdot)
    x, cert = solve_level_qp(
        2.0 * np.eye(n), np.zeros(n), fixed_G, np.maximum(fixed_h, fixed_G @ qdot), A, b, lb, ub, tolerances
    )
    certs.append(cert)
    qdot = np.clip(x, lb, ub)
    return ReferenceSolution(qdot, level_objectives(rows, qdot), slacks, certs)


def lexicographic_reference(
    hierarchy: Hierarchy, robot: Robot, kin: Kinematics, dt: float, regularization: float = 1e-9
) -> tuple[ReferenceSolution, list[LevelRows]]:
    """Reference of one state: :func:`level_rows` and :func:`solve_reference` in the hard joint box.

    Returns:
        (the reference, the level rows it was computed from).
    """
    rows = level_rows(hierarchy, kin, dt)
    lb, ub = joint_box(robot, kin.q, dt)
    return solve_reference(rows, lb, ub, regularization), rows
