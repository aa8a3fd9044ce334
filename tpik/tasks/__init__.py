"""Tasks: one class per file; :mod:`tpik.tasks.task` holds the interface.

The built-in task types of a hierarchy description are registered here, one line each
(:func:`~tpik.tasks.registry.register_task`); a new type is one file (the task, its keys and its
builder) plus one registration, here or in the user's own module (``docs/extending.md``).
"""

from __future__ import annotations

from tpik.tasks.joint_limit_task import JOINT_LIMIT_KEYS, JointLimitTask, build_joint_limits
from tpik.tasks.manipulability_task import MANIPULABILITY_KEYS, ManipulabilityTask, build_manipulability
from tpik.tasks.obstacle_distance_task import OBSTACLE_DISTANCE_KEYS, ObstacleDistanceTask, build_obstacle_distances
from tpik.tasks.orientation_task import ORIENTATION_KEYS, OrientationTask, build_orientation
from tpik.tasks.pose_task import POSE_KEYS, PoseTask, build_pose
from tpik.tasks.position_task import POSITION_KEYS, PositionTask, build_position
from tpik.tasks.registry import (
    REQUIRED,
    TaskKey,
    TaskSpec,
    TaskType,
    build_tasks,
    get_task_type,
    register_task,
    task_types,
)
from tpik.tasks.task import Activation, SetTask, Task, TaskState, Thresholds
from tpik.tasks.virtual_wall_task import (
    VIRTUAL_WALL_KEYS,
    WALL_BOX_KEYS,
    VirtualWallTask,
    build_virtual_wall,
    build_wall_box,
)

_IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]

register_task(
    "joint_limit",
    build_joint_limits,
    keys=JOINT_LIMIT_KEYS,
    example={"joints": [2, 4, 6], "safety_margin": 0.1, "activation_margin": 0.05},
    summary="joint position limits: σ = q_j within the model's limits minus a safety margin [rad]",
)
register_task(
    "wall_box",
    build_wall_box,
    keys=WALL_BOX_KEYS,
    example={"lower": [-0.5, -0.5, 0.2], "upper": [0.5, 0.5, 0.9]},
    summary="six virtual walls of an axis-aligned box around a frame: signed distances [m]",
)
register_task(
    "virtual_wall",
    build_virtual_wall,
    keys=VIRTUAL_WALL_KEYS,
    example={"name": "wall", "normal": [0.3, -0.5, 0.8], "offset": 0.2},
    summary="one virtual wall: signed distance of a frame origin to a plane [m]",
)
register_task(
    "obstacle_distance",
    build_obstacle_distances,
    keys=OBSTACLE_DISTANCE_KEYS,
    example={"frames": ["link_4", "link_6", "link_7"]},
    summary="distance of control points to the closest obstacle point, partial Jacobian (paper sec. III) [m]",
)
register_task(
    "position",
    build_position,
    keys=POSITION_KEYS,
    example={"target": [0.3, 0.3, 0.5]},
    summary="frame position in the base frame [m]",
)
register_task(
    "orientation",
    build_orientation,
    keys=ORIENTATION_KEYS,
    example={"target": _IDENTITY},
    summary="frame orientation, log-map error [rad]",
)
register_task(
    "pose",
    build_pose,
    keys=POSE_KEYS,
    example={"target": [[*row, t] for row, t in zip(_IDENTITY, (0.3, 0.0, 0.5), strict=True)] + [[0.0, 0.0, 0.0, 1.0]]},
    summary="frame position and orientation [m, rad]",
)
register_task(
    "manipulability",
    build_manipulability,
    keys=MANIPULABILITY_KEYS,
    example={"target": 0.2},
    summary="translational manipulability of a frame as a gradient task (unitless)",
)

BUILTIN_TASK_TYPES: tuple[str, ...] = tuple(t.name for t in task_types())
"""The task types registered above (``docs/config.md`` lists these; extensions add their own)."""

__all__ = [
    "BUILTIN_TASK_TYPES",
    "REQUIRED",
    "Activation",
    "JointLimitTask",
    "ManipulabilityTask",
    "ObstacleDistanceTask",
    "OrientationTask",
    "PoseTask",
    "PositionTask",
    "SetTask",
    "Task",
    "TaskKey",
    "TaskSpec",
    "TaskState",
    "TaskType",
    "Thresholds",
    "VirtualWallTask",
    "build_tasks",
    "get_task_type",
    "register_task",
    "task_types",
]
