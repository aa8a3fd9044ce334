"""Task behaviour: targets are copies, thresholds are validated, set tasks report activation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tpik.exceptions import InvalidTaskState, TargetNotSet, TaskDefinitionError, ThresholdOrderError
from tpik.tasks import (
    Activation,
    JointLimitTask,
    ObstacleDistanceTask,
    PositionTask,
    Thresholds,
    VirtualWallTask,
)


def test_target_is_a_copy(jaco):
    target = np.array([0.3, 0.2, 0.5])
    task = PositionTask("ee", target=target)
    target[0] = 99.0
    assert task.target[0] == pytest.approx(0.3)
    task.target[1] = 99.0
    assert task.target[1] == pytest.approx(0.2)


def test_position_task_without_target_raises(jaco):
    with pytest.raises(TargetNotSet, match="'ee'"):
        PositionTask("ee").compute_state(jaco.kinematics(jaco.home))


@pytest.mark.parametrize(
    ("values", "match"),
    [
        ((0.5, 0.4, 1.0, 2.0, 0.1), "physical_lower=0.5 must be < safety_lower=0.4"),
        ((0.0, 0.1, 2.5, 2.0, 0.1), "safety_upper=2.5 must be < physical_upper=2"),
        ((0.0, 0.1, 0.2, 2.0, 0.1), "safety_lower \\+ activation_margin"),
    ],
)
def test_threshold_order_rejected_naming_the_values(values, match):
    with pytest.raises(ThresholdOrderError, match=match):
        JointLimitTask("j", 2, 7, Thresholds(*values))


@pytest.mark.parametrize("eps", [0.0, -0.1, math.nan, math.inf])
def test_activation_margin_must_be_positive(eps):
    with pytest.raises(TaskDefinitionError, match="activation_margin"):
        JointLimitTask("j", 2, 7, Thresholds(0.0, 0.1, 1.0, 1.1, eps))


def test_one_sided_thresholds_accepted_and_both_infinite_rejected():
    Thresholds(0.1, 0.35, math.inf, math.inf, 0.05).check("ok")
    with pytest.raises(TaskDefinitionError, match="at least one safety threshold"):
        Thresholds(-math.inf, -math.inf, math.inf, math.inf, 0.05).check("bad")


def test_continuous_joint_has_no_limit_task(jaco):
    with pytest.raises(TaskDefinitionError, match="continuous"):
        JointLimitTask.from_robot(jaco, 1, 0.1, 0.05)


def test_joint_limit_activation_and_desired_value(jaco):
    task = JointLimitTask.from_robot(jaco, 2, safety_margin=0.1, activation_margin=0.05)
    th = task.thresholds
    q = jaco.home.copy()
    for sigma, expected, desired in [
        (th.activation_upper + 0.01, Activation.UPPER, th.safety_upper),
        (th.activation_lower - 0.01, Activation.LOWER, th.safety_lower),
        (0.5 * (th.safety_lower + th.safety_upper), Activation.INACTIVE, None),
    ]:
        q[1] = sigma
        state = task.compute_state(jaco.kinematics(q))
        assert task.activation_state(state) is expected
        # eq. 7: an active task is driven to the safety threshold it crossed.
        assert state.desired[0] == pytest.approx(sigma if desired is None else desired)


def test_velocity_bounds_stop_at_safety_threshold_in_one_step(jaco):
    task = JointLimitTask.from_robot(jaco, 4, safety_margin=0.1, activation_margin=0.05)
    q = jaco.home.copy()
    q[3] = task.thresholds.safety_lower + 0.02
    lower, upper = task.velocity_bounds(task.compute_state(jaco.kinematics(q)), dt=0.01)
    # The most negative velocity allowed lands exactly on σ_{s,l} after one Euler step (gain capped at 1/dt).
    task_fast = JointLimitTask("fast", 4, 7, task.thresholds, gain=1e6)
    lo_fast, _ = task_fast.velocity_bounds(task_fast.compute_state(jaco.kinematics(q)), dt=0.01)
    assert q[3] + lo_fast * 0.01 == pytest.approx(task.thresholds.safety_lower)
    assert lower == pytest.approx(-0.02) and upper > 0


def test_obstacle_task_without_obstacle_is_inactive(jaco):
    th = Thresholds(0.1, 0.35, math.inf, math.inf, 0.05)
    task = ObstacleDistanceTask("obs", "link_6", th)
    state = task.compute_state(jaco.kinematics(jaco.home))
    assert math.isinf(state.value[0]) and np.all(state.jacobian == 0.0)
    assert task.activation_state(state) is Activation.INACTIVE
    assert task.velocity_bounds(state, 0.01) == (-math.inf, math.inf)


def test_wall_signed_distance_and_normalised_normal(jaco):
    th = Thresholds(-0.05, 0.0, math.inf, math.inf, 0.03)
    wall = VirtualWallTask("w", "end_effector", np.array([0.0, 0.0, 2.0]), 0.4, th)
    ee = jaco.frame_position(jaco.home, "end_effector")
    state = wall.compute_state(jaco.kinematics(jaco.home))
    # n = (0,0,2) with offset 0.4 is the plane z = 0.2.
    assert state.value[0] == pytest.approx(ee[2] - 0.2)


def test_margins_are_signed():
    task = JointLimitTask("j", 2, 7, Thresholds(0.0, 0.1, 1.0, 1.1, 0.05))
    assert task.margins(0.05) == pytest.approx((-0.05, 0.05))
    assert task.margins(0.5) == pytest.approx((0.4, 0.5))


def test_value_and_jacobian_alone_equal_the_pair(jaco):
    rng = np.random.default_rng(3)
    th = Thresholds(0.1, 0.35, math.inf, math.inf, 0.05)
    obstacle = ObstacleDistanceTask("o", "link_6", th)
    obstacle.set_obstacle(np.array([0.3, 0.2, 0.6]))
    tasks = [
        JointLimitTask.from_robot(jaco, 4, 0.1, 0.05),
        VirtualWallTask(
            "w", "end_effector", np.array([0.0, 1.0, 0.0]), -0.5, Thresholds(-0.05, 0.0, math.inf, math.inf, 0.03)
        ),
        obstacle,
    ]
    for _ in range(5):
        kin = jaco.kinematics(rng.uniform(jaco.q_lower.clip(-3, 3) + 0.1, jaco.q_upper.clip(-3, 3) - 0.1))
        for task in tasks:
            sigma, jac = task.compute_value_and_jacobian(kin)
            assert task.compute_value(kin) == pytest.approx(sigma, abs=1e-15)
            np.testing.assert_array_equal(task.compute_jacobian(kin), jac)


def test_obstacle_growth_moves_every_threshold_out_and_keeps_the_jacobian(jaco):
    """σ = ‖O − P‖ − g: the task crosses σ_s exactly when the distance crosses σ_s + g; J unchanged."""
    from tests.test_jacobians import assert_jacobian_matches_finite_differences

    th = Thresholds(0.1, 0.35, math.inf, math.inf, 0.05)
    kin = jaco.kinematics(jaco.home)
    point = kin.frame_position("link_6") + np.array([0.0, 0.3, 0.4])  # 0.5 m away
    plain = ObstacleDistanceTask("plain", "link_6", th)
    grown = ObstacleDistanceTask("grown", "link_6", th)
    plain.set_obstacle(point)
    grown.set_obstacle(point, rate_feedforward=0.7, margin_growth=0.2)
    s_plain, j_plain = plain.compute_value_and_jacobian(kin)
    s_grown, j_grown = grown.compute_value_and_jacobian(kin)
    assert s_plain == pytest.approx(0.5) and s_grown == pytest.approx(0.3)
    assert grown.compute_value(kin) == pytest.approx(0.3)
    np.testing.assert_array_equal(j_plain, j_grown)
    assert grown.activation_state(grown.compute_state(kin)) is Activation.LOWER  # 0.3 <= 0.35 + 0.05
    assert plain.activation_state(plain.compute_state(kin)) is Activation.INACTIVE
    # The feed-forward enters the reference rate: K(σ_s − σ) + f.
    lo, hi = grown.velocity_bounds(grown.compute_state(kin), 0.01)
    assert lo == pytest.approx(1.0 * (0.35 - 0.3) + 0.7) and hi == math.inf
    assert_jacobian_matches_finite_differences(grown, jaco)
    grown.set_obstacle(None)  # no obstacle: no prediction left behind
    assert grown.rate_feedforward == 0.0 and grown.margin_growth == 0.0


@pytest.mark.parametrize(("feedforward", "growth"), [(math.nan, 0.0), (0.0, -0.1), (0.0, math.inf)])
def test_obstacle_prediction_must_be_finite(feedforward, growth):
    task = ObstacleDistanceTask("o", "link_6", Thresholds(0.1, 0.35, math.inf, math.inf, 0.05))
    with pytest.raises(InvalidTaskState, match="rate_feedforward"):
        task.set_obstacle(np.zeros(3), feedforward, growth)
