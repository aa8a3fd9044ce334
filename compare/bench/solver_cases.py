"""The solver benchmark cases: the paper's case-2 hierarchy at states with 0, 1 and 3 active set tasks.

The hierarchy is a config's (``bench --config configs/panda_case2.toml``: its robot and levels)
or :func:`case2_description` of a robot: the paper's case 2 with the robot's own frames.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from robots import Robot
from tpik.hierarchy import Hierarchy
from tpik.tasks import Activation, ObstacleDistanceTask, PositionTask


def limited_joints(robot: Robot) -> list[int]:
    """1-based joints whose range is at most one turn (the Jaco²'s 2, 4, 6; all 7 of the Panda)."""
    span = robot.q_upper - robot.q_lower
    return [j + 1 for j in range(robot.nq) if span[j] <= 2 * math.pi + 1e-9]


def case2_description(robot: Robot) -> list[dict[str, Any]]:
    """Paper case 2 (sec. IV-C) for ``robot``, with its own frames and limited joints.

    Limits of its :func:`limited_joints` > six walls on the EE > obstacle distance of its control
    points > EE position (for the Jaco²: joints 2, 4, 6 and its three control points, as in the paper).
    """
    return [
        {
            "name": "joint_limits",
            "tasks": [
                {
                    "type": "joint_limit",
                    "joints": limited_joints(robot),
                    "safety_margin": 0.1,
                    "activation_margin": 0.05,
                }
            ],
        },
        {
            "name": "walls",
            "tasks": [
                {
                    "type": "wall_box",
                    "frame": robot.ee_frame,
                    "lower": [-0.5, -0.5, 0.2],
                    "upper": [0.5, 0.5, 0.9],
                    "physical_margin": 0.05,
                    "activation_margin": 0.03,
                }
            ],
        },
        {
            "name": "obstacles",
            "tasks": [
                {
                    "type": "obstacle_distance",
                    "frames": list(robot.control_points),
                    "safety_distance": 0.35,
                    "physical_distance": 0.1,
                    "activation_margin": 0.05,
                }
            ],
        },
        {"name": "operational", "tasks": [{"type": "position", "frame": robot.ee_frame, "gain": 1.0}]},
    ]


@dataclass(frozen=True)
class BenchState:
    """A robot state of a case: configuration, obstacle point per control point, EE target."""

    name: str
    q: np.ndarray
    obstacles: dict[str, np.ndarray | None]
    target: np.ndarray


def case2_hierarchy(robot: Robot, description: Sequence[Mapping[str, Any]] | None = None) -> Hierarchy:
    """Fresh case-2 hierarchy (its obstacle points and target are set by :func:`apply_state`).

    Args:
        robot: The arm.
        description: Levels (a config's); default :func:`case2_description` of ``robot``.
    """
    return Hierarchy.from_description(description or case2_description(robot), robot)


def apply_state(hierarchy: Hierarchy, state: BenchState) -> None:
    """Set the obstacle points and the EE target of ``state`` on the hierarchy's tasks."""
    for task in hierarchy.tasks:
        if isinstance(task, ObstacleDistanceTask):
            task.set_obstacle(state.obstacles.get(task.frame))
        elif isinstance(task, PositionTask):
            task.set_target(state.target)


def active_set_tasks(hierarchy: Hierarchy, robot: Robot, q: np.ndarray) -> list[str]:
    """Names of the set tasks past an activation threshold at ``q`` (candidate set of docs/design.md §3)."""
    kin = robot.kinematics(q)
    names = []
    for task in hierarchy.set_tasks:
        if task.activation_state(task.compute_state(kin)) is not Activation.INACTIVE:
            names.append(task.name)
    return names


def _safe(hierarchy: Hierarchy, robot: Robot, q: np.ndarray) -> bool:
    """Whether every set task is strictly inside its safety thresholds at ``q``."""
    kin = robot.kinematics(q)
    for task in hierarchy.set_tasks:
        sigma = float(task.compute_state(kin).value[0])
        if np.isfinite(sigma) and task.margins(sigma)[0] <= 0.0:
            return False
    return True


def case2_states(
    robot: Robot, seed: int = 0, description: Sequence[Mapping[str, Any]] | None = None
) -> list[BenchState]:
    """Deterministic states of the case-2 hierarchy with exactly 0, 1 and 3 active set tasks.

    * ``case2-active0``: EE well inside the box, joints mid-range, no obstacle in range.
    * ``case2-active1``: EE within the activation band of one wall.
    * ``case2-active3``: one wall active and obstacles 0.37 m from the last two control points
      (wrist and hand; inside their 0.35 + 0.05 m activation band).

    Found by a seeded random search over the joint ranges, so every run times the same states.
    """
    rng = np.random.default_rng(seed)
    hierarchy = case2_hierarchy(robot, description)
    cps = tuple(dict.fromkeys(t.frame for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)))
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower + 0.3, -np.pi)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper - 0.3, np.pi)
    apply_state(hierarchy, BenchState("none", robot.home, {}, np.zeros(3)))
    found: dict[int, np.ndarray] = {}
    for _ in range(20000):
        q = rng.uniform(lo, hi)
        if not _safe(hierarchy, robot, q):
            continue
        active = active_set_tasks(hierarchy, robot, q)
        n_walls = sum(name.startswith("wall_") for name in active)
        if len(active) == 0 and 0 not in found:
            found[0] = q
        elif len(active) == 1 and n_walls == 1 and 1 not in found:
            found[1] = q
        if len(found) == 2:
            break
    if len(found) < 2:
        raise RuntimeError("could not find the case-2 benchmark states; widen the search")
    states = []
    for k, q in ((0, found[0]), (1, found[1]), (3, found[1])):
        kin = robot.kinematics(q)
        ee = kin.frame_position(robot.ee_frame)
        obstacles: dict[str, np.ndarray | None] = dict.fromkeys(cps)
        if k == 3:
            # Obstacle points off to the side of the wrist and hand, 0.37 m away.
            for frame in cps[-2:]:
                p = kin.frame_position(frame)
                obstacles[frame] = p + 0.37 * np.array([0.0, 0.6, 0.8])
        target = ee + np.array([0.05, -0.05, 0.05])
        state = BenchState(f"case2-active{k}", q, obstacles, target)
        apply_state(hierarchy, state)
        got = active_set_tasks(hierarchy, robot, q)
        if len(got) != k:
            raise RuntimeError(f"{state.name}: expected {k} active set tasks, got {got}")
        states.append(state)
    return states
