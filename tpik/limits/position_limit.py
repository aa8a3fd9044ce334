r"""Joint position limit over one step: :math:`q_{min} \le q + \dot q\,dt \le q_{max}` (mink's ``ConfigurationLimit``).

In velocity form, with gain :math:`\gamma \in (0, 1]` (the fraction of the remaining range one step
may use; 1 in HQP, mink's ``configuration_limit_gain`` in the mink peer):

.. math::
    \gamma\,\frac{q_{min} - q}{dt} \le \dot q \le \gamma\,\frac{q_{max} - q}{dt}.

Joints without limits (continuous, :math:`\pm\infty`) get no bound.
"""

from __future__ import annotations

import numpy as np

from robots import Robot
from tpik.exceptions import InvalidSettings
from tpik.limits.limit import Box, Limit


class PositionLimit(Limit):
    """Position box of the joints, reached in no less than one step (module docstring).

    Args:
        q_lower: Lower limit per joint [rad] (−inf: none). Shape (n,).
        q_upper: Upper limit per joint [rad] (+inf: none). Shape (n,).
        gain: γ in (0, 1].

    Raises:
        InvalidSettings: Shapes differ, a lower limit exceeds its upper one, or γ is outside (0, 1].
    """

    def __init__(self, q_lower: np.ndarray, q_upper: np.ndarray, gain: float = 1.0) -> None:
        lo, hi = np.array(q_lower, dtype=float), np.array(q_upper, dtype=float)
        if lo.shape != hi.shape or lo.ndim != 1 or np.any(lo > hi) or np.isnan(lo).any() or np.isnan(hi).any():
            raise InvalidSettings(f"joint position limits must be ordered pairs of one shape, got {lo} and {hi}")
        if not 0.0 < gain <= 1.0:
            raise InvalidSettings(f"position limit gain must be in (0, 1], got {gain}")
        lo.flags.writeable = hi.flags.writeable = False
        self.q_lower, self.q_upper, self.gain = lo, hi, float(gain)

    @classmethod
    def from_robot(cls, robot: Robot, gain: float = 1.0) -> PositionLimit:
        """The robot's limits ``robot.q_lower``, ``robot.q_upper``."""
        return cls(robot.q_lower, robot.q_upper, gain)

    def compute_box(self, q: np.ndarray, dt: float) -> Box:
        """The remaining range over one step, times γ (module docstring)."""
        inv_dt = 1.0 / dt
        lower = (self.q_lower - q) * inv_dt  # −inf on continuous joints
        upper = (self.q_upper - q) * inv_dt
        if self.gain != 1.0:
            lower *= self.gain
            upper *= self.gain
        return Box(lower, upper)

    def __repr__(self) -> str:
        return f"PositionLimit(gain={self.gain})"
