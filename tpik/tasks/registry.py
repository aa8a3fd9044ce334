"""The task registry: the ``type`` names of a hierarchy description and how each is built.

A task type is one builder plus the keys its description table takes::

    register_task(
        "elbow_height",
        build_elbow_height,  # (spec: TaskSpec, robot: Robot) -> list[Task]
        keys=(TaskKey("min_height_m", "lowest allowed height", 0.3, "m"), GAIN_KEY),
        example={"min_height_m": 0.3},
    )

after which ``{"type": "elbow_height", ...}`` is accepted by
:meth:`tpik.Hierarchy.from_description` (and so in a TOML ``[[levels]]`` table) and handed to
every solver. The builder reads its values through :class:`TaskSpec`, whose errors name the
location and the key (``levels[1].tasks[0].min_height_m: must be a finite number, got 'low'``);
unknown keys are rejected before the builder runs. ``docs/extending.md`` walks through it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from robots import Robot
from robots.exceptions import RobotError, UnknownFrame
from tpik.exceptions import TaskDefinitionError
from tpik.tasks.task import Task


class _Required:
    """Default of a key that must be given."""

    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()
"""Default of a :class:`TaskKey` the description must give."""


@dataclass(frozen=True)
class TaskKey:
    """One key of a task description table.

    Attributes:
        name: The key.
        doc: What it means (one line; ``docs/config.md`` shows it).
        default: Value when the key is absent; :data:`REQUIRED` if it must be given; ``None`` when
            the builder derives it (the doc says from what).
        unit: SI unit of the value (``"m"``, ``"rad"``, ``"1/s"``), empty for none.
    """

    name: str
    doc: str
    default: Any = REQUIRED
    unit: str = ""

    @property
    def required(self) -> bool:
        """Whether the description must give this key."""
        return self.default is REQUIRED


NAME_KEY = TaskKey("name", "task name, unique in the hierarchy (default from the type and frame)", None)
GAIN_KEY = TaskKey("gain", "closed-loop gain K of the task (paper eq. 2)", 1.0, "1/s")
FRAME_KEY = TaskKey("frame", "robot frame the task acts on (default: the robot's end-effector frame)", None)
GROUP_KEY = TaskKey(
    "group", "metrics group its violations are counted under in summary.json (default: the task's own)", None
)


def frame_task_keys(prefix: str, target: TaskKey) -> tuple[TaskKey, ...]:
    """Keys of a task on one frame: ``name`` (default ``<prefix>_<frame>``), ``frame``, ``gain``, ``target``."""
    return (TaskKey("name", f"task name (default `{prefix}_<frame>`)", None), FRAME_KEY, GAIN_KEY, target)


TaskBuilder = Callable[["TaskSpec", Robot], Sequence[Task]]
"""Builds the task(s) one description entry stands for."""


def frame_task_builder(cls: Callable[..., Task], prefix: str, target_shape: tuple[int, ...]) -> TaskBuilder:
    """Builder of ``cls(name, frame, gain, target)`` from :func:`frame_task_keys` (target an array or unset)."""

    def build(spec: TaskSpec, robot: Robot) -> list[Task]:
        frame = spec.frame("frame")
        target = spec.optional_array("target", target_shape)
        gain = spec.number("gain", positive=True)
        with spec.about("target"):
            return [cls(spec.optional_text("name") or f"{prefix}_{frame}", frame, gain, target)]

    build.__doc__ = f"``{prefix}``: one ``{getattr(cls, '__name__', prefix)}`` on a frame."
    return build


@dataclass(frozen=True)
class TaskType:
    """A registered task type.

    Attributes:
        name: The ``type`` of a description entry.
        builder: Builds the tasks from a :class:`TaskSpec`.
        keys: Every key the entry may hold (besides ``type``).
        example: A valid entry without ``type``: documentation, and every registered type's
            Jacobian is checked against finite differences on it (``tests/test_jacobians.py``).
        summary: One line on what the type stands for.
    """

    name: str
    builder: TaskBuilder
    keys: tuple[TaskKey, ...]
    example: Mapping[str, Any] = field(default_factory=dict)
    summary: str = ""

    def key(self, name: str) -> TaskKey:
        """The declared key ``name``."""
        for key in self.keys:
            if key.name == name:
                return key
        raise TaskDefinitionError(f"task type '{self.name}' declares no key '{name}'")


_REGISTRY: dict[str, TaskType] = {}


def register_task(
    name: str,
    builder: TaskBuilder,
    *,
    keys: Sequence[TaskKey],
    example: Mapping[str, Any],
    summary: str = "",
    replace: bool = False,
) -> TaskType:
    """Make ``{"type": name, ...}`` a valid task description for every hierarchy built after.

    Args:
        name: The task type (a TOML ``type = "..."``).
        builder: ``builder(spec, robot) -> list[Task]``; reads its keys with :class:`TaskSpec`.
        keys: Every key the description may hold besides ``type``.
        example: A valid description without ``type`` (documentation and tests).
        summary: One line on the type.
        replace: Allow replacing a registered type of the same name.

    Returns:
        The registered :class:`TaskType`.

    Raises:
        TaskDefinitionError: The name is taken (and ``replace`` is false), or a key is declared twice.
    """
    if not name or not name.replace("_", "").isalnum():
        raise TaskDefinitionError(f"task type name must be letters, digits and '_', got {name!r}")
    if name in _REGISTRY and not replace:
        raise TaskDefinitionError(f"task type '{name}' is already registered (pass replace=True to replace it)")
    names = [key.name for key in keys]
    if len(set(names)) != len(names) or "type" in names:
        raise TaskDefinitionError(f"task type '{name}': keys must be unique and not 'type', got {names}")
    task_type = TaskType(name, builder, tuple(keys), dict(example), summary)
    _REGISTRY[name] = task_type
    return task_type


def task_types() -> tuple[TaskType, ...]:
    """Every registered task type, in registration order."""
    return tuple(_REGISTRY.values())


def get_task_type(name: str) -> TaskType:
    """The registered type ``name``.

    Raises:
        TaskDefinitionError: Not registered (the message lists what is).
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        raise TaskDefinitionError(f"unknown task type {name!r}; known: {', '.join(_REGISTRY)}") from None


