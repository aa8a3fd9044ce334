"""Building a hierarchy from the plain description the config produces."""

from __future__ import annotations

import pytest

from tpik.exceptions import EmptyHierarchy, TaskDefinitionError
from tpik.hierarchy import Hierarchy, Level
from tpik.tasks import JointLimitTask, ObstacleDistanceTask, PositionTask, VirtualWallTask

CASE2 = [
    {"name": "joint_limits", "tasks": [{"type": "joint_limit", "joints": [2, 4, 6]}]},
    {"name": "walls", "tasks": [{"type": "wall_box", "lower": [-0.5, -0.5, 0.2], "upper": [0.5, 0.5, 0.9]}]},
    {"name": "obstacles", "tasks": [{"type": "obstacle_distance", "frames": ["link_4", "link_6", "link_7"]}]},
    {"name": "operational", "tasks": [{"type": "position", "frame": "end_effector"}]},
]


def test_case2_description_builds_paper_hierarchy(jaco):
    h = Hierarchy.from_description(CASE2, jaco)
    assert [lv.name for lv in h] == ["joint_limits", "walls", "obstacles", "operational"]
    assert [type(t) for t in h.levels[0].tasks] == [JointLimitTask] * 3
    assert [t.joint for t in h.levels[0].tasks] == [2, 4, 6]
    assert len(h.levels[1].tasks) == 6 and all(isinstance(t, VirtualWallTask) for t in h.levels[1].tasks)
    assert [t.frame for t in h.levels[2].tasks] == ["link_4", "link_6", "link_7"]
    assert all(isinstance(t, ObstacleDistanceTask) for t in h.levels[2].tasks)
    assert isinstance(h.task("position_end_effector"), PositionTask)
    assert len(h.set_tasks) == 12


def test_wall_box_walls_bound_the_box(jaco):
    h = Hierarchy.from_description(CASE2[1:2], jaco)
    walls = {t.name: t for t in h.tasks}
    assert walls["wall_z_min"].offset == pytest.approx(0.2)
    assert walls["wall_z_max"].offset == pytest.approx(-0.9)


@pytest.mark.parametrize(
    ("levels", "match"),
    [
        ([{"name": "a", "tasks": [{"type": "teleport"}]}], "levels\\[0\\].tasks\\[0\\]: unknown task type 'teleport'"),
        ([{"name": "a", "tasks": [{"type": "joint_limit", "joints": [2], "margin": 1}]}], "unknown key 'margin'"),
        ([{"name": "a", "tasks": [{"type": "joint_limit", "joints": [9]}]}], "joint must be in 1..7"),
        ([{"name": "a", "tasks": [{"type": "position", "frame": "elbow"}]}], "unknown frame 'elbow'"),
        ([{"name": "a", "tasks": [{"type": "wall_box", "lower": [0, 0, 1], "upper": [1, 1, 0]}]}], "lower z=1"),
        (
            [{"name": "a", "tasks": [{"type": "obstacle_distance", "frames": ["link_4"], "safety_distance": 0.05}]}],
            "physical_lower=0.1 must be < safety_lower=0.05",
        ),
        ([{"name": "a", "tasks": [{"type": "wall_box"}]}], "needs key 'lower'"),
        ([{"name": "a", "priority": 2, "tasks": []}], "unknown key 'priority'"),
    ],
)
def test_bad_descriptions_name_the_key(jaco, levels, match):
    with pytest.raises((TaskDefinitionError, Exception), match=match):
        Hierarchy.from_description(levels, jaco)


def test_empty_hierarchy_and_empty_level_rejected(jaco):
    with pytest.raises(EmptyHierarchy):
        Hierarchy([])
    with pytest.raises(EmptyHierarchy, match="level 'x'"):
        Level("x", ())


def test_duplicate_task_names_rejected(jaco):
    with pytest.raises(TaskDefinitionError, match="duplicate task name"):
        Hierarchy.from_description([{"name": "a", "tasks": [{"type": "position"}, {"type": "position"}]}], jaco)
