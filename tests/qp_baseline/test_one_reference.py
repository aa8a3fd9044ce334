"""One control reference (DESIGN §3): TPIK, HQP and mink receive the same r for the same hierarchy and state.

Every solver takes its references from :class:`tpik.reference.ControlReference`. The test spies on
that one place while each solver solves the same step, and checks the numbers each received:
the equality reference σ̇_d + Kσ̃ of the EE task (gain 500 /s, 1 mm: 0.1 m/s with the gain cap,
0.5 m/s without) and the rates K(σ_s − σ) of every set task a solver asked for. Then the EE
velocity each one commands, which is what the reference is for.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.methods import make_method
from tests.qp_baseline.helpers import DT, joint_limit_level, obstacle_level, position_level, wall_box_level
from tpik.hierarchy import Hierarchy
from tpik.reference import ControlReference
from tpik.tasks import ObstacleDistanceTask

SOLVERS = ("tpik", "hqp-daqp", "mink", "mink-hard")


def _hierarchy(jaco, kin, gain: float) -> Hierarchy:
    """Case 2's levels; obstacles in the activation band of link 6 and 7; EE task 1 mm off."""
    obstacles = obstacle_level(gain=2.0)
    for task in obstacles.tasks:
        assert isinstance(task, ObstacleDistanceTask)
        if task.frame != "link_4":
            task.set_obstacle(kin.frame_position(task.frame) + 0.37 * np.array([0.0, 0.6, 0.8]))
    target = kin.frame_position("end_effector") + np.array([0.001, 0.0, 0.0])
    return Hierarchy(
        [joint_limit_level(jaco, gain=2.0), wall_box_level(gain=2.0), obstacles, position_level(target, gain=gain)]
    )


@pytest.fixture
def spy(monkeypatch):
    """Record every reference ControlReference hands out, by task name."""
    seen: dict[str, dict[str, np.ndarray]] = {"equality": {}, "set": {}}
    equality, set_rates = ControlReference.equality, ControlReference.set_rates

    def spy_equality(self, task, state, dt):
        out = equality(self, task, state, dt)
        seen["equality"][task.name] = np.array(out)
        return out

    def spy_set_rates(self, task, sigma, dt):
        out = set_rates(self, task, sigma, dt)
        seen["set"][task.name] = np.array(out)
        return out

    monkeypatch.setattr(ControlReference, "equality", spy_equality)
    monkeypatch.setattr(ControlReference, "set_rates", spy_set_rates)
    return seen


@pytest.mark.parametrize(("gain_cap", "expected_mps"), [(True, 0.1), (False, 0.5)])
def test_every_method_receives_the_same_reference_for_the_same_state(jaco, spy, gain_cap, expected_mps):
    received: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for name in SOLVERS:
        solver = make_method(name, jaco, {"gain_cap": gain_cap})
        kin = jaco.kinematics(jaco.home)
        hierarchy = _hierarchy(jaco, kin, gain=500.0)
        spy["equality"].clear()
        spy["set"].clear()
        solver.solve(hierarchy, kin, DT)
        received[name] = {"equality": dict(spy["equality"]), "set": dict(spy["set"])}
    ee = "position_end_effector"
    for name in SOLVERS:  # mink evaluates on MuJoCo's kinematics: same EE position to ~1e-14 m (× 500 /s)
        np.testing.assert_allclose(received[name]["equality"][ee], [expected_mps, 0.0, 0.0], rtol=1e-9, atol=1e-10)
    # TPIK asks only for its candidates (past an activation threshold); the QP methods for every task.
    candidates = set(received["tpik"]["set"])
    assert {"obstacle_link_6", "obstacle_link_7"} <= candidates
    for name in SOLVERS[1:]:
        assert candidates <= set(received[name]["set"])
        for task in candidates:
            np.testing.assert_allclose(received[name]["set"][task], received["tpik"]["set"][task], rtol=1e-12)
    lo, hi = received["tpik"]["set"]["obstacle_link_6"]
    assert lo == pytest.approx(2.0 * (0.35 - 0.37), rel=1e-9) and hi == math.inf


@pytest.mark.parametrize("name", SOLVERS)
def test_every_method_commands_the_capped_ee_velocity_with_gain_500(jaco, name):
    """The issue's case: 1 mm error, gain 500: the commanded EE velocity is 0.100 m/s for every method."""
    kin = jaco.kinematics(jaco.home)
    target = kin.frame_position("end_effector") + np.array([0.001, 0.0, 0.0])
    hierarchy = Hierarchy([position_level(target, gain=500.0)])
    result = make_method(name, jaco).solve(hierarchy, kin, DT)
    ee_velocity = kin.position_jacobian("end_effector") @ result.qdot
    # HQP: its ε-regularisation (1e-9); mink: second order in the 1 mm error (SE(3) log), ~2e-6 m/s.
    np.testing.assert_allclose(ee_velocity, [0.1, 0.0, 0.0], atol={"tpik": 1e-12, "hqp-daqp": 1e-8}.get(name, 1e-5))
