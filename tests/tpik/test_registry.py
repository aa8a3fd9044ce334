"""The public task registry: a new task type is one builder and one ``register_task`` call."""

from __future__ import annotations

import math

import numpy as np
import pytest

import tpik
from tpik import Hierarchy, TaskDefinitionError
from tpik.tasks import SetTask, TaskKey, Thresholds, VirtualWallTask, registry


@pytest.fixture(autouse=True)
def private_registry(monkeypatch):
    """Each test registers into a copy: the built-in types stay, nothing leaks to other tests."""
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))


class _Height(SetTask):
    default_group = "heights"

    def __init__(self, name, frame, low):
        super().__init__(name, Thresholds(low - 0.05, low, math.inf, math.inf, 0.02), 1.0)
        self.frame = frame

    def compute_value_and_jacobian(self, kin):
        return float(kin.frame_position(self.frame)[2]), kin.position_jacobian(self.frame)[2:3]


KEYS = (TaskKey("frame", "frame", "link_4"), TaskKey("low", "lowest height", unit="m"))


def _build(spec, robot):
    return [_Height(f"height_{spec.frame('frame')}", spec.frame("frame"), spec.number("low"))]


def test_a_registered_type_is_built_from_a_description_and_listed(jaco):
    tpik.register_task("height", _build, keys=KEYS, example={"low": 0.3})
    h = Hierarchy.from_description([{"name": "s", "tasks": [{"type": "height", "low": 0.3}]}], jaco)
    (task,) = h.set_tasks
    assert isinstance(task, _Height) and task.group == "heights" and task.thresholds.safety_lower == 0.3
    kin = jaco.kinematics(jaco.home)
    assert task.compute_value(kin) == pytest.approx(jaco.frame_position(jaco.home, "link_4")[2])
    assert "height" in [t.name for t in tpik.task_types()]


def test_a_name_is_registered_once_unless_replaced(jaco):
    tpik.register_task("height", _build, keys=KEYS, example={"low": 0.3})
    with pytest.raises(TaskDefinitionError, match="'height' is already registered"):
        tpik.register_task("height", _build, keys=KEYS, example={"low": 0.3})
    with pytest.raises(TaskDefinitionError, match="already registered"):
        tpik.register_task("joint_limit", _build, keys=KEYS, example={"low": 0.3})

    def walls(spec, robot):
        th = Thresholds(-0.05, 0.0, math.inf, math.inf, 0.03)
        return [VirtualWallTask("floor", "link_4", np.array([0.0, 0.0, 1.0]), spec.number("low"), th)]

    tpik.register_task("height", walls, keys=KEYS, example={"low": 0.3}, replace=True)
    h = Hierarchy.from_description([{"name": "s", "tasks": [{"type": "height", "low": 0.3}]}], jaco)
    assert isinstance(h.task("floor"), VirtualWallTask)


@pytest.mark.parametrize(
    ("name", "keys", "match"),
    [
        ("bad name", KEYS, "letters, digits"),
        ("twice", (*KEYS, TaskKey("low", "again")), "keys must be unique"),
        ("typed", (TaskKey("type", "no"),), "not 'type'"),
    ],
)
def test_bad_registrations_are_rejected(name, keys, match):
    with pytest.raises(TaskDefinitionError, match=match):
        tpik.register_task(name, _build, keys=keys, example={})


def test_unknown_keys_are_rejected_before_the_builder_runs(jaco):
    calls = []
    tpik.register_task("height", lambda spec, robot: calls.append(1) or _build(spec, robot), keys=KEYS, example={})
    with pytest.raises(TaskDefinitionError, match=r"^levels\[0\]\.tasks\[0\]: unknown key 'lo' for task type height"):
        Hierarchy.from_description([{"name": "s", "tasks": [{"type": "height", "lo": 0.3}]}], jaco)
    assert calls == []


def test_a_missing_required_key_is_named(jaco):
    tpik.register_task("height", _build, keys=KEYS, example={})
    with pytest.raises(TaskDefinitionError, match=r"^levels\[0\]\.tasks\[0\]: task type height needs key 'low'"):
        Hierarchy.from_description([{"name": "s", "tasks": [{"type": "height"}]}], jaco)


def test_a_builder_bug_is_not_reported_as_a_user_mistake(jaco):
    def buggy(spec, robot):
        return [{}["oops"]]  # a KeyError of the builder's own

    tpik.register_task("buggy", buggy, keys=(), example={})
    with pytest.raises(KeyError, match="oops"):
        Hierarchy.from_description([{"name": "s", "tasks": [{"type": "buggy"}]}], jaco)

    def undeclared(spec, robot):
        return [_Height("h", "link_4", spec.number("height"))]

    tpik.register_task("undeclared", undeclared, keys=(), example={})
    with pytest.raises(TaskDefinitionError, match="builder reads undeclared key 'height'"):
        Hierarchy.from_description([{"name": "s", "tasks": [{"type": "undeclared"}]}], jaco)


def test_errors_of_the_task_class_carry_the_location(jaco):
    tpik.register_task("height", _build, keys=KEYS, example={})
    bad = [{"name": "s", "tasks": [{"type": "height", "low": math.inf}]}]
    with pytest.raises(TaskDefinitionError, match=r"^levels\[0\]\.tasks\[0\]\.low: must be a finite number, got inf"):
        Hierarchy.from_description(bad, jaco)

    def unordered(spec, robot):
        return [SetTaskWithBadThresholds()]

    tpik.register_task("unordered", unordered, keys=(), example={})
    with pytest.raises(TaskDefinitionError, match=r"^levels\[0\]\.tasks\[0\]: task 'u': thresholds out of order"):
        Hierarchy.from_description([{"name": "s", "tasks": [{"type": "unordered"}]}], jaco)


class SetTaskWithBadThresholds(_Height):
    def __init__(self):
        SetTask.__init__(self, "u", Thresholds(0.5, 0.4, math.inf, math.inf, 0.01), 1.0)
