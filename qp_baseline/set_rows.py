r"""Set-based tasks as velocity inequality rows :math:`G\dot q \le h`, built once for HQP and mink.

Each set-based task σ with Jacobian row J has the reference rates of :mod:`tpik.reference`,
:math:`\dot\sigma_l = K(\sigma_{s,l} - \sigma)` and :math:`\dot\sigma_u = K(\sigma_{s,u} - \sigma)`.
A finite upper rate gives the row :math:`J\dot q \le \dot\sigma_u`, a finite lower one
:math:`-J\dot q \le -\dot\sigma_l`; a non-finite σ (no obstacle in range) gives no row.

``hold_at_zero`` (mink as its users run it): the bounds are relaxed to
:math:`J\dot q \le \max(0, \dot\sigma_u)` and :math:`J\dot q \ge \min(0, \dot\sigma_l)`, so
:math:`\dot q = 0` satisfies every row whatever σ: inside the safety set the task may approach
its threshold no faster than its reference; past it, it may not move further out (mink's
``CollisionAvoidanceLimit`` and ``ConfigurationLimit`` behave the same way). Coming back is then
the business of a soft task (:mod:`qp_baseline.mink_peer`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from robots import Kinematics
from tpik.exceptions import InvalidTaskState
from tpik.reference import ControlReference
from tpik.tasks import SetTask


@dataclass(frozen=True)
class SetRows:
    r"""Rows :math:`G\dot q \le h` of a list of set-based tasks at one state.

    Attributes:
        G: Row per bound: ``J`` (upper) or ``-J`` (lower). Shape (r, n).
        h: Bounds [task unit/s]. Shape (r,).
        owner: Index of each row's task in the builder's task list. Shape (r,).
        sigma: σ of every task of the builder (non-finite when not evaluable). Shape (T,).
    """

    G: np.ndarray
    h: np.ndarray
    owner: np.ndarray
    sigma: np.ndarray


class SetRowBuilder:
    """Builds :class:`SetRows` for a fixed list of set-based tasks (HQP and the mink peers).

    Args:
        tasks: The set-based tasks, in the order rows are emitted (HQP: level after level).
        nq: Number of joints ``n``.
        reference: The method's control reference (gain cap).
        hold_at_zero: Relax the bounds so that q̇ = 0 is always feasible (module docstring).
    """

    def __init__(
        self, tasks: Sequence[SetTask], nq: int, reference: ControlReference, hold_at_zero: bool = False
    ) -> None:
        self.tasks = tuple(tasks)
        self.nq = int(nq)
        self.reference = reference
        self.hold_at_zero = hold_at_zero
        self._empty = SetRows(np.zeros((0, self.nq)), np.zeros(0), np.zeros(0, dtype=int), np.zeros(0))

    def build(self, kin: Kinematics, dt: float) -> SetRows:
        """Evaluate every task once at ``kin`` and stack its finite bounds.

        Raises:
            InvalidTaskState: A task's Jacobian is not finite (names the task).
            tpik.exceptions.TpikError: Whatever the task's own evaluation raises.
        """
        if not self.tasks:
            return self._empty
        rows: list[np.ndarray] = []
        bounds: list[float] = []
        owner: list[int] = []
        sigma = np.empty(len(self.tasks))
        hold = self.hold_at_zero
        ref = self.reference
        for i, task in enumerate(self.tasks):
            state = task.compute_state(kin)
            s = float(state.value[0])
            sigma[i] = s
            if not math.isfinite(s):
                continue
            lo, hi = ref.set_rates(task, s, dt)
            jac = state.jacobian[0]
            if hi < math.inf:  # J q̇ ≤ hi
                rows.append(jac)
                bounds.append(max(hi, 0.0) if hold else hi)
                owner.append(i)
            if lo > -math.inf:  # −J q̇ ≤ −lo
                rows.append(-jac)
                bounds.append(-min(lo, 0.0) if hold else -lo)
                owner.append(i)
            if not np.isfinite(jac).all():
                raise InvalidTaskState(f"task '{task.name}': jacobian has non-finite entries")
        if not rows:
            return SetRows(self._empty.G, self._empty.h, self._empty.owner, sigma)
        return SetRows(np.array(rows), np.array(bounds), np.array(owner), sigma)


__all__ = ["SetRowBuilder", "SetRows"]
