r"""Set-based tasks as velocity inequality rows :math:`G\dot q \le h`, built once for HQP and mink.

Each set-based task σ with Jacobian row J has the reference rates of :mod:`tpik.reference`,
:math:`\dot\sigma_l = K(\sigma_{s,l} - \sigma)` and :math:`\dot\sigma_u = K(\sigma_{s,u} - \sigma)`.
A finite upper rate gives the row :math:`J\dot q \le \dot\sigma_u`, a finite lower one
:math:`-J\dot q \le -\dot\sigma_l`; a non-finite σ (no obstacle in range) gives no row.

``hold_at_zero`` (the ``mink`` peer): the bounds are relaxed to
:math:`J\dot q \le \max(0, \dot\sigma_u)` and :math:`J\dot q \ge \min(0, \dot\sigma_l)`, so
:math:`\dot q = 0` satisfies every row whatever σ: inside the safety set the task may approach
its threshold no faster than its reference; past it, it may not move further out (mink's
``CollisionAvoidanceLimit`` and ``ConfigurationLimit`` behave the same way). Coming back is then
the business of a soft task (:mod:`qp_baseline.mink_peer`).

σ and J come from the shared task evaluation (:class:`tpik.evaluation.TaskEvaluation`, the
same pass TPIK uses); the rows are stacked in one compiled call (:func:`_stack_rows`). HQP
evaluates all its tasks in one pass of its own and takes the rows that can bind in its hard box
from :meth:`SetRowBuilder.binding` (one more compiled call, :func:`_binding_rows`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from robots import Kinematics
from tpik.evaluation import (
    SET_FEEDFORWARD,
    SET_GAIN,
    SET_JAC,
    SET_SAFE_HI,
    SET_SAFE_LO,
    SET_SIGMA,
    TaskEvaluation,
    warm_up,
)
from tpik.exceptions import InvalidTaskState
from tpik.reference import ControlReference
from tpik.tasks import SetTask


@numba.njit(cache=True, nogil=True)
def _stack_rows(
    set_out: np.ndarray,
    set_in: np.ndarray,
    dt: float,
    gain_cap: bool,
    hold: bool,
    G: np.ndarray,
    h: np.ndarray,
    owner: np.ndarray,
) -> int:
    r"""Rows :math:`J\dot q \le \dot\sigma_u`, :math:`-J\dot q \le -\dot\sigma_l` of every finite σ, task by task.

    The rates are :func:`tpik.reference.rate_bounds`' (K capped at 1/dt with ``gain_cap``, plus
    the task's rate feed-forward);
    ``hold`` relaxes them to :math:`\max(0, \dot\sigma_u)`, :math:`\min(0, \dot\sigma_l)`.

    Returns:
        The number of rows written into ``G``, ``h``, ``owner``.
    """
    r = 0
    for s in range(set_out.shape[0]):
        sigma = set_out[s, SET_SIGMA]
        if not np.isfinite(sigma):
            continue
        k = set_in[s, SET_GAIN]
        if gain_cap:
            k_max = 1.0 / dt
            k = k if k < k_max else k_max
        lo = k * (set_in[s, SET_SAFE_LO] - sigma) + set_in[s, SET_FEEDFORWARD]
        hi = k * (set_in[s, SET_SAFE_HI] - sigma) + set_in[s, SET_FEEDFORWARD]
        if hi < np.inf:  # J q̇ ≤ hi
            G[r] = set_out[s, SET_JAC:]
            h[r] = (hi if hi >= 0.0 else 0.0) if hold else hi
            owner[r] = s
            r += 1
        if lo > -np.inf:  # −J q̇ ≤ −lo
            G[r] = -set_out[s, SET_JAC:]
            h[r] = -(lo if lo <= 0.0 else 0.0) if hold else -lo
            owner[r] = s
            r += 1
    return r


@numba.njit(cache=True, nogil=True)
def _binding_rows(
    G: np.ndarray,
    h: np.ndarray,
    owner: np.ndarray,
    count: int,
    lb: np.ndarray,
    ub: np.ndarray,
    task_level: np.ndarray,
    cuts: np.ndarray,
) -> int:
    r"""Keep, in place and in order, the first ``count`` rows that can bind in the box; their level cuts.

    A row :math:`g^T\dot q \le h` can bind when
    :math:`\max_{\underline v \le \dot q \le \overline v} g^T\dot q = g^Tc + |g|^Tr > h`, with
    the box centre :math:`c = \tfrac12(\overline v + \underline v)` and half-width
    :math:`r = \tfrac12(\overline v - \underline v)`; any other row is redundant given the box.
    ``cuts[k]`` (shape (L + 1,)) becomes the number of kept rows of the levels before k
    (``task_level``: level of each task, rows ordered by level).

    Returns:
        The number of rows kept.
    """
    n, L = G.shape[1], cuts.shape[0] - 1
    cuts[:] = 0
    kept = 0
    for r in range(count):
        centre, spread = 0.0, 0.0
        for j in range(n):
            centre += G[r, j] * (0.5 * (ub[j] + lb[j]))
            spread += abs(G[r, j]) * (0.5 * (ub[j] - lb[j]))
        if not centre + spread > h[r]:
            continue
        if kept != r:
            G[kept] = G[r]
            h[kept] = h[r]
            owner[kept] = owner[r]
        for k in range(task_level[owner[r]] + 1, L + 1):
            cuts[k] += 1
        kept += 1
    return kept


def warm_up_rows(nq: int) -> None:
    """Load the compiled evaluation and row kernels now (a solver's construction), not at its first control step."""
    warm_up(nq)
    if not _stack_rows.signatures:
        empty = np.zeros((0, SET_JAC + nq))
        _stack_rows(empty, np.zeros((0, 13)), 0.01, True, False, empty, np.zeros(0), np.zeros(0, dtype=np.int64))
    if not _binding_rows.signatures:
        one = np.zeros(1)
        _binding_rows(
            np.zeros((0, 1)),
            one[:0],
            np.zeros(0, dtype=np.int64),
            0,
            one,
            one,
            np.zeros(0, dtype=np.int64),
            np.zeros(1, dtype=np.int64),
        )


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
        self._evaluation: TaskEvaluation | None = None  # built at the first step (needs the robot)
        S = len(self.tasks)
        self._G, self._h, self._owner = np.empty((2 * S, self.nq)), np.empty(2 * S), np.empty(2 * S, dtype=np.int64)
        warm_up_rows(self.nq)

    def build(self, kin: Kinematics, dt: float) -> SetRows:
        """Evaluate every task once at ``kin`` and stack its finite bounds.

        Raises:
            InvalidTaskState: A task's Jacobian is not finite (names the task).
            tpik.exceptions.TpikError: Whatever the task's own evaluation raises.
        """
        if not self.tasks:
            return self._empty
        ev = self._evaluation
        if ev is None:
            ev = self._evaluation = TaskEvaluation(self.tasks, kin.robot)
        ev.evaluate(kin)
        return self.rows(ev, dt)

    def rows(self, ev: TaskEvaluation, dt: float) -> SetRows:
        """:class:`SetRows` of an evaluated ``ev`` whose set tasks are :attr:`tasks` (copies, kept by the caller).

        For a caller that evaluates these tasks with others in one pass of its own (the mink
        peer: its equality tasks too); :meth:`build` is this after its own evaluation.

        Raises:
            InvalidTaskState: A task's Jacobian is not finite (names the task).
        """
        if not self.tasks:
            return self._empty
        count = self._stack(ev, dt)
        sigma = ev.set_out[:, SET_SIGMA].copy()
        if count == 0:
            return SetRows(self._empty.G, self._empty.h, self._empty.owner, sigma)
        return SetRows(self._G[:count].copy(), self._h[:count].copy(), self._owner[:count].copy(), sigma)

    def _stack(self, ev: TaskEvaluation, dt: float) -> int:
        """Rows of an evaluated ``ev`` (its set tasks are :attr:`tasks`) into the buffers; their number.

        Raises:
            InvalidTaskState: A task's Jacobian is not finite (names the task).
        """
        count: int = _stack_rows(
            ev.set_out, ev.set_in, float(dt), self.reference.gain_cap, self.hold_at_zero, self._G, self._h, self._owner
        )
        if not np.isfinite(self._G[:count]).all():
            for i in self._owner[:count].tolist():
                if not np.isfinite(ev.set_out[i, SET_JAC:]).all():
                    raise InvalidTaskState(f"task '{self.tasks[i].name}': jacobian has non-finite entries")
        return count

    def binding(
        self, ev: TaskEvaluation, dt: float, lb: np.ndarray, ub: np.ndarray, task_level: np.ndarray, cuts: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r"""The rows of an evaluated ``ev`` that can bind in the box :math:`[lb, ub]`, level after level.

        ``ev`` holds :attr:`tasks` as its set tasks, evaluated (:meth:`TaskEvaluation.evaluate`,
        e.g. by the caller's own pass over every task); a row that cannot reach its bound in the
        box is redundant and left out (:func:`_binding_rows`). ``cuts`` (L + 1,) is filled: the
        rows of level k are ``cuts[k]:cuts[k + 1]`` (``task_level``: level of each task).

        Returns:
            (G, h, owner): views of the builder's buffers, valid until its next call.

        Raises:
            InvalidTaskState: A task's Jacobian is not finite (names the task).
        """
        count = self._stack(ev, dt) if self.tasks else 0
        kept = _binding_rows(self._G, self._h, self._owner, count, lb, ub, task_level, cuts)
        return self._G[:kept], self._h[:kept], self._owner[:kept]


__all__ = ["SetRowBuilder", "SetRows", "warm_up_rows"]