class TaskSpec:
    """One task description entry, read key by key; every error names ``where`` and the key.

    Args:
        task_type: The entry's registered type.
        data: The entry without ``type``.
        robot: The robot the tasks are built for (frames are checked against it).
        where: Location of the entry in the description, e.g. ``levels[0].tasks[2]``.

    Raises:
        TaskDefinitionError: The entry holds a key the type does not declare.
    """

    def __init__(self, task_type: TaskType, data: Mapping[str, Any], robot: Robot, where: str) -> None:
        self.type = task_type
        self.robot = robot
        self.where = where
        self._data = dict(data)
        self._keys = {key.name: key for key in task_type.keys}
        for key in self._data:
            if key not in self._keys:
                known = ", ".join(["type", *self._keys])
                raise TaskDefinitionError(
                    f"{where}: unknown key '{key}' for task type {task_type.name}; known: {known}"
                )

    def error(self, key: str, message: str) -> TaskDefinitionError:
        """An error naming the location and ``key``: ``levels[0].tasks[1].<key>: <message>``."""
        return TaskDefinitionError(f"{self.where}.{key}: {message}")

    def given(self, key: str) -> bool:
        """Whether the entry gives ``key`` itself (not its default)."""
        self._declared(key)
        return key in self._data

    def value(self, key: str) -> Any:
        """The raw value of ``key``, or its declared default.

        Raises:
            TaskDefinitionError: A required key is missing.
        """
        declared = self._declared(key)
        if key in self._data:
            return self._data[key]
        if declared.required:
            raise TaskDefinitionError(f"{self.where}: task type {self.type.name} needs key '{key}'")
        return declared.default

    def number(self, key: str, *, minimum: float | None = None, positive: bool = False) -> float:
        """A finite float (``positive``: > 0; ``minimum``: ≥ it)."""
        value = self.value(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.error(key, f"must be a finite number, got {value!r}")
        if positive and not value > 0.0:
            raise self.error(key, f"must be > 0, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be >= {minimum:g}, got {value!r}")
        return float(value)

    def integers(self, key: str) -> list[int]:
        """A non-empty list of integers (a single integer is a list of one)."""
        value = self.value(key)
        items = value if isinstance(value, list | tuple) else [value]
        if not items:
            raise self.error(key, "must list at least one entry, got []")
        if any(isinstance(v, bool) or not isinstance(v, int) for v in items):
            raise self.error(key, f"must be integers, got {value!r}")
        return [int(v) for v in items]

    def text(self, key: str) -> str:
        """A non-empty string."""
        value = self.value(key)
        if not isinstance(value, str) or not value:
            raise self.error(key, f"must be a non-empty string, got {value!r}")
        return value

    def optional_text(self, key: str) -> str | None:
        """A non-empty string, or ``None`` when the entry leaves the key (default ``None``) out."""
        return None if self.value(key) is None else self.text(key)

    def array(self, key: str, shape: tuple[int, ...]) -> np.ndarray:
        """A finite float array of ``shape``."""
        value = self.value(key)
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise self.error(key, f"must be numbers of shape {list(shape)}, got {value!r}") from None
        if arr.shape != shape or not np.all(np.isfinite(arr)):
            raise self.error(key, f"must be finite numbers of shape {list(shape)}, got {value!r}")
        return arr

    def optional_array(self, key: str, shape: tuple[int, ...]) -> np.ndarray | None:
        """:meth:`array`, or ``None`` when the entry leaves the key (default ``None``) out."""
        return None if self.value(key) is None else self.array(key, shape)

    def frames(self, key: str) -> list[str]:
        """Frame name(s) of the robot (one string or a non-empty list)."""
        value = self.value(key)
        names = value if isinstance(value, list | tuple) else [value]
        if not names:
            raise self.error(key, "must list at least one frame, got []")
        for name in names:
            if not isinstance(name, str):
                raise self.error(key, f"must be frame names, got {value!r}")
            try:
                self.robot.frame_id(name)
            except UnknownFrame as exc:
                raise self.error(key, str(exc)) from None
        return list(names)

    def frame(self, key: str = "frame") -> str:
        """One frame name of the robot; a key left at default ``None``: the robot's end-effector frame."""
        value = self.value(key)
        if value is None:
            return self.robot.ee_frame
        if not isinstance(value, str):
            raise self.error(key, f"must be one frame name, got {value!r}")
        return self.frames(key)[0]

    def name_for(self, count: int, single: str) -> str | None:
        """The optional ``name`` of an entry that builds ``count`` tasks; only one task may be named."""
        name = self.optional_text("name")
        if name is not None and count > 1:
            raise self.error("name", f"needs a single '{single}'")
        return name

    def one_or_many(self, single: str, many: str) -> str:
        """Which of two alternative keys (``joint`` / ``joints``) the entry gives; exactly one must be."""
        if self.given(single) == self.given(many):
            both = "both" if self.given(single) else "neither"
            raise TaskDefinitionError(
                f"{self.where}: task type {self.type.name} needs '{single}' or '{many}' (got {both})"
            )
        return single if self.given(single) else many

    @contextmanager
    def about(self, *keys: str) -> Iterator[None]:
        """Name ``keys`` in a :class:`TaskDefinitionError` raised by a task constructor in the block."""
        try:
            yield
        except TaskDefinitionError as exc:
            at = f"{self.where}.{keys[0]}" if len(keys) == 1 else f"{self.where} ({', '.join(keys)})"
            raise TaskDefinitionError(f"{at}: {exc}") from None

    def _declared(self, key: str) -> TaskKey:
        try:
            return self._keys[key]
        except KeyError:
            raise TaskDefinitionError(f"task type {self.type.name}: builder reads undeclared key '{key}'") from None


def build_tasks(description: Mapping[str, Any], robot: Robot, where: str = "task") -> list[Task]:
    """Build the task(s) one description entry stands for.

    Args:
        description: ``{"type": <registered name>, <key>: <value>, ...}``.
        robot: The robot.
        where: Location of the entry, the start of every error message.

    Raises:
        TaskDefinitionError: Unknown type, missing or unknown key, invalid value; the message
            starts with ``where`` and names the key.
    """
    data = dict(description)
    kind = data.pop("type", None)
    if not isinstance(kind, str) or kind not in _REGISTRY:
        raise TaskDefinitionError(f"{where}: unknown task type {kind!r}; known: {', '.join(_REGISTRY)}")
    spec = TaskSpec(_REGISTRY[kind], data, robot, where)
    try:
        tasks = list(spec.type.builder(spec, robot))
    except (TaskDefinitionError, RobotError) as exc:
        if str(exc).startswith(where):
            raise
        raise TaskDefinitionError(f"{where}: {exc}") from None
    if not tasks:
        raise TaskDefinitionError(f"{where}: task type {kind} built no task")
    return tasks


__all__ = [
    "FRAME_KEY",
    "GAIN_KEY",
    "GROUP_KEY",
    "NAME_KEY",
    "REQUIRED",
    "TaskBuilder",
    "TaskKey",
    "TaskSpec",
    "TaskType",
    "build_tasks",
    "frame_task_builder",
    "frame_task_keys",
    "get_task_type",
    "register_task",
    "task_types",
]
