"""The shared compiled task evaluation equals every task's own ``compute_state`` (tpik.evaluation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robots import Kinematics
from tests.conftest import random_configuration
from tpik.evaluation import (
    EQ_ERROR,
    EQ_FEEDFORWARD,
    EQ_JAC,
    EQ_VALUE,
    SET_FEEDFORWARD,
    SET_JAC,
    SET_SIDE,
    SET_SIGMA,
    TaskEvaluation,
)
from tpik.exceptions import TargetNotSet
from tpik.tasks import (
    JointLimitTask,
    ObstacleDistanceTask,
    OrientationTask,
    PositionTask,
    SetTask,
    Task,
    Thresholds,
    VirtualWallTask,
)


class _Height(SetTask):
    """A user task (not compiled): σ = z of the EE."""

    def compute_value_and_jacobian(self, kin: Kinematics) -> tuple[float, np.ndarray]:
        return float(kin.frame_position("end_effector")[2]), kin.position_jacobian("end_effector")[2:3]


def _tasks(jaco, rng) -> list[Task]:  # type: ignore[no-untyped-def]
    kin = jaco.kinematics(jaco.home)
    obstacle_th = Thresholds(0.1, 0.35, math.inf, math.inf, 0.05)
    tasks: list[Task] = [JointLimitTask.from_robot(jaco, j, 0.1, 0.05) for j in (2, 4, 6)]
    tasks += [
        VirtualWallTask(
            "wall", "end_effector", rng.normal(size=3), 0.3, Thresholds(-0.05, 0.0, math.inf, math.inf, 0.03)
        ),
        ObstacleDistanceTask("near", "link_6", obstacle_th),
        ObstacleDistanceTask("none", "link_7", obstacle_th),
        ObstacleDistanceTask("on", "link_4", obstacle_th, joint=3),
        PositionTask("ee", "end_effector", 2.0, target=kin.frame_position("end_effector") + 0.1),
        OrientationTask("rot", "end_effector", 1.5, target=np.eye(3)),
        _Height("height", Thresholds(0.0, 0.2, 0.9, 1.2, 0.05), 1.0),
    ]
    return tasks


@pytest.mark.parametrize("jacobians", ["all", "candidates"])
def test_buffers_equal_compute_state(jaco, jacobians):
    rng = np.random.default_rng(3)
    tasks = _tasks(jaco, rng)
    ev = TaskEvaluation(tasks, jaco, jacobians=jacobians)
    assert [t.name for t in ev.set_tasks] == [
        "joint_limit_2",
        "joint_limit_4",
        "joint_limit_6",
        "wall",
        "near",
        "none",
        "on",
        "height",
    ]
    for _ in range(30):
        kin = jaco.kinematics(random_configuration(jaco, rng))
        near, on = tasks[4], tasks[6]
        assert isinstance(near, ObstacleDistanceTask) and isinstance(on, ObstacleDistanceTask)
        # A predicted approach: feed-forward f and growth g (σ = ‖O − P‖ − g) every other step.
        f, g = (rng.uniform(0.0, 1.5), rng.uniform(0.0, 0.4)) if rng.random() < 0.5 else (0.0, 0.0)
        near.set_obstacle(kin.frame_position("link_6") + rng.normal(size=3) * 0.3, f, g)
        on.set_obstacle(kin.frame_position("link_4"))  # O on P: σ = 0, J = 0
        ev.evaluate(kin)
        assert ev.set_in[4, SET_FEEDFORWARD] == f and near.rate_feedforward == f
        for s, task in enumerate(ev.set_tasks):
            state = task.compute_state(kin)
            sigma = float(state.value[0])
            assert ev.set_out[s, SET_SIGMA] == pytest.approx(sigma, rel=1e-12, abs=1e-15)
            side = task.activation_state(state).value
            assert ev.set_out[s, SET_SIDE] == side
            if jacobians == "all" or side != 0 or task.name != "height":
                np.testing.assert_allclose(ev.set_out[s, SET_JAC:], state.jacobian[0], rtol=0.0, atol=1e-12)
        for e, task in enumerate(ev.eq_tasks):
            rows = ev.eq_out[ev.eq_ptr[e] : ev.eq_ptr[e + 1]]
            state = task.compute_state(kin)
            np.testing.assert_allclose(rows[:, EQ_VALUE], state.value, atol=1e-12)
            np.testing.assert_allclose(rows[:, EQ_ERROR], state.error, atol=1e-12)
            np.testing.assert_allclose(rows[:, EQ_FEEDFORWARD], state.feedforward, atol=1e-12)
            np.testing.assert_allclose(rows[:, EQ_JAC:], state.jacobian, atol=1e-12)
    assert ev.set_out[5, SET_SIGMA] == math.inf and not ev.set_out[5, SET_JAC:].any()  # no obstacle
    assert ev.set_out[6, SET_SIGMA] == 0.0 and not ev.set_out[6, SET_JAC:].any()  # O on P


def test_gains_are_read_every_step(jaco):
    tasks = _tasks(jaco, np.random.default_rng(0))
    ev = TaskEvaluation(tasks, jaco)
    tasks[0].gain = 7.0
    tasks[7].gain = 3.0
    ev.evaluate(jaco.kinematics(jaco.home))
    assert ev.set_gain[0] == 7.0 and ev.eq_in[0, 6] == 3.0


def test_position_without_target_raises(jaco):
    ev = TaskEvaluation([PositionTask("ee", "end_effector")], jaco)
    with pytest.raises(TargetNotSet):
        ev.evaluate(jaco.kinematics(jaco.home))


@pytest.mark.parametrize("method", ["tpik", "hqp-daqp", "mink"])
def test_building_a_solver_loads_every_kernel_its_step_uses(jaco, method):
    """Warm-up: the first control step after the solver is built compiles (or loads) nothing new."""
    from compare.bench.solver_cases import apply_state, case2_hierarchy, case2_states
    from compare.methods import make_method
    from qp_baseline.set_rows import _stack_rows
    from robots.kinematics import _frame_origins, _shift_jacobians
    from tpik.evaluation import evaluate_compiled
    from tpik.step_rows import tpik_step

    kernels = (tpik_step, evaluate_compiled, _shift_jacobians, _frame_origins, _stack_rows)
    solver = make_method(method, jaco)
    before = [len(k.signatures) for k in kernels]
    state = case2_states(jaco)[2]
    hierarchy = case2_hierarchy(jaco)
    apply_state(hierarchy, state)
    assert solver.solve(hierarchy, jaco.kinematics(state.q), 0.01).ok
    assert [len(k.signatures) for k in kernels] == before


def test_gather_inputs_writes_a_replaced_obstacle_target_or_gain(jaco):
    """Unchanged inputs are skipped; a new obstacle point, target or gain reaches the buffers."""
    ob = ObstacleDistanceTask("ob", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05))
    pt = PositionTask("ee", "end_effector")
    ev = TaskEvaluation([ob, pt], jaco)
    pt.set_target([0.1, 0.2, 0.3])
    ob.set_obstacle([1.0, 0.0, 0.5])
    ev.gather_inputs()
    ev.gather_inputs()
    np.testing.assert_array_equal(ev.set_in[0, 8:12], [1.0, 0.0, 0.5, 1.0])
    ob.set_obstacle([0.5, 0.5, 0.5])
    pt.set_target([0.3, 0.2, 0.1], [0.0, 0.0, 1.0])
    ob.gain, pt.gain = 4.0, 5.0
    ev.gather_inputs()
    np.testing.assert_array_equal(ev.set_in[0, 8:13], [0.5, 0.5, 0.5, 1.0, 4.0])
    np.testing.assert_array_equal(ev.eq_in[0], [0.3, 0.2, 0.1, 0.0, 0.0, 1.0, 5.0])
    ob.set_obstacle(None)
    ev.gather_inputs()
    assert ev.set_in[0, 11] == 0.0
