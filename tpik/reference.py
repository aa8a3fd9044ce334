r"""The one control reference every method receives (docs/design.md §3): :math:`r = \dot\sigma_d + K\tilde\sigma`.

Every solver of the project — TPIK (:mod:`tpik.solver`), the HQP cascade and the mink peer
(:mod:`qp_baseline`) — takes the reference of a task from here, so no method gets a different
reference for the same task at the same state:

* an **equality task** (paper eq. 2): :math:`r = \dot\sigma_d + K\tilde\sigma`,
  :math:`\tilde\sigma = \sigma_d - \sigma` (the task's own error, e.g. a log map on SO(3));
* a **set-based task** at σ: the rates that bring it to its safety thresholds,

  .. math::
      \dot\sigma_l = K(\sigma_{s,l} - \sigma), \qquad \dot\sigma_u = K(\sigma_{s,u} - \sigma)

  TPIK inserts a candidate task with the rate of the threshold it crossed (eq. 7), HQP bounds
  :math:`\dot\sigma_l \le J\dot q \le \dot\sigma_u`, mink turns the same numbers into limits.

The gain is :math:`K = \min(\text{gain}, 1/dt)` with the **gain cap** (``gain_cap``, on by
default for every method): one explicit-Euler step :math:`\sigma + r\,dt` then never
overshoots a target or a safety threshold. The paper has no cap (``tpik-paper`` turns it off);
any method can switch it off with its ``gain_cap`` setting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from tpik.tasks.task import SetTask, Task, TaskState


def effective_gain(gain: float, dt: float, gain_cap: bool = True) -> float:
    """K used in the reference: ``gain``, capped at ``1/dt`` [1/s] when ``gain_cap``."""
    if gain_cap:
        k_max = 1.0 / dt
        return gain if gain < k_max else k_max
    return gain


def rate_bounds(
    sigma: float,
    safety_lower: float,
    safety_upper: float,
    gain: float,
    dt: float,
    gain_cap: bool = True,
    feedforward: float = 0.0,
) -> tuple[float, float]:
    r"""Reference rates of a set-based task: :math:`(K(\sigma_{s,l} - \sigma) + f, K(\sigma_{s,u} - \sigma) + f)`.

    ``feedforward`` f is the rate the arm must add to cancel what moves σ besides the arm (a
    predicted approach of the person: :attr:`tpik.tasks.SetTask.rate_feedforward`); 0 for a task
    only the arm moves. An infinite threshold gives an infinite rate (no bound on that side); a
    non-finite σ (e.g. no obstacle in range) gives (−inf, +inf).

    Returns:
        (lower, upper) rate [task unit/s].
    """
    if not math.isfinite(sigma):
        return (-math.inf, math.inf)
    k = effective_gain(gain, dt, gain_cap)
    return (k * (safety_lower - sigma) + feedforward, k * (safety_upper - sigma) + feedforward)


@dataclass(frozen=True)
class ControlReference:
    r"""The reference of every task for one method (docs/design.md §3, "One control reference").

    Attributes:
        gain_cap: Cap every gain at ``1/dt`` (default). The same default for every method.
    """

    gain_cap: bool = True

    def gain(self, task: Task, dt: float) -> float:
        """K of ``task`` at control period ``dt`` [1/s]."""
        return effective_gain(task.gain, dt, self.gain_cap)

    def equality(self, task: Task, state: TaskState, dt: float) -> np.ndarray:
        r""":math:`r = \dot\sigma_d + K\tilde\sigma` of an equality task (paper eq. 2). Shape (m,)."""
        return self.equality_rate(task, state.error, state.feedforward, dt)

    def equality_rate(self, task: Task, error: np.ndarray, feedforward: np.ndarray, dt: float) -> np.ndarray:
        r""":meth:`equality` from the task's error :math:`\tilde\sigma` and feedforward :math:`\dot\sigma_d` (m,)."""
        return feedforward + self.gain(task, dt) * error

    def set_rates(self, task: SetTask, sigma: float, dt: float) -> tuple[float, float]:
        r"""Reference rates :math:`(\dot\sigma_l, \dot\sigma_u)` of a set-based task at σ (see :func:`rate_bounds`)."""
        th = task.thresholds
        return rate_bounds(sigma, th.safety_lower, th.safety_upper, task.gain, dt, self.gain_cap, task.rate_feedforward)


