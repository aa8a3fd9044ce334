"""Known backend traps, each detected and handled: the caller never gets a bad velocity.

* OSQP's default tolerances leave constraint violations far above 1e-6 (tight eps + polish);
* ProxQP reports PRIMAL_INFEASIBLE on a feasible QP (no initial guess; retry solving the closest
  feasible problem, then our own feasibility check);
* DAQP reports "infeasible" on a feasible QP with a near-singular Hessian (retry with +1e-6);
* quadprog rejects a positive semidefinite Hessian (regularisation; retry with +1e-6);
* whatever else a backend does wrong (exception, NaN, violated constraints, a worse answer than
  a known feasible point) ends in FAILED with zero velocity, or DEGRADED keeping the levels above.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import qpsolvers
import scipy.sparse as spa

from qp_baseline.backends import BACKENDS
from qp_baseline.exceptions import NoSolutionFound
from qp_baseline.hqp import RETRY_REGULARIZATION, HqpSolver
from tests.qp_baseline import proxqp_false_infeasible as proxqp_case
from tests.qp_baseline.helpers import (
    DT,
    SOLVERS,
    joint_limit_level,
    position_level,
    rollout,
    wall_box_level,
)
from tpik.hierarchy import Hierarchy


def _needs(solver: str) -> None:
    if solver not in SOLVERS:
        pytest.skip(f"{solver} not installed")


def _violation(x: np.ndarray, G: np.ndarray, h: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> float:
    return float(max((lb - x).max(), (x - ub).max(), (G @ x - h).max() if h.size else -math.inf))


@pytest.fixture(scope="module")
def wall_level_qp(jaco):
    """A position-level QP with the x_max wall binding, captured from a closed-loop run."""
    ee = jaco.kinematics(jaco.home).frame_position("end_effector")
    hierarchy = Hierarchy(
        [joint_limit_level(jaco), wall_box_level(gain=10.0), position_level(np.array([0.8, ee[1], ee[2]]), gain=2.0)]
    )
    q = rollout(HqpSolver(jaco, "daqp"), hierarchy, jaco, jaco.home, steps=100).q
    hqp = HqpSolver(jaco, "daqp", {"unconstrained_first": False})
    captured = []
    real = hqp._call_backend

    def capture(problem, initvals, kwargs):
        captured.append(tuple(a.copy() for a in (problem.P, problem.q, problem.G, problem.h, problem.lb, problem.ub)))
        return real(problem, initvals, kwargs)

    hqp._call_backend = capture  # type: ignore[method-assign]
    result = hqp.solve(hierarchy, jaco.kinematics(q), DT)
    assert "wall_x_max" in result.active_set
    return captured[-1]


def test_our_osqp_settings_meet_the_constraints_on_the_wall_level_qp(jaco, wall_level_qp):
    _needs("osqp")
    P, q, G, h, lb, ub = wall_level_qp
    ours = HqpSolver(jaco, "osqp")
    x, _, retried = ours.solve_qp(P, q, G, h, lb, ub, np.zeros_like(q))
    assert _violation(x, G, h, lb, ub) <= ours.tolerance
    assert retried == 0
    exact = qpsolvers.solve_problem(qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub), solver="daqp").x
    assert float(x @ (0.5 * P @ x) + q @ x) == pytest.approx(float(exact @ (0.5 * P @ exact) + q @ exact), abs=1e-8)


def test_osqp_defaults_still_violate_constraints_on_the_wall_level_qp(jaco, wall_level_qp):
    """Why BACKENDS["osqp"].defaults exists (a check of the backend, not of our code)."""
    _needs("osqp")
    P, q, G, h, lb, ub = wall_level_qp
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = qpsolvers.solve_problem(
            qpsolvers.Problem(spa.csc_matrix(P), q, spa.csc_matrix(G), h, lb=lb, ub=ub), solver="osqp"
        )
    if not (raw.found and _violation(raw.x, G, h, lb, ub) > 1e-6):
        pytest.skip("this OSQP version's defaults are accurate here: BACKENDS['osqp'].defaults may be revisited")
    # OSQP says "solved"; its answer breaks the constraints more than the one our settings give.
    ours, _, _ = HqpSolver(jaco, "osqp").solve_qp(P, q, G, h, lb, ub, np.zeros_like(q))
    assert raw.found and _violation(raw.x, G, h, lb, ub) > max(_violation(ours, G, h, lb, ub), 0.0)


@pytest.mark.parametrize("ours", [False, True], ids=["retried", "polished"])
def test_loose_osqp_settings_are_caught_by_the_check_and_retried_or_polished(jaco, wall_level_qp, ours):
    """OSQP at eps 1e-2 without its polish: the certificate rejects the answer; our polish (an exact KKT
    solve of the active set OSQP found) fixes it at once, or else the retry's settings do."""
    _needs("osqp")
    P, q, G, h, lb, ub = wall_level_qp
    settings = {"eps_abs": 1e-2, "eps_rel": 1e-2, "polish": False, "tolerance": 1e-7}
    loose = HqpSolver(jaco, "osqp", {**settings, "kkt_polish": ours})
    answer = loose.solve_qp(P, q, G, h, lb, ub, np.zeros_like(q))
    x, _, retried = answer
    assert answer.certified
    assert retried == (0 if ours else 1)
    assert _violation(x, G, h, lb, ub) <= 1e-7


