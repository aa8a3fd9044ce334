r"""The command guard and fallback policy of the closed loop (docs/design.md §3).

A step's command is sent only when the solve succeeded and the velocity is finite and within
the limits, :math:`|\dot q_i| \le \dot q_{\max,i}(1 + 10^{-6}) + 10^{-9}` (:func:`guard`).
Otherwise the step is FAILED and the configured fallback is sent instead:

* ``zero``: :math:`\dot q = 0`;
* ``hold_last``: the last safe command :math:`\dot q_s` sent at :math:`t_s`, decaying,
  :math:`\dot q = \dot q_s\, e^{-(t - t_s)/\tau}` (``fallback_decay_s`` = τ).

Only the start and the end of a fallback episode are logged, not every step of it.
"""

from __future__ import annotations

import logging
import math
import operator

import numpy as np

from compare.loop.settings import LoopSettings
from tpik.step_result import SolveStatus

log = logging.getLogger(__name__)

GUARD_RELATIVE = 1e-6
"""Relative allowance of :func:`guard` on the velocity limits."""
GUARD_ABSOLUTE = 1e-9
"""Absolute allowance of :func:`guard` on the velocity limits [rad/s]."""


def guard_limits(v_max: np.ndarray) -> np.ndarray:
    """The largest |q̇| [rad/s] :func:`guard` lets through, per joint."""
    return v_max * (1.0 + GUARD_RELATIVE) + GUARD_ABSOLUTE


def guard(qdot: np.ndarray, v_max: np.ndarray, limits: np.ndarray | None = None) -> str | None:
    """Why a command must not be sent, or None when it is finite and within the limits.

    Args:
        qdot: The command [rad/s].
        v_max: Velocity limits [rad/s].
        limits: :func:`guard_limits` of ``v_max``, when precomputed.
    """
    if qdot.shape != v_max.shape:
        return f"command has shape {qdot.shape}, expected {v_max.shape}"
    lim = guard_limits(v_max) if limits is None else limits
    if (np.abs(qdot) <= lim).all():  # the common case in one test (False for NaN)
        return None
    if not np.isfinite(qdot).all():
        return "command is not finite"
    return f"command exceeds the velocity limits by {float(np.max(np.abs(qdot) - v_max)):.3g} rad/s"


class FallbackPolicy:
    """What the loop sends for a solve's answer: the command itself, or the fallback (module docstring).

    Args:
        settings: The loop settings (``fallback``, ``fallback_decay_s``).
        solver_name: Named in the event log.
        v_max: Velocity limits [rad/s].
        events: The run's event log (fallback / recovered lines are appended).
    """

    def __init__(self, settings: LoopSettings, solver_name: str, v_max: np.ndarray, events: list[str]) -> None:
        self._mode = settings.fallback
        self._decay_s = settings.fallback_decay_s
        self._name = solver_name
        self._v_max = v_max
        self._limits = guard_limits(v_max)
        self._limit_list = self._limits.tolist()
        self._events = events
        self._last_safe = np.zeros(v_max.shape[0])
        self._last_safe_t = -math.inf
        self._since: float | None = None  # start of the current fallback episode [s]

    def decide(
        self, t: float, qdot: np.ndarray, status: SolveStatus, message: str
    ) -> tuple[np.ndarray, str | None, SolveStatus]:
        """The command to send at ``t`` [s] for the solve's answer.

        Returns:
            (command [rad/s], why the fallback was used or None, the step's status: FAILED
            whenever the fallback is used).
        """
        if status is SolveStatus.FAILED:
            reason: str | None = message
        elif self._within_limits(qdot):
            reason = None
        else:
            reason = guard(np.asarray(qdot, dtype=float), self._v_max, self._limits)
        if reason is not None:
            return self._fallback(t, reason), reason, SolveStatus.FAILED  # no usable command (docs/design.md §3)
        command = np.array(qdot, dtype=float)
        self._last_safe, self._last_safe_t = command, t
        if self._since is not None:
            self._log(f"t={t:.3f} s: {self._name}: recovered after {t - self._since:.2f} s of fallback")
            self._since = None
        return command, None, status

    def _within_limits(self, qdot: np.ndarray) -> bool:
        """:func:`guard`'s common case, finite and within the limits, on Python floats (False: ask :func:`guard`)."""
        if not (isinstance(qdot, np.ndarray) and qdot.dtype == np.float64 and qdot.shape == self._v_max.shape):
            return False
        return all(map(operator.le, map(abs, qdot.tolist()), self._limit_list))  # False for NaN, as guard's

    def _fallback(self, t: float, reason: str) -> np.ndarray:
        if self._mode == "hold_last":
            command = self._last_safe * math.exp(-(t - self._last_safe_t) / self._decay_s)
        else:
            command = np.zeros(self._v_max.shape[0])
        if self._since is None:  # the start of a fallback episode, not every step of it
            self._since = t
            self._log(f"t={t:.3f} s: {self._name}: fallback ({self._mode}): {reason}")
        return command

    def _log(self, line: str) -> None:
        self._events.append(line)
        log.warning(line)
