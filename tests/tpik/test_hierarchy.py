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


AT = r"^levels\[0\]\.tasks\[0\]"  # the location every message starts with


def _one(task: dict) -> list[dict]:
    return [{"name": "a", "tasks": [task]}]


@pytest.mark.parametrize(
    ("levels", "match"),
    [
        (_one({"type": "teleport"}), AT + r": unknown task type 'teleport'; known: joint_limit, "),
        (_one({"type": "joint_limit", "joints": [2], "margin": 1}), AT + r": unknown key 'margin'"),
        (
            _one({"type": "joint_limit", "joints": [9]}),
            AT + r"\.joints: joint must be in 1\.\.7, got 9",
        ),
        (_one({"type": "joint_limit", "joints": []}), AT + r"\.joints: must list at least one"),
        (_one({"type": "joint_limit"}), AT + r": task type joint_limit needs 'joint' or 'joints'"),
        (_one({"type": "joint_limit", "joint": 2, "joints": [4]}), r"needs 'joint' or 'joints' \(got both\)"),
        (
            _one({"type": "joint_limit", "joints": [2], "gain": "fast"}),
            AT + r"\.gain: must be a finite",
        ),
        (_one({"type": "position", "frame": "elbow"}), AT + r"\.frame: unknown frame 'elbow'"),
        (
            _one({"type": "wall_box", "frame": "elbow", "lower": [0, 0, 0], "upper": [1, 1, 1]}),
            r"\.frame: unknown frame",
        ),
        (_one({"type": "obstacle_distance", "frames": ["link_4", "elbow"]}), r"\.frames: unknown frame 'elbow'"),
        (_one({"type": "wall_box", "lower": [0, 0, 1], "upper": [1, 1, 0]}), r"\.lower: lower z=1 must be < upper z=0"),
        (
            _one({"type": "wall_box", "lower": [0, 0], "upper": [1, 1, 1]}),
            r"\.lower: must be finite numbers of shape \[3\]",
        ),
        (
            _one({"type": "obstacle_distance", "frames": ["link_4"], "safety_distance": 0.05}),
            AT + r"\.safety_distance: must be > physical_distance=0\.1 m, got 0\.05",
        ),
        (
            _one({"type": "joint_limit", "joints": [2], "activation_margin": 3.0}),
            AT + r" \(safety_margin, activation_margin\): task 'joint_limit_2': thresholds out",
        ),
        (_one({"type": "orientation", "target": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}), r"\.target: .*not a rotation"),
        (_one({"type": "wall_box"}), AT + r": task type wall_box needs key 'lower'"),
        (
            _one({"type": "virtual_wall", "name": "w", "normal": [0, 0, 0], "offset": 0.1}),
            r"\.normal: must be non-zero",
        ),
        (_one({"type": "joint_limit", "joints": [2], "group": "Joint Limits"}), r"group must be lower-case"),
        ([{"name": "a", "priority": 2, "tasks": []}], r"^levels\[0\]: unknown key 'priority'"),
        ([{"name": "a", "tasks": []}], r"^levels\[0\]: level 'a' holds no task"),
        ([{"name": "a", "tasks": ["position"]}], AT + r": must be a table"),
    ],
)
def test_bad_descriptions_name_the_location_and_the_key(jaco, levels, match):
    with pytest.raises(TaskDefinitionError, match=match) as info:
        Hierarchy.from_description(levels, jaco)
    assert "\n" not in str(info.value)


def test_empty_hierarchy_and_empty_level_rejected(jaco):
    with pytest.raises(EmptyHierarchy):
        Hierarchy([])
    with pytest.raises(EmptyHierarchy, match="level 'x'"):
        Level("x", ())


def test_duplicate_task_names_rejected_with_both_locations(jaco):
    with pytest.raises(
        TaskDefinitionError, match=r"^levels\[0\]\.tasks\[1\]: duplicate task name .* \(also levels\[0\]\.tasks\[0\]\)"
    ):
        Hierarchy.from_description([{"name": "a", "tasks": [{"type": "position"}, {"type": "position"}]}], jaco)


def test_set_tasks_carry_their_metrics_group(jaco):
    h = Hierarchy.from_description(CASE2, jaco)
    assert {t.group for t in h.levels[0].tasks} == {"joint_limits"}
    assert {t.group for t in h.levels[1].tasks} == {"walls"}
    assert {t.group for t in h.levels[2].tasks} == {"obstacles"}
    elbow = [
        {
            "name": "e",
            "tasks": [
                {
                    "type": "virtual_wall",
                    "name": "elbow",
                    "frame": "link_4",
                    "normal": [0, 0, 1],
                    "offset": 0.4,
                    "group": "elbow_height",
                }
            ],
        }
    ]
    (task,) = Hierarchy.from_description(elbow, jaco).tasks
    assert task.group == "elbow_height"
