r"""One level of the cascade as a QP in :math:`x = [z;\ w]`, :math:`\dot q = \dot q^*_{k-1} + Z z`.

Level :math:`k` minimises :math:`\|J_k\dot q - r_k\|^2 + \|w\|^2 + \epsilon\|\dot q\|^2` under
the earlier levels' set rows (relaxed by their optimal slacks), its own set rows with slack
:math:`w \ge 0` and the hard box. The earlier equality rows are eliminated: :math:`Z` is an
orthonormal basis of their null space, so no backend sees dependent equality constraints.

* **Slacks** are bounded :math:`0 \le w \le w_{max}`, :math:`w_{max}` above the largest
  violation the box allows (a finite bound every backend accepts). The QP is feasible by
  construction: :math:`z = 0` with :math:`w = \max(0, G\dot q^*_{k-1} - h)` is a known feasible
  point (:class:`~qp_baseline.level_qp.QpCheck`).
* With :math:`Z \ne I` the box becomes rows on z; rows that the eliminated equality rows make
  :math:`0 \cdot z \le h` are dropped (some backends take them for an infeasibility, and they
  make the dual ill-posed).
* The check of an answer: its slacks set to their minimal value (``refine``), a curvature
  :math:`P \succeq \mathrm{diag}(c)` for the certificate's bound, and the level objective
  :math:`\tfrac12(\|J\dot q - r\|^2 + \|w\|^2)` (task levels) or the strong-convexity modulus of
  :math:`P = (1 + \epsilon)I` (the min-norm level, judged on its answer itself).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from qp_baseline.cascade_kernels import level_objective
from qp_baseline.level_qp import QpCheck
from qp_baseline.qp_problem import DenseProblem


@dataclass
class CascadeLevel:
    r"""One level as the cascade poses it: its rows in :math:`\dot q` and where it starts from.

    Attributes:
        k: Level index (the number of task levels for the min-norm level).
        qd: :math:`\dot q^*_{k-1}`, the answer of the levels above. Shape (n,).
        Z: Null-space basis of the earlier equality rows; None: the identity. Shape (n, d).
        J: Equality Jacobian of the level (the identity on the min-norm level). Shape (m_eq, n).
        r: Its reference (zero on the min-norm level). Shape (m_eq,).
        G_all: Every set row of the step, level after level. Shape (m, n).
        h_rel: Their bounds, relaxed by the solved levels' slacks. Shape (m,).
        c0: First row of this level in ``G_all``.
        c1: End of this level's rows (rows ``:c0`` are the earlier levels').
        lb: Lower bounds of the hard box [rad/s]. Shape (n,).
        ub: Upper bounds of the hard box [rad/s]. Shape (n,).
        eps: Regularisation ε.
        margin: Relaxation of every row of the QP (the min-norm level's δ; 0 otherwise).
        min_norm: Whether this is the min-norm level.
        at_zero: Z = I and :math:`\dot q^*_{k-1} = 0`: the products with it are spared.
    """

    k: int
    qd: np.ndarray
    Z: np.ndarray | None
    J: np.ndarray
    r: np.ndarray
    G_all: np.ndarray
    h_rel: np.ndarray
    c0: int
    c1: int
    lb: np.ndarray
    ub: np.ndarray
    eps: float
    margin: float
    min_norm: bool = False
    at_zero: bool = False

    @property
    def d(self) -> int:
        """Number of free variables z."""
        return self.qd.shape[0] if self.Z is None else self.Z.shape[1]

    def qdot(self, z: np.ndarray) -> np.ndarray:
        r""":math:`\dot q = \dot q^*_{k-1} + Z z` (a new array)."""
        if self.at_zero:
            return z.copy()
        return self.qd + z if self.Z is None else self.qd + self.Z @ z


class LevelQpBuilder:
    """Builds the QP of each cascade level (one per solver; caches the curvature vectors).

    Args:
        n: Number of joints.
        regularization: ε of every task level.
    """

    def __init__(self, n: int, regularization: float) -> None:
        self.eye = np.eye(n)
        """The min-norm level's J."""
        self.zeros = np.zeros(n)
        """The min-norm level's r."""
        self.regularization = regularization
        self._eps_eye = regularization * np.eye(n)
        self._no_rows = np.zeros(0)
        self._curvatures: dict[tuple[int, int, float], np.ndarray] = {}

    def cost(self, lv: CascadeLevel) -> tuple[np.ndarray | None, np.ndarray | None]:
        r"""Cost of the level in z, :math:`P_z = (JZ)^T JZ + \epsilon I` and :math:`q_z`.

        (None, None) without equality rows (P = εI, see :meth:`build`).
        """
        J, r, qd, Z, eps = lv.J, lv.r, lv.qd, lv.Z, lv.eps
        if not r.size:
            return None, None
        JZ = J if Z is None else J @ Z
        d = JZ.shape[1]
        Pz = JZ.T @ JZ
        Pz += self._eps_eye if d == qd.shape[0] and eps == self.regularization else eps * np.eye(d)
        if lv.at_zero:
            qz = -(JZ.T @ r)
        else:
            qz = JZ.T @ (J @ qd - r)
            if eps:
                qz += eps * (qd if Z is None else Z.T @ qd)
        return Pz, qz

    def build(
        self, lv: CascadeLevel, Pz: np.ndarray | None, qz: np.ndarray | None
    ) -> tuple[DenseProblem, QpCheck, int]:
        """The level's QP in x = [z; w]: earlier rows, this level's rows with slack w, the box.

        Args:
            lv: The level.
            Pz: Its cost matrix in z (:meth:`cost`; None: εI).
            qz: Its cost vector in z (None: that of εI).

        Returns:
            (the QP, how its answers are judged, the number of slacks: the last entries of x).
        """
        if Pz is None or qz is None:
            Pz = np.eye(lv.d) * lv.eps
            qz = lv.eps * (lv.qd if lv.Z is None else lv.Z.T @ lv.qd)
        G_rows, h, own0, z_lb, z_ub = self._rows_in_z(lv)
        if lv.margin:
            h = h + lv.margin
        d, m = lv.d, lv.c1 - lv.c0
        refine = None
        if m == 0:  # no slack variable: x = z
            problem, x0, f0 = DenseProblem(Pz, qz, G_rows, h, lb=z_lb, ub=z_ub), np.zeros(d), 0.0
        else:
            G_own, h_own = lv.G_all[lv.c0 : lv.c1], lv.h_rel[lv.c0 : lv.c1]
            G = np.zeros((G_rows.shape[0], d + m))
            G[:, :d] = G_rows
            G[own0 : own0 + m, d:] = -np.eye(m)
            violation = np.maximum(G_own @ lv.qd - h_own, 0.0)  # slack of the known feasible point
            reach = G_own @ (0.5 * (lv.ub + lv.lb)) + np.abs(G_own) @ (0.5 * (lv.ub - lv.lb))
            x_lb = np.concatenate([z_lb, np.zeros(m)])
            x_ub = np.concatenate([z_ub, np.maximum(reach - h_own, violation) + 1.0])
            P = np.zeros((d + m, d + m))
            P[:d, :d] = Pz
            P.flat[d * (d + m) + d :: d + m + 1] = 1.0
            x0 = np.concatenate([np.zeros(d), violation])
            f0 = 0.5 * float(violation @ violation)
            problem = DenseProblem(P, np.concatenate([qz, np.zeros(m)]), G, h, lb=x_lb, ub=x_ub)
            refine = minimal_slacks(G[own0 : own0 + m, :d], h[own0 : own0 + m], d)
        eps = lv.eps
        # P ⪰ diag(curvature): (JZ)ᵀJZ + εI ⪰ εI (JZ = Z, orthonormal, on the min-norm level), I on slacks.
        curvature = self._curvature(d, m, 1.0 + eps if lv.min_norm else eps)
        # Task levels are judged on their objective; the min-norm level (P = (1 + ε)I) on its
        # answer itself: it only picks the null-space part of q̇.
        if lv.min_norm:
            return problem, QpCheck(x0, f0, None, refine, curvature, 1.0 + eps), m
        return problem, QpCheck(x0, f0, self._level_value(lv, problem), refine, curvature, None), m

    def _curvature(self, d: int, m: int, bend: float) -> np.ndarray:
        """``bend`` on the d variables z, 1 on the m slacks (cached per shape; read, never written)."""
        key = (d, m, bend)
        curvature = self._curvatures.get(key)
        if curvature is None:
            curvature = np.concatenate([np.full(d, bend), np.ones(m)])
            self._curvatures[key] = curvature
        return curvature

    @staticmethod
    def _rows_in_z(lv: CascadeLevel) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray]:
        """Rows on z of the earlier and this level's set rows (and the box when Z ≠ I), z bounds.

        Returns:
            (G rows, h, index of this level's first row, z lower, z upper).
        """
        qd, Z, G_all, h_rel, c0, c1, lb, ub = lv.qd, lv.Z, lv.G_all, lv.h_rel, lv.c0, lv.c1, lv.lb, lv.ub
        if lv.at_zero:
            return G_all[:c1], h_rel[:c1], c0, lb, ub
        if Z is None:
            return G_all[:c1], h_rel[:c1] - G_all[:c1] @ qd, c0, lb - qd, ub - qd
        d = lv.d
        radius = float(np.linalg.norm(ub - lb)) + 1.0  # ‖z‖ = ‖Z z‖ ≤ diameter of the box
        # The box as rows on z; a joint the earlier equality rows fix entirely gives a zero
        # row "0 ≤ 0" that some backends take for an infeasibility: drop those.
        box_G, box_h = np.vstack([Z, -Z]), np.concatenate([ub - qd, qd - lb])
        live = np.abs(box_G).max(axis=1) > 1e-12
        # Likewise an earlier level's row whose Jacobian lies in the row space of the eliminated
        # equality rows (a wall on the EE under an EE position task): ≈ 0·z ≤ h holds for every
        # z (it holds at z = 0 by construction) and only makes the dual ill-posed (OSQP ran to
        # its iteration limit on such min-norm levels): drop those too.
        GZ = G_all[:c1] @ Z
        h_z = h_rel[:c1] - G_all[:c1] @ qd
        alive = np.abs(GZ[:c0]).max(axis=1, initial=0.0) > 1e-12
        own0 = int(alive.sum())
        G_rows = np.vstack([GZ[:c0][alive], GZ[c0:], box_G[live]])
        h = np.concatenate([h_z[:c0][alive], h_z[c0:], box_h[live]])
        return G_rows, h, own0, np.full(d, -radius), np.full(d, radius)

    def _level_value(self, lv: CascadeLevel, problem: DenseProblem) -> Callable[[np.ndarray], float]:
        r"""½(‖J q̇ − r‖² + ‖w‖²) of an answer x = [z; w].

        It is :math:`f(x) + \tfrac12\|J q_d - r\|^2 + \tfrac12\epsilon\|q_d\|^2 - \tfrac12\epsilon\|\dot q(x)\|^2`;
        compiled when Z = I (:func:`~qp_baseline.cascade_kernels.level_objective`).
        """
        qd, Z, d, eps, at_zero = lv.qd, lv.Z, lv.d, lv.eps, lv.at_zero
        P, q_vec = problem.P, problem.q
        if at_zero:  # q_d = 0: J q_d − r = −r
            offset = 0.5 * float(lv.r @ lv.r) if lv.r.size else 0.0
        else:
            res0 = (lv.J @ qd - lv.r) if lv.r.size else self._no_rows
            offset = 0.5 * float(res0 @ res0 + eps * (qd @ qd))
        if Z is None:
            return lambda x: level_objective(P, q_vec, x, qd, at_zero, offset, eps)  # type: ignore[no-any-return]

        def level_value(x: np.ndarray) -> float:
            qdot = x[:d] if at_zero else (qd + x[:d] if Z is None else qd + Z @ x[:d])
            return float(x @ (0.5 * (P @ x) + q_vec)) + offset - 0.5 * eps * float(qdot @ qdot)

        return level_value