DEFAULT_REFERENCE = ControlReference()
"""The reference of a method with default settings."""

STATUS_RATE_TOLERANCE = 1e-3
"""Slack [task unit/s] of :func:`unmet_set_rates` (1 mm/s: 10 µm over a 10 ms step)."""


def unmet_set_rates(
    tasks: tuple[SetTask, ...] | list[SetTask],
    sigmas: list[float],
    kin: object,
    qdot: np.ndarray,
    dt: float,
    reference: ControlReference = DEFAULT_REFERENCE,
    tolerance: float = STATUS_RATE_TOLERANCE,
) -> list[str]:
    r"""Set-based tasks, at or past an activation threshold, whose reference rate ``qdot`` misses.

    The one definition of "a constraint not met" of the step status (docs/design.md §3), applied to every
    method's command by the closed loop: a task past its upper activation threshold needs
    :math:`J\dot q \le \dot\sigma_u` and one past its lower threshold
    :math:`J\dot q \ge \dot\sigma_l` (HQP's rows): inside its safety set it may approach the
    threshold no faster than its reference, past it it must come back at least at its
    reference rate. Tasks between their activation thresholds are not checked (no method is
    asked to act on them).

    Args:
        tasks: The set-based tasks.
        sigmas: σ of each task at ``kin`` (as recorded).
        kin: Kinematics snapshot at the step's configuration.
        qdot: Command [rad/s]. Shape (n,).
        dt: Control period [s].
        reference: The method's reference (its gain cap).
        tolerance: Slack on the rate [task unit/s].

    Returns:
        Names of the tasks whose rate misses the bound.
    """
    rows = [
        task.compute_jacobian(kin) if past_activation(task, sigma) else None  # type: ignore[arg-type]
        for task, sigma in zip(tasks, sigmas, strict=True)
    ]
    return unmet_rates(tasks, sigmas, rows, qdot, dt, reference, tolerance)


def past_activation(task: SetTask, sigma: float) -> bool:
    """Whether a finite σ is at or past an activation threshold of ``task`` (:meth:`SetTask.activation_bounds`)."""
    if not math.isfinite(sigma):
        return False
    act_lo, act_hi = task.activation_bounds()
    return sigma >= act_hi or sigma <= act_lo


def unmet_rates(
    tasks: tuple[SetTask, ...] | list[SetTask],
    sigmas: list[float],
    jacobians: list[np.ndarray | None],
    qdot: np.ndarray,
    dt: float,
    reference: ControlReference = DEFAULT_REFERENCE,
    tolerance: float = STATUS_RATE_TOLERANCE,
) -> list[str]:
    """:func:`unmet_set_rates` with each task's Jacobian row (1, n) at the step's snapshot given.

    A row is read only for a task :func:`past_activation`; the others may be None.

    Raises:
        ValueError: A task past an activation threshold has no row.
    """
    unmet: list[str] = []
    for task, sigma, jacobian in zip(tasks, sigmas, jacobians, strict=True):
        if not math.isfinite(sigma):
            continue
        act_lo, act_hi = task.activation_bounds()
        upper = sigma >= act_hi
        lower = sigma <= act_lo
        if not (upper or lower):
            continue
        if jacobian is None:
            raise ValueError(f"task '{task.name}' is past an activation threshold but has no Jacobian row")
        rate = float(jacobian[0] @ qdot)
        lo, hi = reference.set_rates(task, sigma, dt)
        if (upper and rate > hi + tolerance) or (lower and rate < lo - tolerance):
            unmet.append(task.name)
    return unmet


__all__ = [
    "DEFAULT_REFERENCE",
    "STATUS_RATE_TOLERANCE",
    "ControlReference",
    "past_activation",
    "effective_gain",
    "rate_bounds",
    "unmet_rates",
    "unmet_set_rates",
]
