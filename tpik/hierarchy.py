"""Priority hierarchy: an ordered list of levels, each holding one or more tasks (DESIGN §2)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robots import Robot
from tpik.exceptions import EmptyHierarchy, TaskDefinitionError
from tpik.tasks import (
    JointLimitTask,
    ManipulabilityTask,
    ObstacleDistanceTask,
    OrientationTask,
    PoseTask,
    PositionTask,
    SetTask,
    Task,
    Thresholds,
    VirtualWallTask,
)


@dataclass(frozen=True)
class Level:
    """One priority level: its tasks are stacked (eq. 5) and share a priority.

    Attributes:
        name: Level name (e.g. ``"safety"``).
        tasks: Tasks of the level, in order.
    """

    name: str
    tasks: tuple[Task, ...]

    def __post_init__(self) -> None:
        if not self.tasks:
            raise EmptyHierarchy(f"level '{self.name}' holds no task")


class Hierarchy:
    """An ordered list of priority levels, highest first.

    The same object is handed to every solver (TPIK, HQP, mink). Task names are unique.

    Args:
        levels: Levels, highest priority first.
    """

    def __init__(self, levels: Sequence[Level]) -> None:
        if not levels:
            raise EmptyHierarchy("a hierarchy needs at least one level")
        self.levels = tuple(levels)
        self._by_name: dict[str, Task] = {}
        for level in self.levels:
            for task in level.tasks:
                if task.name in self._by_name:
                    raise TaskDefinitionError(f"duplicate task name '{task.name}'")
                self._by_name[task.name] = task

    @property
    def tasks(self) -> tuple[Task, ...]:
        """All tasks, highest level first."""
        return tuple(self._by_name.values())

    @property
    def set_tasks(self) -> tuple[SetTask, ...]:
        """The set-based tasks, highest level first."""
        return tuple(t for t in self._by_name.values() if isinstance(t, SetTask))

    def task(self, name: str) -> Task:
        """Look a task up by name."""
        try:
            return self._by_name[name]
        except KeyError:
            raise TaskDefinitionError(f"no task named '{name}'; tasks: {', '.join(self._by_name)}") from None

    def tasks_of_type(self, kind: type[Task]) -> list[Task]:
        """Tasks that are instances of ``kind``."""
        return [t for t in self._by_name.values() if isinstance(t, kind)]

    def __iter__(self) -> Iterator[Level]:
        return iter(self.levels)

    def __len__(self) -> int:
        return len(self.levels)

    def __repr__(self) -> str:
        inner = "; ".join(f"{lv.name}: {', '.join(t.name for t in lv.tasks)}" for lv in self.levels)
        return f"Hierarchy({inner})"

    @classmethod
    def from_description(cls, levels: Sequence[Mapping[str, Any]], robot: Robot) -> Hierarchy:
        """Build a hierarchy from plain data (what the TOML config produces).

        Example::

            [{"name": "safety", "tasks": [{"type": "joint_limit", "joints": [2, 4, 6],
                                           "safety_margin": 0.1, "activation_margin": 0.05}]},
             {"name": "operational", "tasks": [{"type": "position", "frame": "end_effector"}]}]

        A task without ``frame`` acts on the robot's end-effector frame (``robot.ee_frame``); an
        ``obstacle_distance`` without ``frame``/``frames`` on its default control points
        (``robot.control_points``).

        Task types: ``position``, ``orientation``, ``pose``, ``manipulability``,
        ``joint_limit`` (``joint`` or ``joints``), ``virtual_wall`` (one plane),
        ``wall_box`` (six walls of an axis-aligned box), ``obstacle_distance`` (``frame`` or
        ``frames``). See :data:`TASK_BUILDERS` for each type's keys.

        Raises:
            TaskDefinitionError: naming ``levels[i].tasks[k]`` and the bad key or value.
        """
        built: list[Level] = []
        for i, level in enumerate(levels):
            where = f"levels[{i}]"
            unknown = set(level) - {"name", "tasks"}
            if unknown:
                raise TaskDefinitionError(f"{where}: unknown key '{sorted(unknown)[0]}'")
            tasks: list[Task] = []
            for k, spec in enumerate(level.get("tasks", [])):
                tasks.extend(build_tasks(spec, robot, f"{where}.tasks[{k}]"))
            built.append(Level(str(level.get("name", f"level_{i}")), tuple(tasks)))
        return cls(built)


def _thresholds(lo_phys: float, lo_safe: float, hi_safe: float, hi_phys: float, eps: float) -> Thresholds:
    return Thresholds(float(lo_phys), float(lo_safe), float(hi_safe), float(hi_phys), float(eps))


def _joint_limits(spec: dict[str, Any], robot: Robot) -> list[Task]:
    joints = spec.pop("joints", None) or [spec.pop("joint")]
    margin = spec.pop("safety_margin", 0.1)
    eps = spec.pop("activation_margin", 0.05)
    gain = spec.pop("gain", 1.0)
    name = spec.pop("name", None)
    if name is not None and len(joints) > 1:
        raise TaskDefinitionError("'name' needs a single 'joint'")
    return [JointLimitTask.from_robot(robot, int(j), margin, eps, gain, name) for j in joints]


_AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


def _wall_box(spec: dict[str, Any], robot: Robot) -> list[Task]:
    frame = spec.pop("frame", robot.ee_frame)
    lower = np.asarray(spec.pop("lower"), dtype=float)
    upper = np.asarray(spec.pop("upper"), dtype=float)
    phys = spec.pop("physical_margin", 0.05)
    eps = spec.pop("activation_margin", 0.03)
    gain = spec.pop("gain", 1.0)
    if lower.shape != (3,) or upper.shape != (3,):
        raise TaskDefinitionError("wall_box: 'lower' and 'upper' need 3 entries [m]")
    walls: list[Task] = []
    for axis_index, axis in enumerate("xyz"):
        lo, hi = float(lower[axis_index]), float(upper[axis_index])
        if not lo < hi:
            raise TaskDefinitionError(f"wall_box: lower {axis}={lo:g} must be < upper {axis}={hi:g}")
        n = _AXES[axis]
        # σ = n·p − d ≥ 0 inside; the wall itself is the safety threshold.
        th = _thresholds(-phys, 0.0, math.inf, math.inf, eps)
        walls.append(VirtualWallTask(f"wall_{axis}_min", frame, n, lo, th, gain))
        walls.append(VirtualWallTask(f"wall_{axis}_max", frame, -n, -hi, th, gain))
    return walls


def _virtual_wall(spec: dict[str, Any], robot: Robot) -> list[Task]:
    phys = spec.pop("physical_margin", 0.05)
    eps = spec.pop("activation_margin", 0.03)
    th = _thresholds(-phys, 0.0, math.inf, math.inf, eps)
    return [
        VirtualWallTask(
            spec.pop("name"),
            spec.pop("frame", robot.ee_frame),
            spec.pop("normal"),
            spec.pop("offset"),
            th,
            spec.pop("gain", 1.0),
        )
    ]


def _obstacles(spec: dict[str, Any], robot: Robot) -> list[Task]:
    frames = spec.pop("frames", None) or [spec.pop("frame", None)]
    if frames == [None]:  # no frame named: the robot's default control points
        frames = list(robot.control_points)
    safety = float(spec.pop("safety_distance", 0.35))
    physical = float(spec.pop("physical_distance", 0.1))
    eps = spec.pop("activation_margin", 0.05)
    gain = spec.pop("gain", 1.0)
    name = spec.pop("name", None)
    if name is not None and len(frames) > 1:
        raise TaskDefinitionError("'name' needs a single 'frame'")
    tasks: list[Task] = []
    for frame in frames:
        robot.frame_id(frame)
        th = _thresholds(physical, safety, math.inf, math.inf, eps)
        tasks.append(ObstacleDistanceTask(name or f"obstacle_{frame}", frame, th, gain))
    return tasks


def _position(spec: dict[str, Any], robot: Robot) -> list[Task]:
    frame = spec.pop("frame", robot.ee_frame)
    robot.frame_id(frame)
    return [PositionTask(spec.pop("name", f"position_{frame}"), frame, spec.pop("gain", 1.0), spec.pop("target", None))]


def _orientation(spec: dict[str, Any], robot: Robot) -> list[Task]:
    frame = spec.pop("frame", robot.ee_frame)
    robot.frame_id(frame)
    return [
        OrientationTask(
            spec.pop("name", f"orientation_{frame}"), frame, spec.pop("gain", 1.0), spec.pop("target", None)
        )
    ]


def _pose(spec: dict[str, Any], robot: Robot) -> list[Task]:
    frame = spec.pop("frame", robot.ee_frame)
    robot.frame_id(frame)
    return [PoseTask(spec.pop("name", f"pose_{frame}"), frame, spec.pop("gain", 1.0), spec.pop("target", None))]


def _manipulability(spec: dict[str, Any], robot: Robot) -> list[Task]:
    frame = spec.pop("frame", robot.ee_frame)
    robot.frame_id(frame)
    return [
        ManipulabilityTask(
            spec.pop("name", f"manipulability_{frame}"), frame, spec.pop("gain", 1.0), spec.pop("target", 0.2)
        )
    ]


TASK_BUILDERS: dict[str, Callable[[dict[str, Any], Robot], list[Task]]] = {
    "joint_limit": _joint_limits,
    "wall_box": _wall_box,
    "virtual_wall": _virtual_wall,
    "obstacle_distance": _obstacles,
    "position": _position,
    "orientation": _orientation,
    "pose": _pose,
    "manipulability": _manipulability,
}
"""Task ``type`` → builder. Each builder pops the keys it knows; any key left is an error."""


def build_tasks(spec: Mapping[str, Any], robot: Robot, where: str = "task") -> list[Task]:
    """Build the task(s) one description entry stands for.

    Raises:
        TaskDefinitionError: unknown type, missing or unknown key, invalid value — the
            message starts with ``where``.
    """
    rest = dict(spec)
    kind = rest.pop("type", None)
    if kind not in TASK_BUILDERS:
        raise TaskDefinitionError(f"{where}: unknown task type {kind!r}; known: {', '.join(TASK_BUILDERS)}")
    try:
        tasks = TASK_BUILDERS[kind](rest, robot)
    except KeyError as exc:
        raise TaskDefinitionError(f"{where}: {kind} needs key {exc.args[0]!r}") from None
    except (TypeError, ValueError) as exc:
        raise TaskDefinitionError(f"{where}: {exc}") from None
    if rest:
        raise TaskDefinitionError(f"{where}: unknown key '{sorted(rest)[0]}' for task type {kind}")
    return tasks
