"""Frame orientation task (equality, m = 3)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from robots import Kinematics
from tpik.exceptions import TargetNotSet
from tpik.tasks._targets import as_rotation
from tpik.tasks.registry import TaskKey, frame_task_builder, frame_task_keys
from tpik.tasks.task import Task, TaskState


class OrientationTask(Task):
    r"""Bring a frame's orientation to a target rotation.

    The error is the rotation vector taking the current orientation to the target, in base
    axes, and the Jacobian is the angular part of the geometric Jacobian:

    .. math:: \tilde\sigma = \log(R_d R^T)^\vee,\quad J = J_{\omega}(q)

    ``value`` holds log(R)^∨ (for plots); only the error and Jacobian drive the solvers.

    Args:
        name: Task name.
        frame: Robot frame.
        gain: K [1/s].
        target: Optional target rotation R_d, shape (3, 3).
    """

    def __init__(
        self, name: str, frame: str = "end_effector", gain: float = 1.0, target: np.ndarray | None = None
    ) -> None:
        super().__init__(name, 3, gain)
        self.frame = frame
        self._target: np.ndarray | None = None
        if target is not None:
            self.set_target(target)

    def set_target(self, rotation: np.ndarray) -> None:
        """Set R_d (copied)."""
        self._target = as_rotation(self.name, rotation)

    @property
    def target(self) -> np.ndarray:
        """A copy of R_d."""
        if self._target is None:
            raise TargetNotSet(self.name)
        return self._target.copy()

    def compute_state(self, kin: Kinematics) -> TaskState:
        """σ̃ = log(R_d Rᵀ), J = J_ω."""
        if self._target is None:
            raise TargetNotSet(self.name)
        rot = kin.frame_rotation(self.frame)
        error = pin.log3(self._target @ rot.T)
        value = pin.log3(rot)
        jac = kin.frame_jacobian(self.frame)[3:]
        return TaskState(value, jac, value + error, np.zeros(3), error)


ORIENTATION_KEYS: tuple[TaskKey, ...] = frame_task_keys(
    "orientation",
    TaskKey("target", "target rotation matrix R_d (3×3, rows) in the base frame (default: none set)", None),
)
"""Keys of an ``orientation`` description."""


build_orientation = frame_task_builder(OrientationTask, "orientation", (3, 3))
"""Builder of a ``orientation`` description."""
