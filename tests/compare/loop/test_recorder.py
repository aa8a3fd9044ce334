"""The step recorder's σ and activity columns: each set task's own value at the step's snapshot."""

from __future__ import annotations

import math

import numpy as np

from compare.bench.solver_cases import apply_state, case2_hierarchy, case2_states
from compare.loop.recorder import StepRecorder
from tests.conftest import random_configuration
from tpik.hierarchy import Hierarchy
from tpik.tasks import ObstacleDistanceTask


def _recorder(hierarchy: Hierarchy, nq: int, steps: int) -> StepRecorder:
    obstacles = [t for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask)]
    return StepRecorder(steps, nq, hierarchy.set_tasks, obstacles, ())


def test_recorded_sigma_of_built_in_tasks_is_each_tasks_own_value(jaco):
    """Joint limits, six walls, obstacle distances with and without a point: the compute_value numbers."""
    hierarchy = case2_hierarchy(jaco)
    state = case2_states(jaco)[2]  # obstacle points on two of the three control points
    apply_state(hierarchy, state)
    rng = np.random.default_rng(4)
    steps = 30
    recorder = _recorder(hierarchy, jaco.nq, steps)
    names = [t.name for t in hierarchy.set_tasks]
    for i in range(steps):
        kin = jaco.kinematics(random_configuration(jaco, rng))
        active = names[i % len(names) :: 5]
        got = recorder.set_tasks(i, kin, active)
        want = [t.compute_value(kin) for t in hierarchy.set_tasks]
        assert any(math.isinf(w) for w in want)  # the control point without an obstacle point
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        for k, name in enumerate(names):
            assert recorder.cols[f"sigma:{name}"][i] == got[k]
            assert recorder.cols[f"active:{name}"][i] == (name in active)
