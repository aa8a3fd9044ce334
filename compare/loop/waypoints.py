"""End-effector waypoint schedule: go to each waypoint, dwell, move on (paper case 1)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


class WaypointSchedule:
    """Targets in the base frame, switched when reached and held for ``dwell_s``.

    Args:
        positions: Waypoints [m], shape (k, 3). Empty: hold ``start`` (case 2).
        start: EE position at t = 0 [m], used when ``positions`` is empty.
        tolerance_m: Distance under which a waypoint is reached [m].
        dwell_s: Time to stay at a reached waypoint [s].
        cycle: Restart from the first waypoint after the last.
    """

    def __init__(
        self,
        positions: Sequence[Sequence[float]],
        start: np.ndarray,
        tolerance_m: float = 0.02,
        dwell_s: float = 2.0,
        cycle: bool = True,
    ) -> None:
        pts = np.asarray(positions, dtype=float).reshape(-1, 3)
        self.positions = pts if len(pts) else np.asarray(start, dtype=float).reshape(1, 3).copy()
        self.tolerance_m = tolerance_m
        self.dwell_s = dwell_s
        self.cycle = cycle
        self.index = 0
        self._reached_at: float | None = None
        self.reached_count = 0

    @property
    def target(self) -> np.ndarray:
        """Current target [m]. Shape (3,)."""
        return self.positions[self.index]

    def update(self, t: float, ee_position: np.ndarray) -> np.ndarray:
        """Advance the schedule at time ``t`` [s] given the EE position [m]; return the target."""
        if len(self.positions) == 1:
            return self.target
        if self._reached_at is None:
            gap = ee_position - self.target
            if math.sqrt(float(gap.dot(gap))) < self.tolerance_m:  # np.linalg.norm's own arithmetic, cheaper
                self._reached_at = t
                self.reached_count += 1
        if self._reached_at is not None and t - self._reached_at >= self.dwell_s:
            last = self.index == len(self.positions) - 1
            if not last or self.cycle:
                self.index = 0 if last else self.index + 1
                self._reached_at = None
        return self.target
