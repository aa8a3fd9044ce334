"""States of the case-2 hierarchy on which the QP backends are judged.

A :class:`QpState` is everything a step of the cascade depends on: the configuration, the
obstacle point per control point, the EE target, one gain per level and the control period.
Two sets:

* the three deterministic case-2 states of :func:`compare.bench.solver_cases.case2_states`
  (gains of :func:`compare.bench.solver_cases.case2_description`, dt = 10 ms);
* :func:`random_states`: ``n`` states drawn from a seed — joints anywhere inside their physical
  limits (continuous joints in [−π, π]), so the EE is often past a wall's safety threshold and
  joints inside their safety bands; per control point an obstacle point with probability ½,
  0.15–0.5 m away in a random direction (often inside the 0.35 m safety distance); an EE target
  up to 0.3 m from the EE; per level a gain log-uniform in [1, 200] 1/s; dt uniform in 5–20 ms.
  Many states need slacks, and the gains and periods span what users configure.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from compare.bench.solver_cases import BenchState, apply_state, case2_states
from robots import Robot
from tpik.hierarchy import Hierarchy

RANDOM_SEED = 23
"""Seed of the bench's random-state set."""

RANDOM_COUNT = 200
"""Size of the bench's random-state set."""

CASE2_DT = 0.01
"""Control period of the deterministic case-2 states [s]."""


@dataclass(frozen=True)
class QpState:
    """One state of the case-2 hierarchy with its gains and period.

    Attributes:
        bench: Configuration, obstacle points, target (:class:`BenchState`).
        gains: Gain of every task of each level, by level name [1/s]; a level not listed keeps
            the hierarchy's gain.
        dt: Control period [s].
    """

    bench: BenchState
    gains: Mapping[str, float]
    dt: float

    @property
    def name(self) -> str:
        """State name (``case2-active3``, ``random-0042``, ...)."""
        return self.bench.name

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (floats round-trip)."""
        b = self.bench
        return {
            "name": b.name,
            "q": b.q.tolist(),
            "obstacles": {k: (None if v is None else np.asarray(v).tolist()) for k, v in b.obstacles.items()},
            "target": b.target.tolist(),
            "gains": dict(self.gains),
            "dt": self.dt,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> QpState:
        """Inverse of :meth:`to_dict`."""
        obstacles = {k: (None if v is None else np.array(v, dtype=float)) for k, v in data["obstacles"].items()}
        bench = BenchState(str(data["name"]), np.array(data["q"], dtype=float), obstacles, np.array(data["target"]))
        return cls(bench, {str(k): float(v) for k, v in data["gains"].items()}, float(data["dt"]))


def apply_qp_state(hierarchy: Hierarchy, state: QpState) -> None:
    """Set obstacle points, target and the per-level gains of ``state`` on the hierarchy's tasks."""
    apply_state(hierarchy, state.bench)
    for level in hierarchy.levels:
        gain = state.gains.get(level.name)
        if gain is not None:
            for task in level.tasks:
                task.gain = float(gain)


def case2_qp_states(robot: Robot) -> list[QpState]:
    """The three deterministic case-2 states (``case2-active0/1/3``) at dt = 10 ms, config gains."""
    return [QpState(s, {}, CASE2_DT) for s in case2_states(robot)]


def random_states(robot: Robot, n: int = RANDOM_COUNT, seed: int = RANDOM_SEED) -> list[QpState]:
    """``n`` random states of the case-2 hierarchy (module docstring), reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower, -np.pi)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper, np.pi)
    levels = ("joint_limits", "walls", "obstacles", "operational")
    states = []
    for i in range(n):
        q = rng.uniform(lo, hi)
        kin = robot.kinematics(q)
        obstacles: dict[str, np.ndarray | None] = {}
        for frame in robot.control_points:
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            distance = rng.uniform(0.15, 0.5)
            near = rng.uniform() < 0.5
            obstacles[frame] = kin.frame_position(frame) + distance * direction if near else None
        offset = rng.normal(size=3)
        offset *= rng.uniform(0.0, 0.3) / np.linalg.norm(offset)
        target = kin.frame_position(robot.ee_frame) + offset
        gains = {name: float(np.exp(rng.uniform(0.0, np.log(200.0)))) for name in levels}
        dt = float(rng.uniform(0.005, 0.02))
        states.append(QpState(BenchState(f"random-{i:04d}", q, obstacles, target), gains, dt))
    return states
