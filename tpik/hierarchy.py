"""Priority hierarchy: an ordered list of levels, each holding one or more tasks (docs/design.md §2)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from robots import Robot
from tpik.exceptions import EmptyHierarchy, TaskDefinitionError
from tpik.tasks import SetTask, Task
from tpik.tasks.registry import build_tasks


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

        Task types are those of the registry (:func:`tpik.register_task`); built in:
        ``position``, ``orientation``, ``pose``, ``manipulability``, ``joint_limit`` (``joint``
        or ``joints``), ``virtual_wall`` (one plane), ``wall_box`` (six walls of an
        axis-aligned box), ``obstacle_distance`` (``frame`` or ``frames``). Each type's keys,
        units and defaults: ``docs/config.md``.

        Raises:
            TaskDefinitionError: naming ``levels[i]`` or ``levels[i].tasks[k]`` and the bad key
                or value (an unknown frame included).
        """
        if not levels:
            raise EmptyHierarchy("levels: a hierarchy needs at least one level")
        built: list[Level] = []
        seen: dict[str, str] = {}
        for i, level in enumerate(levels):
            where = f"levels[{i}]"
            unknown = set(level) - {"name", "tasks"}
            if unknown:
                raise TaskDefinitionError(f"{where}: unknown key '{sorted(unknown)[0]}'")
            entries = level.get("tasks", [])
            if not isinstance(entries, Sequence) or isinstance(entries, str):
                raise TaskDefinitionError(f"{where}.tasks: must be a list of task tables, got {entries!r}")
            tasks: list[Task] = []
            for k, entry in enumerate(entries):
                at = f"{where}.tasks[{k}]"
                if not isinstance(entry, Mapping):
                    raise TaskDefinitionError(f"{at}: must be a table, got {entry!r}")
                for task in build_tasks(entry, robot, at):
                    if task.name in seen:
                        raise TaskDefinitionError(f"{at}: duplicate task name '{task.name}' (also {seen[task.name]})")
                    seen[task.name] = at
                    tasks.append(task)
            name = str(level.get("name", f"level_{i}"))
            if not tasks:
                raise EmptyHierarchy(f"{where}: level '{name}' holds no task")
            built.append(Level(name, tuple(tasks)))
        return cls(built)


__all__ = ["Hierarchy", "Level", "build_tasks"]