def minimal_slacks(G_slack: np.ndarray, h_slack: np.ndarray, d: int) -> Callable[[np.ndarray], np.ndarray]:
    """Map x = [z; w] to the same z with its minimal slacks w = max(0, G q̇ − h) (feasible, no worse)."""

    def refine(x: np.ndarray) -> np.ndarray:
        out = x.copy()
        out[d:] = np.maximum(G_slack @ x[:d] - h_slack, 0.0)
        return out

    return refine


def warm_start_point(previous: np.ndarray, lv: CascadeLevel, problem: DenseProblem) -> np.ndarray:
    """A level's previous-step answer ``previous`` (q̇) in this step's variables x = [z; w], in the box."""
    qd, Z, at_zero = lv.qd, lv.Z, lv.at_zero
    G_own, h_own = lv.G_all[lv.c0 : lv.c1], lv.h_rel[lv.c0 : lv.c1]
    if at_zero:
        z = previous.copy()
    else:
        z = previous - qd if Z is None else Z.T @ (previous - qd)
    if h_own.size:
        qdot = z if at_zero else (qd + z if Z is None else qd + Z @ z)
        z = np.concatenate([z, np.maximum(G_own @ qdot - h_own, 0.0)])
    return np.clip(z, problem.lb, problem.ub)
