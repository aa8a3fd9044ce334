r"""Joint velocity limit :math:`|\dot q_i| \le v_{max,i}` [rad/s] (mink's ``VelocityLimit`` in velocity form)."""

from __future__ import annotations

import numpy as np

from robots import Robot
from tpik.exceptions import InvalidSettings
from tpik.limits.limit import Box, Limit


class VelocityLimit(Limit):
    r"""The box :math:`-v_{max} \le \dot q \le v_{max}`, independent of the state.

    Args:
        v_max: Finite, positive limit per joint [rad/s]. Shape (n,).

    Raises:
        InvalidSettings: A limit is not finite or not > 0.
    """

    def __init__(self, v_max: np.ndarray) -> None:
        v = np.array(v_max, dtype=float)
        if v.ndim != 1 or not np.all(np.isfinite(v)) or np.any(v <= 0.0):
            raise InvalidSettings(f"joint velocity limits must be finite and > 0, got {v}")
        v.flags.writeable = False
        self.v_max = v

    @classmethod
    def from_robot(cls, robot: Robot) -> VelocityLimit:
        """The robot's own limits ``robot.v_max``."""
        try:
            return cls(robot.v_max)
        except InvalidSettings as exc:
            raise InvalidSettings(f"robot '{robot.name}': {exc}") from exc

    def compute_box(self, q: np.ndarray, dt: float) -> Box:
        """The constant box (q and dt are not used)."""
        return Box(-self.v_max, self.v_max.copy())

    def __repr__(self) -> str:
        return f"VelocityLimit(v_max={self.v_max.tolist()})"