def _recording(hqp: HqpSolver, answer: object) -> list[dict[str, object]]:
    """Replace the backend call of ``hqp``: ``answer(P, kwargs)`` says whether to play the bug.

    Returns the list the calls are recorded in (P, initvals, kwargs of each).
    """
    calls: list[dict[str, object]] = []
    real = hqp._call_backend

    def call(problem, initvals, kwargs):
        P = problem.P
        calls.append({"P": P.copy(), "initvals": None if initvals is None else initvals.copy(), "kwargs": kwargs})
        if answer(P, kwargs):
            return _Fake(None, found=False)  # what the buggy backend reports
        return real(problem, initvals, kwargs)

    hqp._call_backend = call  # type: ignore[method-assign]
    return calls


def test_proxqp_retry_solves_the_closest_feasible_problem_after_a_false_infeasibility(jaco):
    """The retry handler against a stand-in for ProxQP's bug, whatever the installed ProxQP does."""
    _needs("proxqp")
    c = proxqp_case
    x0 = np.zeros(4)
    exact = qpsolvers.solve_problem(qpsolvers.Problem(c.P, c.q, c.G, c.h, lb=c.lb, ub=c.ub), solver="daqp").x
    hqp = HqpSolver(jaco, "proxqp")
    calls = _recording(hqp, lambda P, kwargs: not kwargs.get("primal_infeasibility_solving"))
    x, _, retried = hqp.solve_qp(c.P, c.q, c.G, c.h, c.lb, c.ub, x0)
    assert retried == 1 and len(calls) == 2
    assert calls[0]["initvals"] is None and np.array_equal(calls[1]["initvals"], x0)  # warm start on the retry
    assert calls[1]["kwargs"]["primal_infeasibility_solving"] is True
    np.testing.assert_allclose(calls[1]["P"], c.P + RETRY_REGULARIZATION * np.eye(4))
    assert _violation(x, c.G, c.h, c.lb, c.ub) <= hqp.tolerance
    assert np.max(np.abs(x - exact)) < 1e-5
    no_retry = HqpSolver(jaco, "proxqp", {"retry": False})
    _recording(no_retry, lambda P, kwargs: True)
    with pytest.raises(NoSolutionFound) as info:
        no_retry.solve_qp(c.P, c.q, c.G, c.h, c.lb, c.ub, x0, level=3)
    assert info.value.level == 3 and info.value.solution is not None and "no solution" in str(info.value)


def test_proxqp_recorded_problem_is_solved_with_our_settings(jaco):
    _needs("proxqp")
    c = proxqp_case
    x0 = np.zeros(4)
    assert _violation(x0, c.G, c.h, c.lb, c.ub) <= 0.0  # feasible
    exact = qpsolvers.solve_problem(qpsolvers.Problem(c.P, c.q, c.G, c.h, lb=c.lb, ub=c.ub), solver="daqp").x
    for settings in ({}, {"initial_guess": "EQUALITY_CONSTRAINED_INITIAL_GUESS"}):
        hqp = HqpSolver(jaco, "proxqp", settings)
        answer = hqp.solve_qp(c.P, c.q, c.G, c.h, c.lb, c.ub, x0)
        x = answer.x
        assert answer.certified, settings
        assert _violation(x, c.G, c.h, c.lb, c.ub) <= hqp.tolerance
        assert np.max(np.abs(x - exact)) < 1e-5, settings


