"""Solver selection and settings: one clear error naming the solver, the key and what exists."""

from __future__ import annotations

import pytest
import qpsolvers

from compare.methods import available_methods, make_method
from qp_baseline.backends import BACKENDS, SUPPORTED_SOLVERS
from qp_baseline.exceptions import HqpError, InvalidSettings, UnknownSolver
from qp_baseline.hqp import HqpSolver, available_qp_solvers
from qp_baseline.mink_peer import MinkSolver
from tests.qp_baseline.helpers import SOLVERS


def test_available_solvers_are_supported_and_installed():
    names = available_qp_solvers()
    assert "daqp" in names
    assert set(names) <= set(SUPPORTED_SOLVERS) & set(qpsolvers.available_solvers)
    assert set(BACKENDS) == set(SUPPORTED_SOLVERS)


@pytest.mark.parametrize("name", ["nope", "cvxopt", ""])
def test_unknown_solver_lists_the_available_ones(jaco, name):
    with pytest.raises(UnknownSolver) as info:
        HqpSolver(jaco, name)
    message = str(info.value)
    assert f"'{name}'" in message
    for solver in available_qp_solvers():
        assert solver in message
    assert isinstance(info.value, HqpError) and isinstance(info.value, ValueError)


@pytest.mark.parametrize("solver", SOLVERS)
def test_unknown_backend_setting_is_named(jaco, solver):
    with pytest.raises(InvalidSettings) as info:
        HqpSolver(jaco, solver, {"not_a_setting": 1})
    assert info.value.key == "not_a_setting"
    assert solver in str(info.value) and "not_a_setting" in str(info.value)


@pytest.mark.parametrize(
    ("solver", "settings"),
    [
        ("osqp", {"eps_abs": "tight"}),
        ("daqp", {"iter_limit": "many"}),
        ("clarabel", {"max_iter": -3}),
        ("proxqp", {"initial_guess": "SOMETIMES"}),
    ],
)
def test_bad_backend_value_is_rejected_at_construction(jaco, solver, settings):
    if solver not in SOLVERS:
        pytest.skip(f"{solver} not installed")
    with pytest.raises(InvalidSettings) as info:
        HqpSolver(jaco, solver, settings)
    assert solver in str(info.value)


def test_backend_rejection_keeps_the_backend_error_as_cause(jaco):
    with pytest.raises(InvalidSettings) as info:
        HqpSolver(jaco, "daqp", {"bogus": True})
    assert info.value.__cause__ is not None


@pytest.mark.parametrize(
    ("settings", "key"),
    [
        ({"regularization": -1.0}, "regularization"),
        ({"regularization": float("nan")}, "regularization"),
        ({"tolerance": 0.0}, "tolerance"),
        ({"unconstrained_first": "yes"}, "unconstrained_first"),
        ({"min_norm_level": 1}, "min_norm_level"),
    ],
)
def test_bad_cascade_option_is_named(jaco, settings, key):
    with pytest.raises(InvalidSettings) as info:
        HqpSolver(jaco, "daqp", settings)
    assert key in str(info.value)


def test_user_settings_override_the_defaults(jaco):
    hqp = HqpSolver(jaco, "daqp", {"primal_tol": 1e-7, "regularization": 1e-8}, name="custom")
    assert hqp.name == "custom"
    assert hqp.qp_settings["primal_tol"] == 1e-7
    assert hqp.options.regularization == 1e-8
    if "osqp" in SOLVERS:
        osqp = HqpSolver(jaco, "osqp", {"eps_abs": 1e-7})
        assert osqp.qp_settings["eps_abs"] == 1e-7 and osqp.qp_settings["polish"] is True


def test_registry_builds_every_hqp_backend_and_mink(jaco):
    names = available_methods()
    for solver in SOLVERS:
        assert f"hqp-{solver}" in names
        method = make_method(f"hqp-{solver}", jaco)
        assert isinstance(method, HqpSolver) and method.name == f"hqp-{solver}" and method.solver == solver
    assert "mink" in names
    mink = make_method("mink", jaco, {"solver": "daqp"})
    assert isinstance(mink, MinkSolver) and mink.name == "mink"


@pytest.mark.parametrize(
    ("settings", "error", "fragment"),
    [
        ({"solver": "nope"}, UnknownSolver, "available"),
        ({"bogus": 1}, InvalidSettings, "bogus"),
        ({"damping": -1.0}, InvalidSettings, "damping"),
        ({"level_cost_ratio": 0.5}, InvalidSettings, "level_cost_ratio"),
        ({"configuration_limit_gain": 1.5}, InvalidSettings, "configuration_limit_gain"),
        ({"qp_settings": {"bogus": 1}}, InvalidSettings, "bogus"),
    ],
)
def test_mink_settings_are_validated(jaco, settings, error, fragment):
    with pytest.raises(error) as info:
        MinkSolver(jaco, settings)
    assert fragment in str(info.value)
