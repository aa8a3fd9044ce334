"""Reference joint velocities of every method on random case-2 states.

``python -m tests.regression.make_velocity_reference`` draws :data:`COUNT` states from
:data:`SEED` (:func:`random_states`), runs each method of :data:`METHODS` once per state on the
case-2 hierarchy of ``configs/case2.toml`` and writes ``data/velocity_reference.npz`` (float64):

* ``q`` (N, n) [rad], ``obstacles`` (N, c, 3) [m] (NaN: no obstacle in range for that control
  point), ``target`` (N, 3) [m], ``dt`` (N,) [s]: the states;
* ``active`` (N,): number of set tasks of the hierarchy past an activation threshold (candidates);
* ``qdot_<method>`` (N, n) [rad/s]: the velocity each method returned, the states solved in
  chunks of :data:`CHUNK` with the history cleared at each chunk (:func:`velocities`).

Regenerate only when a change of the velocities is intended (and say so in the commit): the
test :mod:`tests.regression.test_velocity_regression` holds every later change of the code to
these velocities within 1e-9 rad/s.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

import robots
from compare.bench.solver_cases import BenchState, active_set_tasks, apply_state
from compare.config import load_config
from tpik.hierarchy import Hierarchy
from tpik.step_result import IkSolver

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "case2.toml"
DATA = Path(__file__).resolve().parent / "data" / "velocity_reference.npz"
METHODS = ("tpik", "tpik-paper", "hqp-daqp", "hqp-quadprog", "mink", "mink-hard")
SEED = 21
COUNT = 4000
CHUNK = 8
"""States solved in sequence before the history is cleared (:func:`velocities`)."""


def case2_setup() -> tuple[robots.Robot, Callable[[], Hierarchy], dict[str, dict[str, object]], np.ndarray]:
    """Robot, a factory of fresh case-2 hierarchies, method settings and start q of ``configs/case2.toml``."""
    config, _ = load_config(CONFIG)
    robot = config.load_robot()
    settings = {k: dict(v) for k, v in config.methods.settings.items()}
    start = np.array(config.scenario.start_q if config.scenario.start_q is not None else robot.home, dtype=float)
    return robot, lambda: config.build_hierarchy(robot), settings, start


def random_states(
    robot: robots.Robot, hierarchy: Hierarchy, start: np.ndarray, n: int = COUNT, seed: int = SEED
) -> list[BenchState]:
    """``n`` states around the case-2 thresholds, reproducible from ``seed``.

    Two kinds, alternately drawn with probability ½:

    * *near the start*: q = ``start`` + N(0, 0.35² rad²) per joint (the EE mostly inside the wall
      box, joints mid-range), obstacle point per control point with probability 0.3, 0.25–0.6 m
      away in a random direction: mostly 0–3 candidate set tasks;
    * *near the limits*: joints uniform inside the physical limits (continuous joints in
      [−π, π]); each joint limit of the hierarchy with probability ½ placed 0–0.25 rad inside
      its limit (or up to 0.02 rad past it), in or near its safety and activation bands; an
      obstacle point per control point with probability 0.6, 0.1–0.5 m away (0.35 m safety
      distance, 0.05 m band): mostly 3–7 candidates, the EE often past a wall.

    EE target up to 0.3 m from the EE.
    """
    from tpik.tasks import JointLimitTask, ObstacleDistanceTask

    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower, -np.pi)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper, np.pi)
    limited = sorted({t.joint - 1 for t in hierarchy.tasks if isinstance(t, JointLimitTask)})
    frames = list(dict.fromkeys(t.frame for t in hierarchy.tasks if isinstance(t, ObstacleDistanceTask)))
    states = []
    for i in range(n):
        if rng.uniform() < 0.5:
            q = np.clip(start + rng.normal(0.0, 0.35, size=robot.nq), lo, hi)
            p_near, d_lo, d_hi = 0.3, 0.25, 0.6
        else:
            q = rng.uniform(lo, hi)
            for j in limited:
                if rng.uniform() < 0.5:
                    inside = rng.uniform(-0.02, 0.25)
                    q[j] = lo[j] + inside if rng.uniform() < 0.5 else hi[j] - inside
            p_near, d_lo, d_hi = 0.6, 0.1, 0.5
        kin = robot.kinematics(q)
        obstacles: dict[str, np.ndarray | None] = {}
        for frame in frames:
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            near = rng.uniform() < p_near
            distance = rng.uniform(d_lo, d_hi)
            obstacles[frame] = kin.frame_position(frame) + distance * direction if near else None
        offset = rng.normal(size=3)
        offset *= rng.uniform(0.0, 0.3) / np.linalg.norm(offset)
        target = kin.frame_position(robot.ee_frame) + offset
        states.append(BenchState(f"regression-{i:04d}", q, obstacles, target))
    return states


def velocities(
    robot: robots.Robot,
    solver: IkSolver,
    hierarchies: tuple[Hierarchy, Hierarchy],
    states: Sequence[BenchState],
    dts: np.ndarray,
    indices: Sequence[int] | np.ndarray,
) -> np.ndarray:
    """q̇ [rad/s] of ``solver`` at ``states[i]`` for ``i`` in ``indices`` (one step each, fresh kinematics).

    Some methods carry history from step to step (HQP sends a level to its backend when that
    level needed it at the previous step), so a state's velocity depends on the states solved
    before it. The states are therefore solved in chunks of :data:`CHUNK` consecutive states,
    the history cleared at each chunk start by switching between the two hierarchy objects (a
    solver rebuilds its per-hierarchy state for a new object): a chunk's velocities do not
    depend on the other chunks, so any set of whole chunks can be checked on its own.

    Returns:
        Shape (len(indices), n).
    """
    out = np.empty((len(indices), robot.nq))
    previous = -2
    hierarchy = hierarchies[1]
    for row, i in enumerate(indices):
        if i % CHUNK == 0 or i != previous + 1:  # a new chunk: fresh history (the other object)
            hierarchy = hierarchies[0] if hierarchy is hierarchies[1] else hierarchies[1]
            if i % CHUNK != 0:
                raise ValueError(f"state {i} does not follow state {previous}: indices must be whole chunks")
        previous = int(i)
        apply_state(hierarchy, states[i])
        out[row] = solver.solve(hierarchy, robot.kinematics(states[i].q), float(dts[i])).qdot
    return out


def build(methods: Sequence[str] = METHODS, n: int = COUNT, seed: int = SEED) -> dict[str, np.ndarray]:
    """The arrays of the reference file (module docstring)."""
    from compare.methods import make_method

    robot, make_hierarchy, settings, start = case2_setup()
    probe = make_hierarchy()
    states = random_states(robot, probe, start, n, seed)
    dts = np.random.default_rng(seed + 1).uniform(0.005, 0.02, size=n)
    frames = list(states[0].obstacles)
    obstacles = np.full((n, len(frames), 3), np.nan)
    for i, s in enumerate(states):
        for c, frame in enumerate(frames):
            if s.obstacles[frame] is not None:
                obstacles[i, c] = s.obstacles[frame]
    active = np.empty(n)
    for i, s in enumerate(states):
        apply_state(probe, s)
        active[i] = len(active_set_tasks(probe, robot, s.q))
    data = {
        "q": np.array([s.q for s in states]),
        "obstacles": obstacles,
        "target": np.array([s.target for s in states]),
        "dt": dts,
        "active": active,
    }
    for name in methods:
        solver = make_method(name, robot, settings.get(name))
        data[f"qdot_{name}"] = velocities(robot, solver, (make_hierarchy(), make_hierarchy()), states, dts, range(n))
    return data


def load_states(data: dict[str, np.ndarray] | np.lib.npyio.NpzFile, frames: Sequence[str]) -> list[BenchState]:
    """The states stored in a reference file (obstacles by control point in ``frames`` order)."""
    states = []
    for i in range(len(data["dt"])):
        obstacles = {
            f: (None if np.isnan(data["obstacles"][i, c, 0]) else np.array(data["obstacles"][i, c]))
            for c, f in enumerate(frames)
        }
        states.append(BenchState(f"regression-{i:04d}", np.array(data["q"][i]), obstacles, np.array(data["target"][i])))
    return states


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=COUNT)
    parser.add_argument("--out", type=Path, default=DATA)
    args = parser.parse_args(argv)
    data = build(n=args.count)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **data)
    counts = np.bincount(data["active"].astype(int))
    print(f"wrote {args.out}: {args.count} states; states by number of candidate set tasks: {counts.tolist()}")


if __name__ == "__main__":
    main()
