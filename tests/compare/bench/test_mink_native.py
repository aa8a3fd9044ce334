"""mink-native (the reference of every "× mink" ratio) poses the same QP as the project's mink peer."""

from __future__ import annotations

import mink
import numpy as np
import pytest

from compare.bench.mink_native import MinkCase2
from compare.bench.solver_cases import BenchState, apply_state, case2_hierarchy, case2_states
from compare.bench.solvers import native_for
from qp_baseline.mink_peer import MinkSolver

DT = 0.01


@pytest.fixture(scope="module")
def native(jaco) -> MinkCase2:
    return native_for(jaco, case2_hierarchy(jaco))  # the case-2 thresholds and gains, mink alone from here


def _problems(jaco, native: MinkCase2, peer: MinkSolver, state: BenchState):
    hierarchy = case2_hierarchy(jaco)
    apply_state(hierarchy, state)
    result = peer.solve(hierarchy, jaco.kinematics(state.q), DT)
    ours = mink.build_ik(peer.configuration, peer._tasks, DT, peer.settings.damping, peer._limits)
    native.set_scene([state.obstacles.get(cp) for cp in jaco.control_points], state.target)
    qdot = native.step(state.q, DT)
    theirs = mink.build_ik(native.configuration, native.tasks, DT, 1e-12, native.limits)
    return ours, theirs, result, qdot


def _rows(problem) -> np.ndarray:
    """Constraint rows [G | h] in a canonical order (mink stacks them limit by limit)."""
    rows = np.column_stack([problem.G, problem.h])
    rows = rows[np.isfinite(rows).all(axis=1)]
    return rows[np.lexsort(np.round(rows, 12).T[::-1])]


def test_the_bench_states_give_the_peers_step(jaco, native):
    peer = MinkSolver(jaco)
    for state in case2_states(jaco):
        _, _, result, qdot = _problems(jaco, native, peer, state)
        np.testing.assert_allclose(qdot, result.qdot, atol=1e-9)


def test_random_states_pose_the_same_qp_with_tasks_past_their_thresholds(jaco, native):
    """Same cost (H, c) and the same constraint rows, also where the soft return acts."""
    rng = np.random.default_rng(0)
    peer = MinkSolver(jaco)
    lo = np.where(np.isfinite(jaco.q_lower), jaco.q_lower + 0.02, -3.0)
    hi = np.where(np.isfinite(jaco.q_upper), jaco.q_upper - 0.02, 3.0)
    returning = 0
    for _ in range(60):
        q = rng.uniform(lo, hi)
        kin = jaco.kinematics(q)
        obstacles = {}
        for cp in jaco.control_points:
            direction = rng.normal(size=3)
            if rng.random() < 0.7:
                obstacles[cp] = kin.frame_position(cp) + rng.uniform(0.2, 0.5) * direction / np.linalg.norm(direction)
        target = kin.frame_position(jaco.ee_frame) + 0.1 * rng.normal(size=3)
        ours, theirs, result, _ = _problems(jaco, native, peer, BenchState("random", q, obstacles, target))
        returning += bool(result.extras["returning"])
        np.testing.assert_allclose(ours.P, theirs.P, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(ours.q, theirs.q, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(_rows(ours), _rows(theirs), atol=1e-12)
    assert returning > 20  # the soft return is exercised
