"""σ of every set-based task at the loop's own snapshot, and the reference-rate check of the step status.

Before the solve, at its own kinematics snapshot of the step's ``q``, the loop evaluates σ of
every set task (each task's own :meth:`~tpik.tasks.SetTask.compute_value`: the numbers recorded)
and the Jacobian rows of the tasks at or past an activation threshold; after the solve,
:meth:`SetTaskWatch.unmet` checks the command against their reference rates
(:func:`tpik.reference.unmet_rates`, docs/design.md §3). The method's snapshot is of the same
``q``, so these are the numbers the method's snapshot gives, each computed once per step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from robots import Kinematics
from tpik.reference import ControlReference, unmet_rates
from tpik.tasks import ObstacleDistanceTask, SetTask


class SetTaskWatch:
    """σ and the status check of a hierarchy's set tasks (module docstring).

    Args:
        set_tasks: The hierarchy's set-based tasks, in its order.
        predicting: The obstacle tasks' activation thresholds move with their feed-forward
            (:meth:`~tpik.tasks.SetTask.activation_bounds`, a ``[prediction]``); the other set
            tasks get none, so theirs are read once.

    Attributes:
        tasks: The set tasks.
        sigmas: σ of each task at the last :meth:`measure`.
    """

    def __init__(self, set_tasks: Sequence[SetTask], predicting: bool = False) -> None:
        self.tasks = tuple(set_tasks)
        self._values = [t.compute_value for t in self.tasks]
        # Activation thresholds (σ_{a,l}, σ_{a,u}) of each task, read once (Thresholds are frozen).
        self._bands = [(t.thresholds.activation_lower, t.thresholds.activation_upper) for t in self.tasks]
        self._fed = [k for k, t in enumerate(self.tasks) if isinstance(t, ObstacleDistanceTask)] if predicting else []
        self.sigmas: list[float] = [math.nan] * len(self.tasks)
        self._near: list[SetTask] = []
        self._near_sigmas: list[float] = []
        self._rows: list[np.ndarray | None] = []

    def measure(self, kin: Kinematics) -> list[float]:
        """σ of every task at ``kin``, and the Jacobian rows of those at or past an activation threshold."""
        sigmas = [value(kin) for value in self._values]
        bands = self._bands
        if self._fed:
            bands = list(bands)
            for k in self._fed:
                bands[k] = self.tasks[k].activation_bounds()
        pairs = enumerate(zip(sigmas, bands, strict=True))
        near = [k for k, (s, (lo, hi)) in pairs if (s >= hi or s <= lo) and math.isfinite(s)]
        self._near = [self.tasks[k] for k in near]
        self._near_sigmas = [sigmas[k] for k in near]
        self._rows = [task.compute_jacobian(kin) for task in self._near]
        self.sigmas = sigmas
        return sigmas

    def unmet(self, qdot: np.ndarray, dt: float, reference: ControlReference) -> bool:
        """Whether ``qdot`` [rad/s] misses the reference rate of a task at or past an activation threshold."""
        if not self._near:
            return False
        return bool(unmet_rates(self._near, self._near_sigmas, self._rows, qdot, dt, reference))
