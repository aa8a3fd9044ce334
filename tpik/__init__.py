"""Set-based task-priority inverse kinematics (Di Lillo et al.): tasks, hierarchy, solver."""

from __future__ import annotations

from tpik.exceptions import (
    EmptyHierarchy,
    InvalidSettings,
    InvalidTaskState,
    TargetNotSet,
    TaskDefinitionError,
    ThresholdOrderError,
    TpikError,
)
from tpik.hierarchy import Hierarchy, Level
from tpik.solver import TpikSettings, TpikSolver, solve_tpik
from tpik.step_result import IkSolver, SolveStatus, StepResult
from tpik.tasks.registry import TaskKey, TaskSpec, build_tasks, register_task, task_types

__all__ = [
    "EmptyHierarchy",
    "Hierarchy",
    "IkSolver",
    "InvalidSettings",
    "InvalidTaskState",
    "Level",
    "SolveStatus",
    "StepResult",
    "TargetNotSet",
    "TaskDefinitionError",
    "TaskKey",
    "TaskSpec",
    "ThresholdOrderError",
    "TpikError",
    "TpikSettings",
    "TpikSolver",
    "build_tasks",
    "register_task",
    "solve_tpik",
    "task_types",
]
