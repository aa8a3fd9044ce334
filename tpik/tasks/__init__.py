"""Tasks: one class per file; :mod:`tpik.tasks.task` holds the interface."""

from __future__ import annotations

from tpik.tasks.joint_limit_task import JointLimitTask
from tpik.tasks.manipulability_task import ManipulabilityTask
from tpik.tasks.obstacle_distance_task import ObstacleDistanceTask
from tpik.tasks.orientation_task import OrientationTask
from tpik.tasks.pose_task import PoseTask
from tpik.tasks.position_task import PositionTask
from tpik.tasks.task import Activation, SetTask, Task, TaskState, Thresholds
from tpik.tasks.virtual_wall_task import VirtualWallTask

__all__ = [
    "Activation",
    "JointLimitTask",
    "ManipulabilityTask",
    "ObstacleDistanceTask",
    "OrientationTask",
    "PoseTask",
    "PositionTask",
    "SetTask",
    "Task",
    "TaskState",
    "Thresholds",
    "VirtualWallTask",
]
