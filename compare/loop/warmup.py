"""Process warm-up: compiled kernels loaded and caches built before the first timed step.

A fresh process (a sweep worker, a ``run``) pays on its first calls of each code path for lazy
imports, for loading the compiled (numba) kernels from their cache and for building lookup
caches: milliseconds that, on a timed step, would land in the solve-time percentiles and could
count as deadline misses. :func:`warm_up_process` pays them once per process and method (the
loop's own compiled σ, :class:`~compare.loop.set_task_watch.SetTaskWatch`, included), on a
*throwaway* solver and hierarchy, at states where the set-based tasks are inactive, in their
activation band and past their safety threshold (an obstacle placed at each control point's
distance of interest), so that the branches a run takes later (mode search, active levels) are
warm as well. The run's own solver is untouched: its state, and so every step it computes, is
the same as without this warm-up. The run then still makes
:data:`~compare.loop.closed_loop.WARMUP_SOLVES` untimed solves of its own
(:func:`~compare.loop.closed_loop.warm_up_solver`, ``warmup_steps`` in ``summary.json``).

After a warm-up everything alive is moved out of the cyclic garbage collector's generations
(``gc.freeze``): it lives as long as the process, and a full collection no longer scans it
(~0.1 s of CPU each time with numba, MuJoCo and pandas loaded, landing on some run's steps).
"""

from __future__ import annotations

import gc

import numpy as np

from compare.config import Config
from compare.loop.closed_loop import SOLVER_ERRORS, WARMUP_SOLVES, ee_position_tasks
from compare.loop.set_task_watch import SetTaskWatch
from compare.methods import make_method
from robots import Robot
from tpik.tasks import ObstacleDistanceTask

_WARM: set[tuple[str, str]] = set()
"""(robot, method) pairs already warmed up in this process."""


def warm_up_process(config: Config, method: str, robot: Robot, q0: np.ndarray) -> int:
    """Warm ``method`` up on a throwaway copy once per process (module docstring).

    Args:
        config: The run's configuration (hierarchy, method settings, control period).
        method: Method name.
        robot: The arm.
        q0: Start configuration [rad].

    Returns:
        The number of throwaway solves made (0 when this process was already warm for it).
    """
    key = (robot.name, method)
    if key in _WARM:
        return 0
    _WARM.add(key)
    hierarchy = config.build_hierarchy(robot)
    solver = make_method(method, robot, config.methods.settings.get(method))
    dt = config.scenario.dt
    kin = robot.kinematics(q0)
    for position in ee_position_tasks(hierarchy, robot):
        position.set_target(kin.frame_position(robot.ee_frame) + np.array([0.05, 0.0, -0.05]))
    obstacles = [t for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)]
    frames = {t.frame: kin.frame_position(t.frame) for t in obstacles}
    done = 0
    # Inactive, in the activation band, past the safety threshold (a fraction of it, beyond it).
    for fraction in (None, 1.05, 0.8):
        for task in obstacles:
            if fraction is None:
                task.set_obstacle(None)
            else:
                lo = task.thresholds.safety_lower
                task.set_obstacle(frames[task.frame] + np.array([0.0, 0.0, fraction * lo]))
        for _ in range(WARMUP_SOLVES):
            try:
                solver.solve(hierarchy, robot.kinematics(q0), dt)
            except SOLVER_ERRORS:
                break
            done += 1
    SetTaskWatch(hierarchy.set_tasks).measure(robot.kinematics(q0))  # the loop's compiled σ, loaded now
    solver.close()
    del solver, hierarchy, obstacles  # the throwaway copy goes before the freeze below
    # What is alive now (modules, models, kernels, caches) lives as long as the process: out of the
    # collector's generations, a full collection need not scan it again (~0.1 s each time otherwise).
    gc.freeze()
    return done
