"""Shared pieces of the qp_baseline tests: the Siciliano–Slotine reference, scenarios, rollouts."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from qp_baseline.hqp import available_qp_solvers
from robots import Robot
from tpik.hierarchy import Hierarchy, Level
from tpik.step_result import IkSolver, SolveStatus
from tpik.tasks import (
    JointLimitTask,
    ObstacleDistanceTask,
    PositionTask,
    SetTask,
    Task,
    Thresholds,
    VirtualWallTask,
)

SOLVERS = available_qp_solvers()
DT = 0.01


def ss_reference(levels: Sequence[tuple[np.ndarray, np.ndarray]], n: int, rcond: float = 1e-10) -> np.ndarray:
    """Siciliano–Slotine: q̇_k = q̇_{k−1} + (J_k N_{k−1})† (r_k − J_k q̇_{k−1}).

    With N_k = N_{k−1} − (J_k N_{k−1})† J_k N_{k−1} (N_0 = I).

    Undamped, with exact projectors: equal to the lexicographic least-squares solution of minimum
    norm, which the HQP cascade returns up to its regularisation ε (O(ε/σ_min²)).
    """
    qdot = np.zeros(n)
    N = np.eye(n)
    for J, r in levels:
        JN = J @ N
        JN_pinv = np.linalg.pinv(JN, rcond=rcond)
        qdot = qdot + JN_pinv @ (r - J @ qdot)
        N = N - JN_pinv @ JN
    return qdot


def reference_rows(hierarchy: Hierarchy, kin: object) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per level, the stacked equality Jacobian and CLIK reference r = σ̇_d + K σ̃."""
    rows = []
    for level in hierarchy.levels:
        Js, rs = [], []
        for task in level.tasks:
            state = task.compute_state(kin)  # type: ignore[arg-type]
            Js.append(state.jacobian)
            rs.append(state.feedforward + task.gain * state.error)
        rows.append((np.vstack(Js), np.concatenate(rs)))
    return rows


def smallest_level_singular_value(rows: Sequence[tuple[np.ndarray, np.ndarray]], n: int) -> float:
    """min over levels of the smallest nonzero singular value of J_k N_{k−1} (conditioning of the reference)."""
    N = np.eye(n)
    worst = math.inf
    for J, _ in rows:
        JN = J @ N
        s = np.linalg.svd(JN, compute_uv=False)
        nonzero = s[s > 1e-9]
        worst = min(worst, float(nonzero.min()) if nonzero.size else 0.0)
        N = N - np.linalg.pinv(JN, rcond=1e-10) @ JN
    return worst


def margins(hierarchy: Hierarchy, robot: Robot, q: np.ndarray) -> dict[str, float]:
    """Signed safety margin of every set task with a finite σ at ``q`` (> 0 inside)."""
    kin = robot.kinematics(q)
    out = {}
    for task in hierarchy.set_tasks:
        sigma = float(task.compute_state(kin).value[0])
        if math.isfinite(sigma):
            out[task.name] = task.margins(sigma)[0]
    return out


@dataclass
class Rollout:
    """What a closed-loop kinematic run saw."""

    q: np.ndarray
    worst_margin: dict[str, float] = field(default_factory=dict)
    statuses: list[SolveStatus] = field(default_factory=list)
    max_speed_ratio: float = 0.0
    retries: int = 0


def rollout(
    solver: IkSolver,
    hierarchy: Hierarchy,
    robot: Robot,
    q0: np.ndarray,
    steps: int,
    dt: float = DT,
    before_step: Callable[[int, np.ndarray], None] | None = None,
) -> Rollout:
    """Closed-loop kinematic integration q ← q + q̇ dt, recording the worst safety margins."""
    q = np.array(q0, dtype=float)
    out = Rollout(q)
    for step in range(steps):
        if before_step is not None:
            before_step(step, q)
        result = solver.solve(hierarchy, robot.kinematics(q), dt)
        assert np.all(np.isfinite(result.qdot)), result.message
        out.statuses.append(result.status)
        out.retries += int(result.extras.get("retries", 0) or 0)
        out.max_speed_ratio = max(out.max_speed_ratio, float(np.max(np.abs(result.qdot) / robot.v_max)))
        q = q + result.qdot * dt
        for name, margin in margins(hierarchy, robot, q).items():
            out.worst_margin[name] = min(out.worst_margin.get(name, math.inf), margin)
    out.q = q
    return out


def wall_box_level(frame: str = "end_effector", gain: float = 1.0) -> Level:
    """The paper's case-2 walls: x, y ∈ [−0.5, 0.5] m, z ∈ [0.2, 0.9] m, on ``frame``."""
    th = Thresholds(-0.05, 0.0, math.inf, math.inf, 0.03)
    walls: list[Task] = []
    for axis, (lo, hi) in enumerate(((-0.5, 0.5), (-0.5, 0.5), (0.2, 0.9))):
        n = np.zeros(3)
        n[axis] = 1.0
        walls.append(VirtualWallTask(f"wall_{'xyz'[axis]}_min", frame, n, lo, th, gain))
        walls.append(VirtualWallTask(f"wall_{'xyz'[axis]}_max", frame, -n, -hi, th, gain))
    return Level("walls", tuple(walls))


def wall_behind_ee(ee: np.ndarray, past_m: float, gain: float) -> VirtualWallTask:
    """A wall x ≥ ee_x + ``past_m`` on the EE: the EE starts ``past_m`` past its safety threshold."""
    th = Thresholds(-0.05, 0.0, math.inf, math.inf, 0.03)
    return VirtualWallTask("wall", "end_effector", np.array([1.0, 0.0, 0.0]), float(ee[0]) + past_m, th, gain)


def joint_limit_level(robot: Robot, joints: Sequence[int] = (2, 4, 6), gain: float = 1.0) -> Level:
    """Joint limits of the model with a 0.1 rad safety margin and ε = 0.05 rad."""
    return Level("joint_limits", tuple(JointLimitTask.from_robot(robot, j, 0.1, 0.05, gain) for j in joints))


def obstacle_level(frames: Sequence[str] = ("link_4", "link_6", "link_7"), gain: float = 1.0) -> Level:
    """Obstacle distance of control points: physical 0.1 m, safety 0.35 m, ε = 0.05 m."""
    th = Thresholds(0.1, 0.35, math.inf, math.inf, 0.05)
    return Level("obstacles", tuple(ObstacleDistanceTask(f"obstacle_{f}", f, th, gain) for f in frames))


def position_level(target: np.ndarray, gain: float = 1.0, frame: str = "end_effector") -> Level:
    """EE position task at ``target`` [m]."""
    return Level("operational", (PositionTask(f"position_{frame}", frame, gain, target),))


def set_task(hierarchy: Hierarchy, name: str) -> SetTask:
    """A set task of the hierarchy by name."""
    task = hierarchy.task(name)
    assert isinstance(task, SetTask)
    return task