def test_proxqp_still_reports_the_recorded_false_infeasibility():
    """Why BACKENDS["proxqp"].retry exists (a check of the backend, not of our code)."""
    _needs("proxqp")
    c = proxqp_case
    raw = qpsolvers.solve_problem(qpsolvers.Problem(c.P, c.q, c.G, c.h, lb=c.lb, ub=c.ub), "proxqp", eps_abs=1e-9)
    if raw.found:
        pytest.skip("this ProxQP version solves the recorded problem with its stock settings")
    # "Primal infeasible", although x = 0 satisfies every constraint: the report is false.
    assert "PRIMAL_INFEASIBLE" in str(raw.extras["info"].status)
    assert _violation(np.zeros(4), c.G, c.h, c.lb, c.ub) <= 0.0


def _near_singular_qp() -> tuple[np.ndarray, ...]:
    """A feasible QP with a rank-3 + 1e-9 I Hessian and degenerate bounds (seeded search)."""
    rng = np.random.default_rng(1756)
    n = 7
    J = rng.standard_normal((3, n)) * 0.3
    P = J.T @ J + 1e-9 * np.eye(n)
    q = rng.standard_normal(n) * 0.1
    g = rng.standard_normal((3, n)) * 0.3
    G = np.vstack([np.eye(n)[:2], g, -g, -np.eye(n)[3:4]])
    h = np.concatenate([[0.0, 0.5], rng.uniform(0, 0.5, 3), rng.uniform(0, 0.5, 3), [0.0]])
    lb, ub = -np.ones(n) * 0.8, np.ones(n) * 0.8
    lb[rng.integers(0, n)] = 0.0
    ub[rng.integers(0, n)] = 0.0
    return P, q, G, h, lb, ub


def test_a_failure_on_a_near_singular_hessian_is_retried_with_regularisation(jaco):
    """The retry handler against a stand-in for DAQP's bug: "infeasible" unless P is regularised."""
    P, q, G, h, lb, ub = _near_singular_qp()
    feasible = qpsolvers.solve_problem(qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub), solver="quadprog").x
    assert feasible is not None  # the problem is feasible
    hqp = HqpSolver(jaco, "daqp")
    calls = _recording(hqp, lambda P_, kwargs: np.linalg.eigvalsh(P_)[0] < 1e-7)
    x, _, retried = hqp.solve_qp(P, q, G, h, lb, ub, feasible)
    assert retried == 1 and len(calls) == 2
    np.testing.assert_allclose(calls[1]["P"], P + RETRY_REGULARIZATION * np.eye(7))
    assert np.array_equal(calls[1]["initvals"], feasible)
    assert _violation(x, G, h, lb, ub) <= hqp.tolerance
    no_retry = HqpSolver(jaco, "daqp", {"retry": False})
    _recording(no_retry, lambda P_, kwargs: np.linalg.eigvalsh(P_)[0] < 1e-7)
    with pytest.raises(NoSolutionFound):
        no_retry.solve_qp(P, q, G, h, lb, ub, feasible)


def test_near_singular_problem_is_solved_by_our_daqp_settings(jaco):
    P, q, G, h, lb, ub = _near_singular_qp()
    feasible = qpsolvers.solve_problem(qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub), solver="quadprog").x
    hqp = HqpSolver(jaco, "daqp")
    x, _, _ = hqp.solve_qp(P, q, G, h, lb, ub, feasible)
    assert _violation(x, G, h, lb, ub) <= hqp.tolerance
    f = float(x @ (0.5 * P @ x) + q @ x)
    assert f <= float(feasible @ (0.5 * P @ feasible) + q @ feasible) + hqp.tolerance


