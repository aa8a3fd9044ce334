"""Every task's analytic Jacobian against central finite differences of its value.

Parametrised over the task registry (:func:`tpik.task_types`): every registered type is built
from its registered ``example`` description and checked, so a new task type is covered without
touching this file. A few more frames and planes are added in :data:`EXTRA`.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from robots import Robot
from tests.conftest import random_configuration
from tpik.tasks import (
    ObstacleDistanceTask,
    OrientationTask,
    PoseTask,
    Task,
    Thresholds,
    build_tasks,
    task_types,
)

_OBSTACLE = np.array([0.4, -0.3, 0.6])
_ROT = pin.rpy.rpyToMatrix(0.3, -0.2, 0.5)

EXTRA: dict[str, dict[str, object]] = {
    "position_link_6": {"type": "position", "frame": "link_6", "target": [0.0, 0.0, 0.0]},
    "orientation_rpy": {"type": "orientation", "target": _ROT.tolist()},
    "virtual_wall_link_4": {"type": "virtual_wall", "name": "w4", "frame": "link_4", "normal": [0, 1, 1], "offset": 0},
}


def _descriptions() -> dict[str, dict[str, object]]:
    out: dict[str, dict[str, object]] = {t.name: {"type": t.name, **t.example} for t in task_types()}
    out.update(EXTRA)
    return out


def _rotation_error_derivative(frame: str, robot: Robot, q: np.ndarray, eps: float) -> np.ndarray:
    """For SO(3) tasks compare J with d(rotation)/dq as an angular velocity (dR Rᵀ)^∨."""
    cols = []
    rot = robot.frame_pose(q, frame)[:3, :3]
    for k in range(robot.nq):
        dq = np.zeros(robot.nq)
        dq[k] = eps
        d_rot = robot.frame_pose(q + dq, frame)[:3, :3] - robot.frame_pose(q - dq, frame)[:3, :3]
        w = (d_rot / (2 * eps)) @ rot.T
        cols.append([w[2, 1], w[0, 2], w[1, 0]])
    return np.array(cols).T


def assert_jacobian_matches_finite_differences(task: Task, robot: Robot, seed: int = 7) -> None:
    """J of ``task`` equals the central difference of σ at 8 random configurations (atol 2e-6).

    An obstacle task's Jacobian is the paper's partial one: only the joints before the control
    point's act (sec. III), so the other columns are compared with zero. SO(3) tasks are compared
    with the angular velocity of their frame.
    """
    rng = np.random.default_rng(seed)
    eps = 1e-6
    partial = None
    if isinstance(task, ObstacleDistanceTask):
        task.set_obstacle(_OBSTACLE)
        partial = task.joint if task.joint is not None else robot.frame_joint(task.frame)
    for _ in range(8):
        q = random_configuration(robot, rng)
        jac = task.compute_state(robot.kinematics(q)).jacobian
        assert jac.shape == (task.dim, robot.nq)
        numeric = np.empty_like(jac)
        for k in range(robot.nq):
            if partial is not None and k >= partial - 1:
                numeric[:, k] = 0.0
                continue
            dq = np.zeros(robot.nq)
            dq[k] = eps
            plus = task.compute_state(robot.kinematics(q + dq)).value
            minus = task.compute_state(robot.kinematics(q - dq)).value
            numeric[:, k] = (plus - minus) / (2 * eps)
        if isinstance(task, OrientationTask):
            numeric = _rotation_error_derivative(task.frame, robot, q, eps)
        elif isinstance(task, PoseTask):
            numeric[3:] = _rotation_error_derivative(task.frame, robot, q, eps)
        np.testing.assert_allclose(jac, numeric, atol=2e-6, err_msg=task.name)


@pytest.mark.parametrize(("kind", "description"), sorted(_descriptions().items()), ids=sorted(_descriptions()))
def test_task_jacobian_matches_finite_differences(jaco, kind, description):
    tasks = build_tasks(description, jaco, kind)
    assert tasks, kind
    for task in tasks:
        assert_jacobian_matches_finite_differences(task, jaco)


def test_every_registered_type_is_covered():
    # The parametrisation above is built from the registry: nothing registered is left out.
    assert {t.name for t in task_types()} <= set(_descriptions())
    assert {"joint_limit", "wall_box", "virtual_wall", "obstacle_distance", "position", "manipulability"} <= {
        t.name for t in task_types()
    }


def test_obstacle_task_jacobian_uses_only_the_joints_before_the_control_point(jaco):
    task = ObstacleDistanceTask("o6", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05))
    task.set_obstacle(_OBSTACLE)
    jac = task.compute_state(jaco.kinematics(jaco.home)).jacobian
    assert np.all(jac[0, jaco.frame_joint("link_6") - 1 :] == 0.0)
    assert np.any(jac[0, : jaco.frame_joint("link_6") - 1] != 0.0)


def test_orientation_error_decreases_along_jacobian_step(jaco):
    # CLIK on the orientation task alone converges: the error sign convention matches J.
    task = OrientationTask("o", target=_ROT)
    q = jaco.home.copy()
    for _ in range(200):
        state = task.compute_state(jaco.kinematics(q))
        q = q + 0.05 * np.linalg.pinv(state.jacobian) @ state.error
    assert np.linalg.norm(task.compute_state(jaco.kinematics(q)).error) < 1e-3
