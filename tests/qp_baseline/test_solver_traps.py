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

from qp_baseline.exceptions import NoSolutionFound
from qp_baseline.hqp import HqpSolver
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

    def capture(P, q_, G, h, lb, ub, initvals, kwargs):
        captured.append((P.copy(), q_.copy(), G.copy(), h.copy(), lb.copy(), ub.copy()))
        return real(P, q_, G, h, lb, ub, initvals, kwargs)

    hqp._call_backend = capture  # type: ignore[method-assign]
    result = hqp.solve(hierarchy, jaco.kinematics(q), DT)
    assert "wall_x_max" in result.active_set
    return captured[-1]


def test_osqp_defaults_violate_constraints_and_ours_do_not(jaco, wall_level_qp):
    _needs("osqp")
    P, q, G, h, lb, ub = wall_level_qp
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = qpsolvers.solve_problem(
            qpsolvers.Problem(spa.csc_matrix(P), q, spa.csc_matrix(G), h, lb=lb, ub=ub), solver="osqp"
        )
    if not (raw.found and _violation(raw.x, G, h, lb, ub) > 1e-6):
        pytest.skip("OSQP's defaults happened to be accurate on this problem")
    ours = HqpSolver(jaco, "osqp")
    answer = ours.solve_qp(P, q, G, h, lb, ub, np.zeros_like(q))
    x, _, retried = answer
    assert answer.certified
    assert _violation(x, G, h, lb, ub) <= ours.tolerance
    assert retried == 0
    exact = qpsolvers.solve_problem(qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub), solver="daqp").x
    assert float(x @ (0.5 * P @ x) + q @ x) == pytest.approx(float(exact @ (0.5 * P @ exact) + q @ exact), abs=1e-8)


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


def test_proxqp_false_infeasibility_is_survived(jaco):
    _needs("proxqp")
    c = proxqp_case
    x0 = np.zeros(4)
    assert _violation(x0, c.G, c.h, c.lb, c.ub) <= 0.0  # feasible
    raw = qpsolvers.solve_problem(qpsolvers.Problem(c.P, c.q, c.G, c.h, lb=c.lb, ub=c.ub), "proxqp", eps_abs=1e-9)
    if raw.found:
        pytest.skip("this ProxQP version solves the recorded problem with its stock settings")
    exact = qpsolvers.solve_problem(qpsolvers.Problem(c.P, c.q, c.G, c.h, lb=c.lb, ub=c.ub), solver="daqp").x
    for settings in ({}, {"initial_guess": "EQUALITY_CONSTRAINED_INITIAL_GUESS"}):
        hqp = HqpSolver(jaco, "proxqp", settings)
        answer = hqp.solve_qp(c.P, c.q, c.G, c.h, c.lb, c.ub, x0)
        x = answer.x
        assert answer.certified, settings
        assert _violation(x, c.G, c.h, c.lb, c.ub) <= hqp.tolerance
        assert np.max(np.abs(x - exact)) < 1e-5, settings
    # Without the retry, the stock guess's "infeasible" answer is feasible but its multipliers do not
    # certify it: it comes back uncertified (the cascade then reports the level), never as a solution.
    lone = HqpSolver(jaco, "proxqp", {"initial_guess": "EQUALITY_CONSTRAINED_INITIAL_GUESS", "retry": False})
    answer = lone.solve_qp(c.P, c.q, c.G, c.h, c.lb, c.ub, x0, level=3)
    assert not answer.solution.found and not answer.certified
    assert answer.certificate is not None and answer.certificate.reason
    with pytest.raises(NoSolutionFound) as info:
        HqpSolver(jaco, "proxqp", {"initial_guess": "EQUALITY_CONSTRAINED_INITIAL_GUESS", "retry": False}).solve_qp(
            c.P,
            c.q,
            c.G,
            c.h,
            c.lb,
            c.ub,
            x0,
            f0=-1.0,
            level=3,  # a (fictitious) better point known: unusable
        )
    assert info.value.level == 3 and info.value.solution is not None and "worse than a known" in str(info.value)


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


def test_daqp_failure_on_a_near_singular_hessian_is_retried_with_regularisation(jaco):
    P, q, G, h, lb, ub = _near_singular_qp()
    raw = qpsolvers.solve_problem(qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub), solver="daqp")
    if raw.found:
        pytest.skip("this DAQP version solves the near-singular problem")
    feasible = qpsolvers.solve_problem(qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub), solver="quadprog").x
    assert feasible is not None  # the problem is feasible: DAQP's "infeasible" is wrong
    hqp = HqpSolver(jaco, "daqp")
    answer = hqp.solve_qp(P, q, G, h, lb, ub, feasible)
    x, _, retried = answer
    cert = answer.certificate
    assert retried == 1
    assert _violation(x, G, h, lb, ub) <= hqp.tolerance
    # The retry's extra 1e-7 on P moves the optimum of this near-singular QP a little (here the known
    # feasible point is quadprog's optimum): close, and reported as not certified, not as the optimum.
    f_exact = float(feasible @ (0.5 * P @ feasible) + q @ feasible)
    assert cert.objective == pytest.approx(f_exact, rel=1e-6)
    assert cert.objective > f_exact and not cert.passed and "above a known feasible point" in cert.reason
    with pytest.raises(NoSolutionFound):
        HqpSolver(jaco, "daqp", {"retry": False}).solve_qp(P, q, G, h, lb, ub, feasible)


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

    def fake(P, q, G, h, lb, ub, initvals, kwargs):
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
