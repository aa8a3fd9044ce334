"""The compiled σ of the built-in set tasks: numpy's dot bit for bit, the tasks' own values, the one activation rule."""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.bench.solver_cases import apply_state, case2_hierarchy, case2_states
from compare.loop import _sigma_kernel, set_task_watch
from compare.loop.numpy_dot import dot3, numpy_dot_order
from compare.loop.set_task_watch import SetTaskWatch
from tests.conftest import random_configuration
from tpik.tasks import ObstacleDistanceTask, VirtualWallTask


def test_dot3_is_numpys_dot_bit_for_bit_and_the_two_orders_differ():
    """On this machine numpy's 3-vector dot is one of the two chains, and the other is not it."""
    order = numpy_dot_order()
    assert order is not None, "numpy's dot is neither chain here: the watch asks every task itself"
    rng = np.random.default_rng(11)
    differ = 0
    for _ in range(5000):
        x, y = rng.normal(size=3), rng.normal(size=3) * rng.uniform(1e-3, 1e3)
        want = float(x.dot(y))
        assert dot3(*x.tolist(), *y.tolist(), order) == want
        differ += dot3(*x.tolist(), *y.tolist(), not order) != want
    assert differ > 500  # the probe can tell them apart


def test_near_tasks_follow_the_activation_rule_of_each_task(jaco):
    """The indices past an activation threshold are those of the Python rule, in order; infinite σ never."""
    hierarchy = case2_hierarchy(jaco)
    rng = np.random.default_rng(5)
    seen = 0
    for state in case2_states(jaco):
        apply_state(hierarchy, state)
        watch = SetTaskWatch(hierarchy.set_tasks)
        for _ in range(20):
            kin = jaco.kinematics(random_configuration(jaco, rng))
            sigmas = watch.measure(kin)
            want = [
                t
                for t, s in zip(hierarchy.set_tasks, sigmas, strict=True)
                if math.isfinite(s) and (s >= t.thresholds.activation_upper or s <= t.thresholds.activation_lower)
            ]
            assert watch._near == want
            seen += len(want)
    assert seen > 0


class _ShiftedWall(VirtualWallTask):
    """A wall whose σ is its own (a subclass: asked itself, never the compiled σ)."""

    def compute_value(self, kin):  # noqa: ANN001, ANN201
        return super().compute_value(kin) + 0.125


def test_a_task_with_its_own_value_is_asked_itself(jaco):
    """A subclass's compute_value is what is recorded; with no usable numpy order every task is asked."""
    hierarchy = case2_hierarchy(jaco)
    apply_state(hierarchy, case2_states(jaco)[2])
    wall = next(t for t in hierarchy.set_tasks if type(t) is VirtualWallTask)
    shifted = _ShiftedWall("shifted", wall.frame, wall.normal, wall.offset, wall.thresholds, wall.gain)
    tasks = [*hierarchy.set_tasks, shifted]
    kin = jaco.kinematics(random_configuration(jaco, np.random.default_rng(2)))
    got = SetTaskWatch(tasks).measure(kin)
    assert got == [t.compute_value(kin) for t in tasks]
    assert got[-1] == wall.compute_value(kin) + 0.125


def test_without_a_known_numpy_order_every_task_is_asked(jaco, monkeypatch):
    """The fallback: every σ from the task itself, the same numbers."""
    hierarchy = case2_hierarchy(jaco)
    apply_state(hierarchy, case2_states(jaco)[2])
    kin = jaco.kinematics(random_configuration(jaco, np.random.default_rng(3)))
    compiled = SetTaskWatch(hierarchy.set_tasks).measure(kin)
    monkeypatch.setattr(set_task_watch, "NUMPY_DOT_FUSED", None)
    watch = SetTaskWatch(hierarchy.set_tasks)
    assert all(kind == _sigma_kernel.KIND_GIVEN for kind in watch._spec[:, 0])
    assert watch.measure(kin) == compiled == [t.compute_value(kin) for t in hierarchy.set_tasks]


def test_a_new_obstacle_point_is_read_and_none_is_infinite(jaco):
    """O, g and the moved bands are read when set_obstacle gives a new point; without one σ = +inf."""
    hierarchy = case2_hierarchy(jaco)
    task = next(t for t in hierarchy.set_tasks if isinstance(t, ObstacleDistanceTask))
    k = hierarchy.set_tasks.index(task)
    watch = SetTaskWatch(hierarchy.set_tasks, predicting=True)
    kin = jaco.kinematics(random_configuration(jaco, np.random.default_rng(4)))
    frame = kin.frame_position(task.frame)
    for point, feedforward, growth in ((frame + [0.0, 0.0, 0.3], 0.4, 0.02), (frame + [0.2, 0.0, 0.0], 0.0, 0.0)):
        task.set_obstacle(point, feedforward, growth)
        assert watch.measure(kin)[k] == task.compute_value(kin)
        assert tuple(watch._spec[k, 6:8]) == task.activation_bounds()
    task.set_obstacle(None)
    assert watch.measure(kin)[k] == math.inf


def test_the_obstacle_point_is_the_tasks_own_read_only_array(jaco):
    """A new array at every set_obstacle, not writable; None without an obstacle."""
    task = next(t for t in case2_hierarchy(jaco).set_tasks if isinstance(t, ObstacleDistanceTask))
    task.set_obstacle(np.array([0.1, 0.2, 0.3]))
    first = task.obstacle_point
    assert first is task.obstacle_point and not first.flags.writeable
    task.set_obstacle(np.array([0.1, 0.2, 0.3]))
    assert task.obstacle_point is not first
    task.set_obstacle(None)
    assert task.obstacle_point is None


def test_a_joint_outside_q_is_an_index_error(jaco):
    """A joint limit on a joint q does not have: an error, never a read past the array."""
    spec = np.zeros((1, _sigma_kernel.SPEC_COLUMNS))
    spec[0, :2] = _sigma_kernel.KIND_JOINT, jaco.nq
    with pytest.raises(IndexError):
        _sigma_kernel.set_task_sigmas(
            np.zeros(jaco.nq), np.zeros((0, 3)), spec, np.zeros(1), np.zeros(1, dtype=np.int64), True
        )


class _OwnObstacle(ObstacleDistanceTask):
    """An obstacle task of its own class: asked itself, its bands still moved by the prediction."""


@pytest.mark.parametrize("compiled", [True, False])
def test_moved_bands_of_an_obstacle_task_asked_itself_are_read_every_step(jaco, monkeypatch, compiled):
    """With a prediction, a subclass (or every task, with no known numpy order) gets its activation_bounds."""
    if not compiled:
        monkeypatch.setattr(set_task_watch, "NUMPY_DOT_FUSED", None)
    base = next(t for t in case2_hierarchy(jaco).set_tasks if isinstance(t, ObstacleDistanceTask))
    task = _OwnObstacle("own", base.frame, base.thresholds, base.gain)
    watch = SetTaskWatch([task], predicting=True)
    kin = jaco.kinematics(random_configuration(jaco, np.random.default_rng(6)))
    frame = kin.frame_position(task.frame)
    lo = task.thresholds.activation_lower
    task.set_obstacle(frame + [0.0, 0.0, lo + 0.02], 0.0, 0.0)  # just outside the activation band: not near
    watch.measure(kin)
    assert watch._near == []
    task.set_obstacle(frame + [0.0, 0.0, lo + 0.02], 0.5, 0.0)  # closing: the band moves out past σ
    assert task.activation_bounds()[0] > lo + 0.02
    watch.measure(kin)
    assert watch._near == [task]
