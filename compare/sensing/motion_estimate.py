r"""The motion of each control point's closest obstacle point, estimated from the sensing stream alone.

One constant-velocity Kalman filter per control point on its closest obstacle point O (base
frame), updated at every accepted sensing update (30 Hz, depth or geometric alike). State
:math:`x = (p, v) \in \mathbb{R}^6`, measurement :math:`z = O`; over an interval Δt

.. math::
    F = \begin{pmatrix} I & \Delta t\, I \\ 0 & I \end{pmatrix},\qquad
    Q = a^2 \begin{pmatrix} \tfrac{\Delta t^4}{4} I & \tfrac{\Delta t^3}{2} I \\
                             \tfrac{\Delta t^3}{2} I & \Delta t^2 I \end{pmatrix},\qquad
    R = s^2 I

(white-noise acceleration of spectral size a [m/s²], measurement noise s [m], larger for a point
assumed from occluded space when nothing of the surface hiding it is known; a reading assumed
from hidden space is tracked at its nearest measured surface point,
:mod:`compare.sensing.prediction`). The closest point is not one material point: it slides over
the person and jumps when another body part becomes the closest. An innovation beyond the χ²(3)
gate (0.999) restarts the track at the new point with its velocity kept and its covariance reset;
no reading in range ends the track. The filter sees only what the sensing gate accepted: never
the scenario's keyframes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_GATE_CHI2_3 = 16.27  # χ²(3) at 0.999
_I3 = np.eye(3)


@dataclass(frozen=True)
class MotionFilterSettings:
    """Noise model of :class:`PointMotionFilter`.

    Attributes:
        acceleration_mps2: a, the white-noise acceleration of the tracked point [m/s²].
        measurement_m: s, the noise of a measured closest point [m].
        occluded_m: s for a point assumed from occluded space [m].
        initial_speed_mps: Standard deviation of the velocity of a new track, per axis [m/s].
    """

    acceleration_mps2: float = 8.0
    measurement_m: float = 0.01
    occluded_m: float = 0.05
    initial_speed_mps: float = 1.0

    def __post_init__(self) -> None:
        for name in ("acceleration_mps2", "measurement_m", "occluded_m", "initial_speed_mps"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")


class PointMotionFilter:
    """The constant-velocity Kalman filter of one control point (module docstring)."""

    def __init__(self, settings: MotionFilterSettings) -> None:
        self._settings = settings
        self._x = np.zeros(6)
        self._p = np.eye(6)
        self._t = math.nan
        self.restarts = 0

    @property
    def tracking(self) -> bool:
        """A track exists (the last update had a reading in range)."""
        return math.isfinite(self._t)

    @property
    def velocity(self) -> np.ndarray:
        """Estimated velocity of the closest point [m/s] (zero without a track). Shape (3,)."""
        return self._x[3:].copy() if self.tracking else np.zeros(3)

    def reset(self) -> None:
        """End the track (nothing in range)."""
        self._t = math.nan

    def update(self, t: float, point: np.ndarray, occluded: bool = False) -> np.ndarray:
        """Fuse the closest point ``point`` [m] seen at ``t`` [s]; returns the estimated velocity [m/s]."""
        s = self._settings
        r = (s.occluded_m if occluded else s.measurement_m) ** 2
        if not self.tracking:
            self._start(t, point, np.zeros(3))
            return self.velocity
        dt = t - self._t
        if dt <= 0.0:  # the same frame again: nothing new
            return self.velocity
        x, p = self._x, self._p
        x[:3] += dt * x[3:]
        f = np.eye(6)
        f[:3, 3:] = dt * _I3
        a2 = s.acceleration_mps2**2
        q = np.zeros((6, 6))
        q[:3, :3] = a2 * dt**4 / 4.0 * _I3
        q[:3, 3:] = q[3:, :3] = a2 * dt**3 / 2.0 * _I3
        q[3:, 3:] = a2 * dt**2 * _I3
        p = f @ p @ f.T + q
        innovation = np.asarray(point, dtype=float) - x[:3]
        s_mat = p[:3, :3] + r * _I3
        s_inv = np.linalg.inv(s_mat)
        if float(innovation @ s_inv @ innovation) > _GATE_CHI2_3:
            self.restarts += 1
            self._start(t, point, x[3:].copy())  # another part of the person is now the closest
            return self.velocity
        gain = p[:, :3] @ s_inv
        self._x = x + gain @ innovation
        self._p = (np.eye(6) - gain @ np.hstack([_I3, np.zeros((3, 3))])) @ p
        self._t = t
        return self.velocity

    def _start(self, t: float, point: np.ndarray, velocity: np.ndarray) -> None:
        s = self._settings
        self._x = np.concatenate([np.asarray(point, dtype=float), velocity])
        self._p = np.diag([s.measurement_m**2] * 3 + [s.initial_speed_mps**2] * 3)
        self._t = t
