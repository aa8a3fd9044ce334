"""Safety layer between the control loop and the arm (no ROS import here).

Three independent guards, applied to every command that leaves the process:

* :class:`CommandLimiter` — velocity clamp (a fraction of the model's limits) and acceleration
  clamp (on the change from the last command sent). Both scale the whole vector so the
  direction of motion is kept. An all-zero command always passes at once: stopping is never
  rate-limited.
* :class:`Watchdog` — stale joint state (no message for ``state_timeout_s``), stale depth (no
  frame for ``depth_timeout_s``) or a stalled controller (no new command for
  ``command_timeout_s``) → the command is replaced by zero. Every change of state is logged
  once with its reason.
* :func:`start_problems` — before the first command: every set-based task must be inside its
  safety thresholds at the first joint state.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from robots import Kinematics
from tpik.hierarchy import Hierarchy

log = logging.getLogger(__name__)

NO_COMMAND_YET = "no command from the control loop yet"
"""Watchdog reason before the loop's first command: zero is expected, not a trip."""


class CommandLimiter:
    """Velocity and acceleration clamp of joint velocity commands.

    Args:
        v_max: Joint velocity limits [rad/s]. Shape (n,).
        a_max: Limit on the change of the command [rad/s²].
        dt: Command period [s].
    """

    def __init__(self, v_max: np.ndarray, a_max: float, dt: float) -> None:
        self.v_max = np.asarray(v_max, dtype=float).copy()
        if np.any(~np.isfinite(self.v_max)) or np.any(self.v_max <= 0.0):
            raise ValueError(f"velocity limits must be finite and > 0, got {self.v_max}")
        if not (math.isfinite(a_max) and a_max > 0.0 and dt > 0.0):
            raise ValueError(f"a_max and dt must be > 0, got {a_max}, {dt}")
        self.dv_max = float(a_max) * float(dt)

    def apply(self, qdot: np.ndarray, previous: np.ndarray) -> tuple[np.ndarray, str | None]:
        """Clamp ``qdot`` [rad/s] given the ``previous`` command sent [rad/s].

        Returns:
            The command to send and, when it was changed, why (for the log).
        """
        qdot = np.asarray(qdot, dtype=float)
        if qdot.shape != self.v_max.shape:
            return np.zeros_like(self.v_max), f"command has shape {qdot.shape}, expected {self.v_max.shape}"
        if not np.all(np.isfinite(qdot)):
            return np.zeros_like(self.v_max), "command is not finite"
        if not np.any(qdot):
            return qdot.copy(), None
        reason = None
        ratio = float(np.max(np.abs(qdot) / self.v_max))
        if ratio > 1.0:
            qdot = qdot / ratio
            reason = f"velocity clamped (x{1.0 / ratio:.3f})"
        delta = qdot - previous
        step = float(np.max(np.abs(delta)))
        if step > self.dv_max:
            qdot = previous + delta * (self.dv_max / step)
            reason = f"acceleration clamped ({step / self.dv_max:.2f}x the limit)"
        return qdot, reason


@dataclass
class WatchdogEvent:
    """One change of the watchdog's verdict.

    Attributes:
        t_s: Time on the controller's clock [s].
        reason: Why commands are zeroed, or None when the watchdog recovered.
        message: Log line.
        state_t_s: Arrival time of the latest joint state the verdict was judged on [s], on the
            same clock as ``t_s`` (None: none yet).
        next_state_t_s: Arrival time of the first joint state after that one [s], same clock;
            filled by the bridge when that state arrives (None: none arrived since).
    """

    t_s: float
    reason: str | None
    message: str
    state_t_s: float | None = None
    next_state_t_s: float | None = None


@dataclass
class Watchdog:
    """Zero velocity when joint state, depth or the controller's own commands are stale.

    Attributes:
        state_timeout_s: Oldest acceptable joint state [s] (3 state periods by default).
        depth_timeout_s: Oldest acceptable depth frame [s]; None = depth not used.
        command_timeout_s: Oldest acceptable command from the loop [s] (a stalled loop).
        events: Every change of verdict, in order.
        quiet: Log changes at debug level only (before the control loop starts, zero is expected).
    """

    state_timeout_s: float
    depth_timeout_s: float | None
    command_timeout_s: float
    events: list[WatchdogEvent] = field(default_factory=list)
    quiet: bool = False
    _reason: str | None = field(default=None, init=False, repr=False)

    def check(self, now: float, state_t: float | None, depth_t: float | None, command_t: float | None) -> str | None:
        """Why the command must be zero at ``now`` [s], or None; logs every change.

        Args:
            now: Current time [s].
            state_t: Arrival time of the latest joint state [s] (None: none yet).
            depth_t: Arrival time of the latest depth frame [s] (None: none yet).
            command_t: Time of the latest command from the loop [s] (None: none yet).
        """
        reason = self.reason_at(now, state_t, depth_t, command_t)
        if (reason is None) != (self._reason is None) or (
            reason is not None and self._reason is not None and _kind(reason) != _kind(self._reason)
        ):
            if reason is None:
                message = f"watchdog: recovered at t={now:.3f} s, commands resume"
            else:
                message = f"watchdog: zero velocity at t={now:.3f} s: {reason}"
            level = logging.INFO if reason is None else logging.WARNING
            log.log(logging.DEBUG if self.quiet else level, message)
            self.events.append(WatchdogEvent(now, reason, message, state_t))
        self._reason = reason
        return reason

    def reason_at(
        self, now: float, state_t: float | None, depth_t: float | None, command_t: float | None
    ) -> str | None:
        """Like :meth:`check` without logging or recording anything."""
        reason = None
        if state_t is None:
            reason = "no joint state received"
        elif now - state_t > self.state_timeout_s:
            reason = (
                f"joint state stale: last one {1e3 * (now - state_t):.0f} ms ago "
                f"(limit {1e3 * self.state_timeout_s:.0f} ms)"
            )
        elif self.depth_timeout_s is not None and depth_t is None:
            reason = "no depth frame received"
        elif self.depth_timeout_s is not None and depth_t is not None and now - depth_t > self.depth_timeout_s:
            reason = (
                f"depth stale: last frame {1e3 * (now - depth_t):.0f} ms ago "
                f"(limit {1e3 * self.depth_timeout_s:.0f} ms)"
            )
        elif command_t is None:
            reason = NO_COMMAND_YET
        elif now - command_t > self.command_timeout_s:
            reason = (
                f"control loop stalled: last command {1e3 * (now - command_t):.0f} ms ago "
                f"(limit {1e3 * self.command_timeout_s:.0f} ms)"
            )
        return reason


def _kind(reason: str) -> str:
    """The cause part of a reason (before ':'), so a growing age does not log a new event."""
    return reason.split(":", 1)[0]


def start_problems(hierarchy: Hierarchy, kin: Kinematics) -> list[str]:
    """Set-based tasks outside their safety thresholds at ``kin.q`` (empty: safe to start).

    Obstacle tasks are checked with whatever obstacle they hold (set it from a first sensing
    update before calling); a task whose σ is not finite (nothing in range) is fine.
    """
    problems = []
    for task in hierarchy.set_tasks:
        sigma = float(task.compute_value_and_jacobian(kin)[0])
        if not math.isfinite(sigma):
            continue
        th = task.thresholds
        if sigma < th.safety_lower or sigma > th.safety_upper:
            problems.append(
                f"task '{task.name}': σ = {sigma:.4g} is outside its safety thresholds "
                f"[{th.safety_lower:.4g}, {th.safety_upper:.4g}]"
            )
    return problems
