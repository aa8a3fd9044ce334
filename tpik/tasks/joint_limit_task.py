"""Joint position limit (set-based, m = 1)."""

from __future__ import annotations

import math

import numpy as np

from robots import Kinematics, Robot
from tpik.exceptions import TaskDefinitionError
from tpik.tasks.registry import GAIN_KEY, GROUP_KEY, TaskKey, TaskSpec
from tpik.tasks.task import SetTask, Task, Thresholds


class JointLimitTask(SetTask):
    r"""Keep joint ``j`` inside its safety range.

    .. math:: \sigma = q_j,\quad J = e_j^T

    Args:
        name: Task name.
        joint: 1-based joint number.
        nq: Number of joints ``n``.
        thresholds: Thresholds [rad].
        gain: K [1/s].
        group: Metrics group (default ``joint_limits``).
    """

    default_group = "joint_limits"

    def __init__(
        self, name: str, joint: int, nq: int, thresholds: Thresholds, gain: float = 1.0, group: str | None = None
    ) -> None:
        if not 1 <= joint <= nq:
            raise TaskDefinitionError(f"task '{name}': joint must be in 1..{nq}, got {joint}")
        super().__init__(name, thresholds, gain, group)
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
        group: str | None = None,
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
        return cls(task_name, joint, robot.nq, th, gain, group)

    def compute_value(self, kin: Kinematics) -> float:
        """σ = q_j [rad]."""
        return float(kin.q[self.joint - 1])

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        """J = e_jᵀ (a shared read-only row)."""
        return self._jacobian

    def compute_value_and_jacobian(self, kin: Kinematics) -> tuple[float, np.ndarray]:
        """σ = q_j, J = e_jᵀ."""
        return float(kin.q[self.joint - 1]), self._jacobian


JOINT_LIMIT_KEYS: tuple[TaskKey, ...] = (
    TaskKey("joint", "1-based joint number (or give `joints`)", None),
    TaskKey("joints", "1-based joint numbers, one task each (or give `joint`)", None),
    TaskKey("safety_margin", "safety threshold inside each physical limit of the model", 0.1, "rad"),
    TaskKey("activation_margin", "ε: activation threshold inside the safety threshold", 0.05, "rad"),
    GAIN_KEY,
    TaskKey("name", "task name, only with a single `joint` (default `joint_limit_<j>`)", None),
    GROUP_KEY,
)
"""Keys of a ``joint_limit`` description."""


def build_joint_limits(spec: TaskSpec, robot: Robot) -> list[Task]:
    """``joint_limit``: one :class:`JointLimitTask` per joint, thresholds from the model's limits."""
    key = spec.one_or_many("joint", "joints")
    joints = spec.integers(key)
    margin = spec.number("safety_margin", positive=True)
    eps = spec.number("activation_margin", positive=True)
    gain = spec.number("gain", positive=True)
    name = spec.name_for(len(joints), "joint")
    group = spec.optional_text("group")
    for j in joints:
        if not 1 <= j <= robot.nq:
            raise spec.error(key, f"joint must be in 1..{robot.nq}, got {j}")
        if not (math.isfinite(robot.q_lower[j - 1]) and math.isfinite(robot.q_upper[j - 1])):
            raise spec.error(key, f"joint {j} is continuous (no position limits)")
    tasks: list[Task] = []
    for j in joints:
        with spec.about("safety_margin", "activation_margin"):
            tasks.append(JointLimitTask.from_robot(robot, j, margin, eps, gain, name, group))
    return tasks
