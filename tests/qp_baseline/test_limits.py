"""HQP and the mink peer read the limit objects (tpik.limits): their box, mink's own rows, an acceleration limit."""

from __future__ import annotations

import mink
import numpy as np
import pytest

from qp_baseline.hqp import HqpSolver, default_limits
from qp_baseline.lexicographic import joint_box
from qp_baseline.mink_peer import JointLimits, MinkSolver
from tests.conftest import random_configuration
from tests.tpik.test_limits import rollout_changes
from tpik.limits import AccelerationLimit, PositionLimit, VelocityLimit, compose_box


def test_hqp_box_equals_the_reference_box_written_apart(jaco):
    """The composed default limits are the hard box the lexicographic reference writes out by hand."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = random_configuration(jaco, rng, inset=-0.2)  # some joints outside their limits
        dt = float(rng.uniform(0.005, 0.02))
        lower, upper = compose_box(default_limits(jaco), q, dt)
        ref_lower, ref_upper = joint_box(jaco, q, dt)
        np.testing.assert_allclose(lower, ref_lower, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(upper, ref_upper, rtol=1e-12, atol=1e-12)


def test_mink_peer_rows_are_minks_own_limits_rows(jaco):
    """JointLimits with the default limits gives ConfigurationLimit's and VelocityLimit's rows, in Δq."""
    gain, dt = 0.95, 0.01
    configuration = mink.Configuration(jaco.mj_model)
    rng = np.random.default_rng(5)
    ours = JointLimits((PositionLimit.from_robot(jaco, gain=gain), VelocityLimit.from_robot(jaco)))
    velocities = {jaco.joint_names[i]: float(jaco.v_max[i]) for i in range(jaco.nq)}
    theirs = [mink.ConfigurationLimit(jaco.mj_model, gain=gain), mink.VelocityLimit(jaco.mj_model, velocities)]
    for _ in range(10):
        configuration.update(random_configuration(jaco, rng))
        G, h = ours.compute_qp_inequalities(configuration, dt)
        parts = [limit.compute_qp_inequalities(configuration, dt) for limit in theirs]
        np.testing.assert_array_equal(G, np.vstack([p.G for p in parts]))
        np.testing.assert_allclose(h, np.concatenate([p.h for p in parts]), rtol=1e-13, atol=1e-15)


def test_hqp_with_explicit_default_limits_equals_the_default(jaco):
    """Limits given in the API and the built-in ones pose the same problem (same answer, bit for bit)."""
    from compare.bench.qp_states import apply_qp_state, random_states
    from compare.bench.solver_cases import case2_hierarchy

    default = HqpSolver(jaco, "daqp")
    explicit = HqpSolver(jaco, "daqp", limits=(VelocityLimit(jaco.v_max), PositionLimit(jaco.q_lower, jaco.q_upper)))
    h1, h2 = case2_hierarchy(jaco), case2_hierarchy(jaco)
    for state in random_states(jaco, n=20, seed=2):
        apply_qp_state(h1, state)
        apply_qp_state(h2, state)
        kin = jaco.kinematics(state.bench.q)
        np.testing.assert_array_equal(default.solve(h1, kin, state.dt).qdot, explicit.solve(h2, kin, state.dt).qdot)


@pytest.mark.parametrize("solver_name", ["daqp", "quadprog"])
def test_hqp_respects_an_acceleration_limit(jaco, solver_name):
    a_max = 5.0  # rad/s²
    free = rollout_changes(HqpSolver(jaco, solver_name), jaco, 40, a_max)
    limits = (VelocityLimit.from_robot(jaco), AccelerationLimit(a_max, n=jaco.nq), PositionLimit.from_robot(jaco))
    limited = rollout_changes(HqpSolver(jaco, solver_name, limits=limits), jaco, 40, a_max)
    assert free > 2.0  # the limit binds on this sequence
    assert limited <= 1.0 + 1e-6


def test_mink_peer_respects_an_acceleration_limit(jaco):
    a_max = 5.0
    limits = (PositionLimit.from_robot(jaco, 0.95), VelocityLimit.from_robot(jaco), AccelerationLimit(a_max, n=jaco.nq))
    free = rollout_changes(MinkSolver(jaco), jaco, 40, a_max)
    limited = rollout_changes(MinkSolver(jaco, limits=limits), jaco, 40, a_max)
    assert free > 2.0
    assert limited <= 1.0 + 1e-4  # mink's answer is checked to the backend tolerance in Δq units


def test_hqp_needs_a_limit(jaco):
    from tpik.exceptions import InvalidSettings

    with pytest.raises(InvalidSettings, match="at least one limit"):
        HqpSolver(jaco, "daqp", limits=())