def test_daqp_still_fails_on_the_near_singular_hessian():
    """Why the regularised retry exists (a check of the backend, not of our code)."""
    P, q, G, h, lb, ub = _near_singular_qp()
    if qpsolvers.solve_problem(qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub), solver="daqp").found:
        pytest.skip("this DAQP version solves the near-singular problem")
    # DAQP finds nothing, yet quadprog finds a point meeting every constraint: the failure is false.
    feasible = qpsolvers.solve_problem(qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub), solver="quadprog").x
    assert feasible is not None and _violation(feasible, G, h, lb, ub) <= BACKENDS["daqp"].tolerance


def test_quadprog_semidefinite_hessian_is_retried_with_regularisation(jaco):
    rng = np.random.default_rng(0)
    J = rng.standard_normal((3, 7))
    P = J.T @ J  # rank 3: quadprog needs a positive definite P
    q = -J.T @ rng.standard_normal(3)
    lb, ub = -np.ones(7), np.ones(7)
    with pytest.raises(Exception, match="positive definite"):
        qpsolvers.solve_problem(qpsolvers.Problem(P, q, lb=lb, ub=ub), solver="quadprog")
    hqp = HqpSolver(jaco, "quadprog")
    answer = hqp.solve_qp(P, q, None, None, lb, ub, np.zeros(7))
    x, _, retried = answer
    assert answer.certified
    assert retried == 1 and np.all(np.isfinite(x)) and _violation(x, np.zeros((0, 7)), np.zeros(0), lb, ub) <= 0


class _Fake:
    """Stands for a backend answer."""

    def __init__(self, x: np.ndarray | None, found: bool = True) -> None:
        self.x = x
        self.found = found
        self.extras: dict[str, object] = {}
        self.y = self.z = self.z_box = None  # no multipliers: the certificate recovers them


@pytest.mark.parametrize(
    ("behaviour", "fragment"),
    [
        ("not_found", "reported no solution"),
        ("nan", "non-finite"),
        ("violating", "violates its constraints"),
        ("worse", "worse than a known feasible point"),
        ("raises", "raised RuntimeError"),
    ],
)
def test_every_bad_answer_ends_in_a_safe_zero_velocity(jaco, monkeypatch, behaviour, fragment):
    kin = jaco.kinematics(jaco.home)
    hierarchy = Hierarchy([position_level(kin.frame_position("end_effector") + np.array([0.05, 0.0, 0.0]))])
    hqp = HqpSolver(jaco, "daqp", {"unconstrained_first": False})
    calls = {"n": 0}

    def fake(problem, initvals, kwargs):
        q, lb, ub = problem.q, problem.lb, problem.ub
        calls["n"] += 1
        if behaviour == "raises":
            raise RuntimeError("backend exploded")
        if behaviour == "not_found":
            return _Fake(None, found=False)
        if behaviour == "nan":
            return _Fake(np.full(q.shape, np.nan))
        if behaviour == "violating":
            return _Fake(ub + 1.0)
        return _Fake(np.where(q > 0, ub, lb))  # a feasible box corner uphill of the cost

    monkeypatch.setattr(hqp, "_call_backend", fake)
    result = hqp.solve(hierarchy, kin, DT)
    assert result.status.value == "failed"
    assert fragment in result.message and "priority level 0" in result.message
    assert np.array_equal(result.qdot, np.zeros(jaco.nq))
    assert calls["n"] == 2  # the answer was retried once


def test_a_retried_level_is_reported_and_its_answer_used(jaco, monkeypatch):
    kin = jaco.kinematics(jaco.home)
    hierarchy = Hierarchy([position_level(kin.frame_position("end_effector") + np.array([0.05, 0.0, 0.0]))])
    hqp = HqpSolver(jaco, "daqp", {"unconstrained_first": False})
    reference = HqpSolver(jaco, "daqp").solve(hierarchy, kin, DT).qdot
    real = hqp._call_backend
    calls = {"n": 0}

    def first_fails(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 1:
            return _Fake(None, found=False)
        return real(*args, **kwargs)

    monkeypatch.setattr(hqp, "_call_backend", first_fails)
    result = hqp.solve(hierarchy, kin, DT)
    assert result.status.value == "ok" and result.extras["retries"] == 1
    np.testing.assert_allclose(result.qdot, reference, atol=1e-5)  # the retry adds 1e-6 regularisation
