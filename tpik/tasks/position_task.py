"""Frame position task (equality, m = 3)."""

from __future__ import annotations

import numpy as np

from robots import Kinematics
from tpik.exceptions import TargetNotSet
from tpik.tasks._targets import as_finite_vector
from tpik.tasks.registry import TaskKey, frame_task_builder, frame_task_keys
from tpik.tasks.task import Task, TaskState


class PositionTask(Task):
    r"""Bring a frame origin to a target position in the base frame.

    .. math:: \sigma = p(q) \in \mathbb{R}^3,\quad J = J_{pos}(q),\quad \tilde\sigma = p_d - p

    Args:
        name: Task name.
        frame: Robot frame whose origin is controlled (e.g. ``"end_effector"``).
        gain: K [1/s].
        target: Optional initial target p_d [m], shape (3,).
        target_velocity: Optional feedforward ṗ_d [m/s], shape (3,).
    """

    def __init__(
        self,
        name: str,
        frame: str = "end_effector",
        gain: float = 1.0,
        target: np.ndarray | None = None,
        target_velocity: np.ndarray | None = None,
    ) -> None:
        super().__init__(name, 3, gain)
        self.frame = frame
        self._target: np.ndarray | None = None
        self._velocity = np.zeros(3)
        if target is not None:
            self.set_target(target, target_velocity)

    def set_target(self, position: np.ndarray, velocity: np.ndarray | None = None) -> None:
        """Set p_d [m] and optionally ṗ_d [m/s]; both are copied."""
        self._target = as_finite_vector(self.name, "target", position, 3)
        self._velocity = (
            np.zeros(3) if velocity is None else as_finite_vector(self.name, "target_velocity", velocity, 3)
        )

    @property
    def target(self) -> np.ndarray:
        """A copy of p_d [m]."""
        if self._target is None:
            raise TargetNotSet(self.name)
        return self._target.copy()

    def compute_state(self, kin: Kinematics) -> TaskState:
        """σ = p, J = J_pos, σ_d = p_d, σ̇_d = ṗ_d."""
        if self._target is None:
            raise TargetNotSet(self.name)
        return TaskState(
            kin.frame_position(self.frame), kin.position_jacobian(self.frame), self._target, self._velocity
        )


POSITION_KEYS: tuple[TaskKey, ...] = frame_task_keys(
    "position",
    TaskKey("target", "fixed target position p_d, base frame (default: the scenario's waypoints set it)", None, "m"),
)
"""Keys of a ``position`` description."""


build_position = frame_task_builder(PositionTask, "position", (3,))
"""Builder of a ``position`` description."""
