"""The one builder of set-task rows (HQP and both mink peers): the reference rates as G q̇ ≤ h."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.methods import make_method
from qp_baseline.set_rows import SetRowBuilder
from tests.qp_baseline.helpers import DT, joint_limit_level, obstacle_level, wall_box_level
from tpik.exceptions import InvalidTaskState
from tpik.hierarchy import Hierarchy
from tpik.reference import ControlReference
from tpik.tasks import SetTask


def _tasks(jaco, kin, rng) -> list[SetTask]:
    obstacles = obstacle_level(gain=2.0)
    for task in obstacles.tasks[:2]:
        task.set_obstacle(kin.frame_position(task.frame) + rng.uniform(0.25, 0.45) * np.array([0.0, 0.6, 0.8]))
    hierarchy = Hierarchy([joint_limit_level(jaco, gain=2.0), wall_box_level(gain=2.0), obstacles])
    return list(hierarchy.set_tasks)


@pytest.mark.parametrize("hold", [False, True])
def test_rows_are_the_velocity_bounds_of_every_task(jaco, hold):
    rng = np.random.default_rng(2)
    for _ in range(10):
        q = jaco.home + rng.uniform(-0.5, 0.5, size=jaco.nq)
        kin = jaco.kinematics(q)
        tasks = _tasks(jaco, kin, rng)
        rows = SetRowBuilder(tasks, jaco.nq, ControlReference(), hold_at_zero=hold).build(kin, DT)
        expected = []
        for i, task in enumerate(tasks):
            state = task.compute_state(kin)
            lo, hi = task.velocity_bounds(state, DT)
            J = state.jacobian[0]
            if math.isfinite(hi):
                expected.append((i, J, max(hi, 0.0) if hold else hi))
            if math.isfinite(lo):
                expected.append((i, -J, -min(lo, 0.0) if hold else -lo))
        assert rows.owner.tolist() == [e[0] for e in expected]
        np.testing.assert_allclose(rows.G, np.array([e[1] for e in expected]), atol=0.0)
        np.testing.assert_allclose(rows.h, np.array([e[2] for e in expected]), atol=0.0)
        if hold:
            assert np.all(rows.h >= 0.0)  # q̇ = 0 satisfies every row
        assert math.isinf(rows.sigma[-1])  # the third control point has no obstacle: no row


def test_hqp_and_both_mink_peers_build_their_rows_with_it(jaco):
    kin = jaco.kinematics(jaco.home)
    hierarchy = Hierarchy([joint_limit_level(jaco), wall_box_level()])
    for name, hold in (("hqp-daqp", False), ("mink", True), ("mink-hard", False)):
        solver = make_method(name, jaco)
        solver.solve(hierarchy, kin, DT)
        rows = solver._layout.rows if name.startswith("hqp-") else solver._rows
        assert isinstance(rows, SetRowBuilder) and rows.hold_at_zero is hold
        assert rows.reference is solver.reference


def test_a_non_finite_jacobian_names_the_task(jaco):
    class Broken(SetTask):
        def compute_value_and_jacobian(self, kin):
            return 0.5, np.full((1, jaco.nq), np.nan)

    from tpik.tasks import Thresholds

    task = Broken("broken", Thresholds(-1.0, 0.0, 1.0, 2.0, 0.1), 1.0)
    with pytest.raises(InvalidTaskState, match="broken"):
        SetRowBuilder([task], jaco.nq, ControlReference()).build(jaco.kinematics(jaco.home), DT)
