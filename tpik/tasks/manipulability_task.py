"""Translational manipulability of a frame as a gradient task (equality, m = 1)."""

from __future__ import annotations

import numpy as np

from robots import Kinematics, Robot
from tpik.tasks.registry import TaskKey, TaskSpec, frame_task_keys
from tpik.tasks.task import Task, TaskState


class ManipulabilityTask(Task):
    r"""Drive the translational manipulability of a frame toward a target value.

    .. math::
        w(q) = \sqrt{\det(J_v J_v^T)},\qquad
        \frac{\partial w}{\partial q_k} = w\,\mathrm{tr}\!\left((J_vJ_v^T)^{-1}
            J_v \frac{\partial J_v^T}{\partial q_k}\right)

    with the geometric derivative of each Jacobian column (revolute joints, axis z_i through
    p_i, frame origin p): for k ≤ i, ∂J_{v,i}/∂q_k = (z_k×z_i)×(p−p_i) + z_i×(z_k×(p−p_i));
    for k > i, ∂J_{v,i}/∂q_k = z_i×(z_k×(p−p_k)). Used in the optimisation group with a
    high target: its projected gradient moves the arm away from singularities.

    Args:
        name: Task name.
        frame: Frame whose translational manipulability is measured.
        gain: K [1/s].
        target: Desired w (unitless, m³ scale for position rows).
    """

    def __init__(self, name: str, frame: str = "end_effector", gain: float = 1.0, target: float = 0.2) -> None:
        super().__init__(name, 1, gain)
        self.frame = frame
        self.target = float(target)

    def compute_state(self, kin: Kinematics) -> TaskState:
        """σ = w(q), J = ∇w(q)ᵀ, σ_d = target."""
        jac = kin.frame_jacobian(self.frame)
        jv, axes = jac[:3], jac[3:]
        n = kin.nq
        rel = kin.frame_position(self.frame) - kin.joint_origins()  # p − p_i, (n, 3)
        gram = jv @ jv.T
        w = float(np.sqrt(max(np.linalg.det(gram), 0.0)))
        grad = np.zeros(n)
        if w > 1e-12:
            gram_inv = np.linalg.inv(gram)
            for k in range(n):
                zk = axes[:, k]
                djv = np.empty((3, n))
                for i in range(n):
                    zi = axes[:, i]
                    if k <= i:
                        djv[:, i] = np.cross(np.cross(zk, zi), rel[i]) + np.cross(zi, np.cross(zk, rel[i]))
                    else:
                        djv[:, i] = np.cross(zi, np.cross(zk, rel[k]))
                grad[k] = w * float(np.trace(gram_inv @ (jv @ djv.T)))
        return TaskState(np.array([w]), grad[None, :], np.array([self.target]), np.zeros(1))


MANIPULABILITY_KEYS: tuple[TaskKey, ...] = frame_task_keys(
    "manipulability",
    TaskKey("target", "desired translational manipulability w (unitless, m³ scale)", 0.2),
)
"""Keys of a ``manipulability`` description."""


def build_manipulability(spec: TaskSpec, robot: Robot) -> list[Task]:
    """``manipulability``: one :class:`ManipulabilityTask` (gradient task)."""
    frame = spec.frame("frame")
    name = spec.optional_text("name") or f"manipulability_{frame}"
    return [ManipulabilityTask(name, frame, spec.number("gain", positive=True), spec.number("target", minimum=0.0))]
