r"""Joint acceleration limit :math:`|\dot q - \dot q_{prev}| \le a_{max}\,dt`.

:math:`\dot q_{prev}` is the velocity the solver commanded at its previous step (zero before the
first), which every solver reports through :meth:`AccelerationLimit.observe`. Put it after the
velocity limit: the composition (:func:`~tpik.limits.limit.compose_box`) then clips it into
:math:`[-v_{max}, v_{max}]`, and the position box after it.
"""

from __future__ import annotations

import numpy as np

from tpik.exceptions import InvalidSettings
from tpik.limits.limit import Box, Limit


class AccelerationLimit(Limit):
    r"""The box :math:`\dot q_{prev} - a_{max} dt \le \dot q \le \dot q_{prev} + a_{max} dt`.

    Args:
        a_max: Finite, positive limit per joint [rad/s²]. Shape (n,), or a scalar for all ``n``.
        n: Number of joints (with a scalar ``a_max``).

    Raises:
        InvalidSettings: A limit is not finite or not > 0.
    """

    def __init__(self, a_max: np.ndarray | float, n: int | None = None) -> None:
        a = np.array(a_max, dtype=float)
        if a.ndim == 0:
            if n is None:
                raise InvalidSettings("a scalar acceleration limit needs the number of joints n")
            a = np.full(int(n), float(a))
        if a.ndim != 1 or not np.all(np.isfinite(a)) or np.any(a <= 0.0):
            raise InvalidSettings(f"joint acceleration limits must be finite and > 0, got {a}")
        a.flags.writeable = False
        self.a_max = a
        self.previous = np.zeros(a.shape[0])
        """The last commanded velocity [rad/s]."""

    def compute_box(self, q: np.ndarray, dt: float) -> Box:
        """The box around the last commanded velocity (q is not used)."""
        reach = self.a_max * dt
        return Box(self.previous - reach, self.previous + reach)

    def observe(self, qdot: np.ndarray) -> None:
        """Remember the commanded velocity: the next step's box is centred on it."""
        self.previous = np.array(qdot, dtype=float)

    def __repr__(self) -> str:
        return f"AccelerationLimit(a_max={self.a_max.tolist()})"
