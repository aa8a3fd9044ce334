"""Frame pose task (equality, m = 6): position rows then orientation rows."""

from __future__ import annotations

import numpy as np

from robots import Kinematics
from tpik.tasks.orientation_task import OrientationTask
from tpik.tasks.position_task import PositionTask
from tpik.tasks.registry import TaskKey, frame_task_builder, frame_task_keys
from tpik.tasks.task import Task, TaskState


class PoseTask(Task):
    r"""Position and orientation of a frame at once.

    .. math:: \tilde\sigma = \begin{bmatrix} p_d - p \\ \log(R_d R^T)^\vee \end{bmatrix},\quad
        J = \begin{bmatrix} J_{pos} \\ J_\omega \end{bmatrix}

    Args:
        name: Task name.
        frame: Robot frame.
        gain: K [1/s].
        target: Optional 4×4 homogeneous target in the base frame.
    """

    def __init__(
        self, name: str, frame: str = "end_effector", gain: float = 1.0, target: np.ndarray | None = None
    ) -> None:
        super().__init__(name, 6, gain)
        self.frame = frame
        self._position = PositionTask(f"{name}.position", frame, gain)
        self._orientation = OrientationTask(f"{name}.orientation", frame, gain)
        if target is not None:
            self.set_target(target)

    def set_target(self, transform: np.ndarray) -> None:
        """Set the 4×4 target transform (copied)."""
        t = np.asarray(transform, dtype=float)
        self._position.set_target(t[:3, 3])
        self._orientation.set_target(t[:3, :3])

    def compute_state(self, kin: Kinematics) -> TaskState:
        """Stack the position and orientation states."""
        pos = self._position.compute_state(kin)
        rot = self._orientation.compute_state(kin)
        return TaskState(
            np.concatenate([pos.value, rot.value]),
            kin.frame_jacobian(self.frame),
            np.concatenate([pos.desired, rot.desired]),
            np.concatenate([pos.feedforward, rot.feedforward]),
            np.concatenate([pos.error, rot.error]),
        )


POSE_KEYS: tuple[TaskKey, ...] = frame_task_keys(
    "pose",
    TaskKey("target", "target 4×4 homogeneous transform (rows; translation in m) in the base frame", None),
)
"""Keys of a ``pose`` description."""


build_pose = frame_task_builder(PoseTask, "pose", (4, 4))
"""Builder of a ``pose`` description."""
