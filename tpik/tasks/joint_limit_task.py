"""Joint position limit (set-based, m = 1)."""

from __future__ import annotations

import math

import numpy as np

from robots import Kinematics, Robot
from tpik.exceptions import TaskDefinitionError
from tpik.tasks.task import SetTask, Thresholds


class JointLimitTask(SetTask):
    r"""Keep joint ``j`` inside its safety range.

    .. math:: \sigma = q_j,\quad J = e_j^T

    Args:
        name: Task name.
        joint: 1-based joint number.
        nq: Number of joints ``n``.
        thresholds: Thresholds [rad].
        gain: K [1/s].
    """

    def __init__(self, name: str, joint: int, nq: int, thresholds: Thresholds, gain: float = 1.0) -> None:
        if not 1 <= joint <= nq:
            raise TaskDefinitionError(f"task '{name}': joint must be in 1..{nq}, got {joint}")
        super().__init__(name, thresholds, gain)
        self.joint = int(joint)
        self._jacobian = np.zeros((1, nq))
        self._jacobian[0, joint - 1] = 1.0
        self._jacobian.flags.writeable = False

    @classmethod
    def from_robot(
        cls,
        robot: Robot,
        joint: int,
        safety_margin: float,
        activation_margin: float,
        gain: float = 1.0,
        name: str | None = None,
    ) -> JointLimitTask:
        """Build the task with the model's physical limits and safety = physical ∓ margin [rad]."""
        task_name = name or f"joint_limit_{joint}"
        if not 1 <= joint <= robot.nq:
            raise TaskDefinitionError(f"task '{task_name}': joint must be in 1..{robot.nq}, got {joint}")
        lo, hi = float(robot.q_lower[joint - 1]), float(robot.q_upper[joint - 1])
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise TaskDefinitionError(f"task '{task_name}': joint {joint} is continuous (no position limits)")
        if not safety_margin > 0.0:
            raise TaskDefinitionError(f"task '{task_name}': safety_margin must be > 0, got {safety_margin}")
        th = Thresholds(lo, lo + safety_margin, hi - safety_margin, hi, activation_margin)
        return cls(task_name, joint, robot.nq, th, gain)

    def compute_value(self, kin: Kinematics) -> float:
        """σ = q_j [rad]."""
        return float(kin.q[self.joint - 1])

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        """J = e_jᵀ (a shared read-only row)."""
        return self._jacobian

    def compute_value_and_jacobian(self, kin: Kinematics) -> tuple[float, np.ndarray]:
        """σ = q_j, J = e_jᵀ."""
        return float(kin.q[self.joint - 1]), self._jacobian
