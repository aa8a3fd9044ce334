"""Set-based task-priority inverse kinematics (Di Lillo et al.): tasks, hierarchy, solver."""

from __future__ import annotations

from tpik.exceptions import (
    EmptyHierarchy,
    InvalidTaskState,
    TargetNotSet,
    TaskDefinitionError,
    ThresholdOrderError,
    TpikError,
)
from tpik.hierarchy import Hierarchy, Level, build_tasks
from tpik.solver import TpikSettings, TpikSolver, solve_tpik
from tpik.step_result import IkSolver, SolveStatus, StepResult

__all__ = [
    "EmptyHierarchy",
    "Hierarchy",
    "IkSolver",
    "InvalidTaskState",
    "Level",
    "SolveStatus",
    "StepResult",
    "TargetNotSet",
    "TaskDefinitionError",
    "ThresholdOrderError",
    "TpikError",
    "TpikSettings",
    "TpikSolver",
    "build_tasks",
    "solve_tpik",
]
