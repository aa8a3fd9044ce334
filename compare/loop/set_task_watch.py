"""σ of every set-based task at the loop's own snapshot, and the reference-rate check of the step status.

Before the solve, at its own kinematics snapshot of the step's ``q``, the loop evaluates σ of
every set task (each task's :meth:`~tpik.tasks.SetTask.compute_value`: the numbers recorded)
and the Jacobian rows of the tasks at or past an activation threshold; after the solve,
:meth:`SetTaskWatch.unmet` checks the command against their reference rates
(:func:`tpik.reference.unmet_rates`, docs/design.md §3). The method's snapshot is of the same
``q``, so these are the numbers the method's snapshot gives, each computed once per step.

Joint limits, walls and obstacle distances are evaluated together in one compiled call
(:func:`~compare.loop._sigma_kernel.set_task_sigmas`), with the arithmetic of their own
``compute_value`` bit for bit; any other set task (a subclass included) is asked itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from compare.loop._sigma_kernel import (
    KIND_GIVEN,
    KIND_JOINT,
    KIND_OBSTACLE,
    KIND_WALL,
    SPEC_COLUMNS,
    set_task_sigmas,
)
from compare.loop.numpy_dot import NUMPY_DOT_FUSED
from robots import Kinematics
from tpik.reference import ControlReference, unmet_rates
from tpik.tasks import JointLimitTask, ObstacleDistanceTask, SetTask, VirtualWallTask


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
        self._predicting = predicting
        self.sigmas: list[float] = [math.nan] * len(self.tasks)
        self._near: list[SetTask] = []
        self._near_sigmas: list[float] = []
        self._rows: list[np.ndarray | None] = []
        self._spec = np.zeros((len(self.tasks), SPEC_COLUMNS))
        self._sigma = np.full(len(self.tasks), math.nan)
        self._near_index = np.zeros(len(self.tasks), dtype=np.int64)
        frames: dict[str, int] = {}
        self._given: list[tuple[int, SetTask, bool]] = []  # asked themselves (and their moved bands)
        self._obstacles: list[tuple[int, ObstacleDistanceTask]] = []  # O, g (and bands) read when O changes
        for k, task in enumerate(self.tasks):
            th = task.thresholds
            self._spec[k, 6:8] = th.activation_lower, th.activation_upper
            kind = _kind(task) if NUMPY_DOT_FUSED is not None else KIND_GIVEN
            self._spec[k, 0] = kind
            if kind == KIND_JOINT:
                self._spec[k, 1] = task.joint - 1
            elif kind == KIND_WALL:
                self._spec[k, 1] = frames.setdefault(task.frame, len(frames))
                self._spec[k, 2:5] = task.normal
                self._spec[k, 5] = task.offset
            elif kind == KIND_OBSTACLE:
                self._spec[k, 1] = frames.setdefault(task.frame, len(frames))
                self._spec[k, 2] = math.nan
                self._obstacles.append((k, task))
            else:
                self._given.append((k, task, predicting and isinstance(task, ObstacleDistanceTask)))
        self._frames = tuple(frames)
        self._points = np.zeros((len(self._frames), 3))
        self._seen: list[np.ndarray | None] = [None] * len(self._obstacles)

    def measure(self, kin: Kinematics) -> list[float]:
        """σ of every task at ``kin``, and the Jacobian rows of those at or past an activation threshold."""
        spec, sigma = self._spec, self._sigma
        for k, task, fed in self._given:
            sigma[k] = task.compute_value(kin)
            if fed:
                spec[k, 6:8] = task.activation_bounds()
        seen = self._seen
        for m, (k, task) in enumerate(self._obstacles):
            point = task.obstacle_point
            if point is not seen[m]:  # a new O (set_obstacle copies): its g and bands with it
                seen[m] = point
                spec[k, 2:5] = math.nan if point is None else point
                spec[k, 5] = task.margin_growth
                if self._predicting:
                    spec[k, 6:8] = task.activation_bounds()
        if self._frames:
            kin.frame_positions(self._frames, self._points)
        count = set_task_sigmas(kin.q, self._points, spec, sigma, self._near_index, bool(NUMPY_DOT_FUSED))
        sigmas = sigma.tolist()
        if count:
            near = self._near_index[:count].tolist()
            self._near = [self.tasks[k] for k in near]
            self._near_sigmas = [sigmas[k] for k in near]
            self._rows = [task.compute_jacobian(kin) for task in self._near]
        elif self._near:
            self._near, self._near_sigmas, self._rows = [], [], []
        self.sigmas = sigmas
        return sigmas

    def unmet(self, qdot: np.ndarray, dt: float, reference: ControlReference) -> bool:
        """Whether ``qdot`` [rad/s] misses the reference rate of a task at or past an activation threshold."""
        if not self._near:
            return False
        return bool(unmet_rates(self._near, self._near_sigmas, self._rows, qdot, dt, reference))


def _kind(task: SetTask) -> int:
    """The compiled σ of a built-in task (its exact class: a subclass may compute its own), else given."""
    cls = type(task)
    if cls is JointLimitTask:
        return KIND_JOINT
    if cls is VirtualWallTask:
        return KIND_WALL
    if cls is ObstacleDistanceTask:
        return KIND_OBSTACLE
    return KIND_GIVEN
