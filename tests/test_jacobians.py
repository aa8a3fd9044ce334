"""Every task's analytic Jacobian against central finite differences of its value.

Parametrised over :data:`TASK_FACTORIES`: a new task is covered by adding one line.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pinocchio as pin
import pytest

from robots import Robot
from tests.conftest import random_configuration
from tpik.tasks import (
    JointLimitTask,
    ManipulabilityTask,
    ObstacleDistanceTask,
    OrientationTask,
    PoseTask,
    PositionTask,
    Task,
    Thresholds,
    VirtualWallTask,
)

_OBSTACLE = np.array([0.4, -0.3, 0.6])
_ROT = pin.rpy.rpyToMatrix(0.3, -0.2, 0.5)


def _obstacle(frame: str) -> Callable[[Robot], Task]:
    def make(robot: Robot) -> Task:
        task = ObstacleDistanceTask(f"obstacle_{frame}", frame, Thresholds(0.1, 0.35, math.inf, math.inf, 0.05))
        task.set_obstacle(_OBSTACLE)
        return task

    return make


TASK_FACTORIES: dict[str, Callable[[Robot], Task]] = {
    "position": lambda r: PositionTask("p", "end_effector", target=np.zeros(3)),
    "position_link_6": lambda r: PositionTask("p6", "link_6", target=np.zeros(3)),
    "orientation": lambda r: OrientationTask("o", "end_effector", target=_ROT),
    "pose": lambda r: PoseTask("x", "end_effector", target=np.eye(4)),
    "joint_limit_4": lambda r: JointLimitTask.from_robot(r, 4, 0.1, 0.05),
    "wall": lambda r: VirtualWallTask(
        "w", "end_effector", np.array([0.3, -0.5, 0.8]), 0.2, Thresholds(-0.05, 0.0, math.inf, math.inf, 0.03)
    ),
    "obstacle_link_4": _obstacle("link_4"),
    "obstacle_link_6": _obstacle("link_6"),
    "obstacle_link_7": _obstacle("link_7"),
    "manipulability": lambda r: ManipulabilityTask("m", "end_effector"),
}

_PARTIAL = {"obstacle_link_4": 4, "obstacle_link_6": 6, "obstacle_link_7": 7}


def _rotation_error_derivative(task: Task, robot: Robot, q: np.ndarray, eps: float) -> np.ndarray:
    """For SO(3) tasks compare J with d(rotation)/dq as an angular velocity (dR Rᵀ)^∨."""
    cols = []
    rot = robot.frame_pose(q, task.frame)[:3, :3]  # type: ignore[attr-defined]
    for k in range(robot.nq):
        dq = np.zeros(robot.nq)
        dq[k] = eps
        d_rot = robot.frame_pose(q + dq, task.frame)[:3, :3] - robot.frame_pose(q - dq, task.frame)[:3, :3]  # type: ignore[attr-defined]
        w = (d_rot / (2 * eps)) @ rot.T
        cols.append([w[2, 1], w[0, 2], w[1, 0]])
    return np.array(cols).T


@pytest.mark.parametrize("kind", sorted(TASK_FACTORIES))
def test_task_jacobian_matches_finite_differences(jaco, kind):
    task = TASK_FACTORIES[kind](jaco)
    rng = np.random.default_rng(7)
    eps = 1e-6
    for _ in range(8):
        q = random_configuration(jaco, rng)
        jac = task.compute_state(jaco.kinematics(q)).jacobian
        assert jac.shape == (task.dim, jaco.nq)
        numeric = np.empty_like(jac)
        for k in range(jaco.nq):
            dq = np.zeros(jaco.nq)
            dq[k] = eps
            # Obstacle tasks: the paper's Jacobian only lets joints before the control point act.
            if kind in _PARTIAL and k >= _PARTIAL[kind] - 1:
                numeric[:, k] = 0.0
                continue
            plus = task.compute_state(jaco.kinematics(q + dq)).value
            minus = task.compute_state(jaco.kinematics(q - dq)).value
            numeric[:, k] = (plus - minus) / (2 * eps)
        if kind == "orientation":
            numeric = _rotation_error_derivative(task, jaco, q, eps)
        elif kind == "pose":
            numeric[3:] = _rotation_error_derivative(task, jaco, q, eps)
        np.testing.assert_allclose(jac, numeric, atol=2e-6, err_msg=kind)


def test_orientation_error_decreases_along_jacobian_step(jaco):
    # CLIK on the orientation task alone converges: the error sign convention matches J.
    task = OrientationTask("o", target=_ROT)
    q = jaco.home.copy()
    for _ in range(200):
        state = task.compute_state(jaco.kinematics(q))
        q = q + 0.05 * np.linalg.pinv(state.jacobian) @ state.error
    assert np.linalg.norm(task.compute_state(jaco.kinematics(q)).error) < 1e-3
