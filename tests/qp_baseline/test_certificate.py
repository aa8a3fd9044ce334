"""The correctness certificate against hand-built QPs with known optima, and against qpsolvers itself."""

from __future__ import annotations

import math

import numpy as np
import pytest
import qpsolvers

from qp_baseline.certificate import Tolerances, certify
from qp_baseline.certificate_dense import certify_dense
from qp_baseline.qp_problem import DenseProblem


def _halfline() -> qpsolvers.Problem:
    """min ½x² − x s.t. x ≤ 0.5: optimum x* = 0.5, f* = −0.375, multiplier z* = 0.5."""
    return qpsolvers.Problem(np.eye(1), np.array([-1.0]), np.eye(1), np.array([0.5]))


def test_the_optimum_with_its_multiplier_is_certified_with_zero_residuals():
    qp = _halfline()
    cert = certify(qp, np.array([0.5]), z=np.array([0.5]))
    assert cert.passed and cert.multipliers == "backend"
    assert cert.primal_residual == 0.0 and cert.dual_residual == 0.0 and cert.duality_gap == pytest.approx(0.0)
    assert cert.objective == pytest.approx(-0.375) and cert.lower_bound == pytest.approx(-0.375)


def test_a_feasible_suboptimal_answer_fails_and_its_bound_stays_below_the_optimum():
    qp = _halfline()
    cert = certify(qp, np.array([0.4]), z=np.array([0.6]))  # z consistent with stationarity at 0.4
    assert not cert.passed and "above the optimum" in cert.reason
    assert cert.lower_bound <= -0.375 + 1e-12 < cert.objective  # weak duality: a valid bound, f(x) above f*


def test_an_infeasible_answer_fails_on_its_primal_residual():
    qp = _halfline()
    cert = certify(qp, np.array([0.6]), z=np.array([0.4]))
    assert not cert.passed and cert.primal_residual == pytest.approx(0.1) and cert.reason.startswith("primal residual")


def test_a_multiplier_of_the_wrong_sign_is_not_trusted_but_recovered():
    qp = _halfline()
    x = np.array([0.5])
    wrong = certify(qp, x, z=np.array([-0.5]), recover=False)
    assert not wrong.passed and wrong.dual_residual == pytest.approx(0.5)  # z⁺ = 0: stationarity off by 0.5
    right = certify(qp, x, z=np.array([-0.5]))
    assert right.passed and right.multipliers == "recovered" and right.dual_residual == pytest.approx(0.0, abs=1e-12)


def test_missing_multipliers_are_recovered_on_the_active_set():
    qp = _halfline()
    cert = certify(qp, np.array([0.5]))
    assert cert.passed and cert.multipliers == "recovered"
    assert certify(qp, np.array([0.5]), recover=False).multipliers == "none"


def test_equality_constraint_and_box():
    # min ½‖x‖² s.t. x₁ + x₂ = 1, 0.6 ≤ x₁: optimum (0.6, 0.4), y* = −0.4, box multiplier on x₁: −0.2.
    P, q = np.eye(2), np.zeros(2)
    A, b = np.array([[1.0, 1.0]]), np.array([1.0])
    lb, ub = np.array([0.6, -1.0]), np.array([1.0, 1.0])
    x = np.array([0.6, 0.4])
    qp = qpsolvers.Problem(P, q, A=A, b=b, lb=lb, ub=ub)
    cert = certify(qp, x, y=np.array([-0.4]), z_box=np.array([-0.2, 0.0]))
    assert cert.passed and cert.dual_residual == pytest.approx(0.0, abs=1e-15)
    assert cert.lower_bound == pytest.approx(cert.objective)
    other = certify(qp, np.array([0.7, 0.3]))  # feasible, not optimal
    assert not other.passed


@pytest.mark.parametrize("seed", range(6))
def test_residuals_equal_qpsolvers_and_the_bound_holds_for_any_multipliers(seed):
    """On random feasible QPs: our residuals are qpsolvers' (``Solution.primal_residual`` ...), and the
    lower bound is below the exact optimum whatever nonnegative multipliers are given (weak duality)."""
    rng = np.random.default_rng(seed)
    n, m = 5, 6
    M = rng.normal(size=(n, n))
    P = M @ M.T + 0.1 * np.eye(n)
    q = rng.normal(size=n)
    G = rng.normal(size=(m, n))
    h = rng.uniform(0.1, 1.0, m)  # x = 0 feasible
    lb, ub = -np.ones(n), np.ones(n)
    qp = qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub)
    solution = qpsolvers.solve_problem(qp, solver="daqp")
    assert solution.found
    cert = certify(qp, solution.x, z=solution.z, z_box=solution.z_box)
    assert cert.passed
    assert cert.primal_residual == pytest.approx(solution.primal_residual(), abs=1e-14)
    assert cert.dual_residual == pytest.approx(solution.dual_residual(), abs=1e-12)
    assert cert.duality_gap == pytest.approx(solution.duality_gap(), abs=1e-12)
    f_star = float(solution.x @ (0.5 * P @ solution.x) + q @ solution.x)
    for _ in range(20):
        x = np.clip(rng.normal(size=n) * 0.3, lb, ub)
        if (G @ x > h).any():
            continue
        for z in (rng.uniform(0, 2, m), np.zeros(m)):
            bound = certify(qp, x, z=z, recover=False).lower_bound
            assert bound <= f_star + 1e-9
            curved = certify(qp, x, z=z, curvature=np.linalg.eigvalsh(P)[0], recover=False)
            assert curved.lower_bound <= f_star + 1e-9 and curved.lower_bound >= bound - 1e-12


def test_level_tolerance_catches_a_slack_above_a_zero_optimum():
    """A slack-level QP min ½w² s.t. g − w ≤ 0 (x = [g, w], g ∈ [−1, 1]): the optimum needs no slack.

    An answer keeping w = 2.1e-5 (ProxQP's suboptimal "solved" answer on a trap state, in spirit) has an
    objective error of only 2.2e-10, but a slack 2.1e-5 above the optimum: the level tolerance, in
    the level's own units, sees it; 1e-7 passes.
    """
    P = np.diag([0.0, 1.0])
    q = np.zeros(2)
    G = np.array([[1.0, -1.0]])
    h = np.array([0.0])
    lb, ub = np.array([-1.0, 0.0]), np.array([1.0, 10.0])
    qp = qpsolvers.Problem(P, q, G, h, lb=lb, ub=ub)
    tol = Tolerances(level=1e-6)
    for w, ok in ((2.1e-5, False), (1e-7, True)):
        x = np.array([w, w])  # the row binds: g = w
        cert = certify(qp, x, level_value=0.5 * w * w, tolerances=tol)
        assert cert.passed is ok, (w, cert.reason)
        assert cert.objective == pytest.approx(0.5 * w * w)
    loose = certify(qp, np.array([2.1e-5, 2.1e-5]), tolerances=Tolerances(gap=1e-9))
    assert loose.passed  # the plain relative gap would have accepted it


def test_modulus_judges_the_distance_to_the_optimum():
    P, q = np.eye(2), np.array([-1.0, -1.0])  # optimum (1, 1) in the box [−2, 2]²
    lb, ub = -2 * np.ones(2), 2 * np.ones(2)
    qp = qpsolvers.Problem(P, q, lb=lb, ub=ub)
    near = certify(qp, np.array([1.0, 1.0 + 1e-8]), modulus=1.0)
    far = certify(qp, np.array([1.0, 1.0 + 1e-4]), modulus=1.0)
    assert near.passed and not far.passed and "distance" in far.reason


def test_upper_bound_of_a_known_feasible_point():
    qp = _halfline()
    cert = certify(qp, np.array([0.2]), z=np.array([0.0]), feasible_objective=-0.375)
    assert not cert.passed and "known feasible point" in cert.reason and cert.upper_bound == -0.375


def test_non_finite_answer_and_bad_tolerances():
    qp = _halfline()
    cert = certify(qp, np.array([math.nan]))
    assert not cert.passed and cert.reason == "non-finite answer"
    with pytest.raises(ValueError, match="'level'"):
        Tolerances(level=0.0)


def _dense_level_qp(rng: np.random.Generator, n: int, m: int) -> tuple[np.ndarray, ...]:
    """A random level-like QP: P = MᵀM + εI (curvature ε), rows with x = 0 feasible, box around 0."""
    M = rng.normal(size=(3, n))
    eps = 10.0 ** rng.uniform(-9, -1)
    P = M.T @ M + eps * np.eye(n)
    q = rng.normal(size=n)
    G = rng.normal(size=(m, n))
    h = rng.uniform(0.0, 1.0, m)
    lb, ub = -rng.uniform(0.1, 2.0, n), rng.uniform(0.1, 2.0, n)
    return P, q, G, h, lb, ub, np.full(n, eps)


def _answers(rng: np.random.Generator, P: np.ndarray, q: np.ndarray, G: np.ndarray, h: np.ndarray, lb, ub):
    """(x, z, z_box) to judge: DAQP's optimum, perturbed ones, random and wrong-signed multipliers."""
    solution = qpsolvers.solve_problem(
        qpsolvers.Problem(P, q, G if h.size else None, h if h.size else None, lb=lb, ub=ub), solver="daqp"
    )
    assert solution.found
    x, z, zb = solution.x, solution.z if h.size else np.zeros(0), solution.z_box
    n, m = x.size, h.size
    yield x, z, zb
    yield x + 1e-7 * rng.normal(size=n), z, zb
    yield x + 1e-3 * rng.normal(size=n), z, zb  # suboptimal or infeasible
    yield np.clip(rng.normal(size=n), lb, ub), rng.uniform(-1.0, 2.0, m), rng.normal(size=n)
    yield x, -np.abs(z), np.zeros(n)


@pytest.mark.parametrize("seed", range(8))
def test_the_compiled_judgement_equals_the_numpy_one(seed):
    """``_dense_judgement`` (compiled) against the NumPy functions it replaces, on random inputs."""
    from qp_baseline import certificate_dense as cm
    from qp_baseline.dual_bound import box_term, primal_residual

    rng = np.random.default_rng(seed)
    for n, m in ((1, 0), (4, 3), (7, 6), (9, 12)):
        P, q, G, h, lb, ub, curv = _dense_level_qp(rng, n, m)
        for x, z, zb in _answers(rng, P, q, G, h, lb, ub):
            out = np.empty(cm._DENSE_OUT)
            assert cm._dense_judgement(P, q, G, h, lb, ub, x, z, zb, curv, out)
            qp = DenseProblem(P, q, G, h, lb=lb, ub=ub)
            Px, slack = P @ x, h - G @ x
            zp = np.maximum(z, 0.0)
            g = Px + q + G.T @ zp
            scale = 1.0 + float(np.abs(P).max() + np.abs(G).max(initial=0.0)) * (1.0 + float(np.abs(x).max()))
            assert out[cm._R_P] == pytest.approx(primal_residual(qp, x, slack), abs=1e-13 * scale)
            assert out[cm._F] == pytest.approx(float(x @ (0.5 * Px + q)), rel=1e-12, abs=1e-13 * scale)
            assert out[cm._R_D] == pytest.approx(float(np.abs(g + zb).max()), rel=1e-12, abs=1e-13 * scale)
            assert out[cm._COMP] == pytest.approx(float(zp @ slack), rel=1e-12, abs=1e-13 * scale)
            box = box_term(g, x, lb, ub, curv)
            assert out[cm._BOX] == pytest.approx(box, rel=1e-9, abs=1e-12 * scale)
            terms = [x @ Px, q @ x, h @ zp, lb @ np.minimum(zb, 0.0), ub @ np.maximum(zb, 0.0)]
            assert out[cm._TERMS :] == pytest.approx(terms, rel=1e-12, abs=1e-13 * scale)


@pytest.mark.parametrize("seed", range(8))
def test_certify_dense_gives_the_certificate_of_certify(seed):
    """Same verdict, reason and multiplier source as :func:`certify`, fields to round-off, on random
    level-like QPs with optimal, nearly optimal, suboptimal, infeasible and wrongly signed answers."""
    rng = np.random.default_rng(100 + seed)
    verdicts = set()
    for n, m in ((1, 0), (4, 3), (7, 6), (9, 12)):
        P, q, G, h, lb, ub, curv = _dense_level_qp(rng, n, m)
        for x, z, zb in _answers(rng, P, q, G, h, lb, ub):
            for f0, level, recover in ((None, None, False), (0.0, 0.5 * float(q @ q), True), (-1e9, None, False)):
                kw = dict(feasible_objective=f0, level_value=level, recover=recover)
                qp = DenseProblem(P, q, G, h, lb=lb, ub=ub)
                fast = certify_dense(qp, x, z, zb, curv, **kw)
                ref = certify(qp, x, z=z, z_box=zb, curvature=curv, **kw)
                assert (fast.passed, fast.multipliers) == (ref.passed, ref.multipliers)
                assert fast.reason.split(" ")[:2] == ref.reason.split(" ")[:2]
                for name in ("primal_residual", "dual_residual", "duality_gap", "objective", "lower_bound"):
                    assert getattr(fast, name) == pytest.approx(getattr(ref, name), rel=1e-9, abs=1e-12), name
                assert fast.upper_bound == ref.upper_bound
                verdicts.add(fast.passed)
    assert verdicts == {True, False}  # both kinds of verdict were exercised


def test_certify_dense_hands_other_forms_to_certify():
    qp = DenseProblem(*_halfline().unpack()[:4], lb=np.array([-1.0]), ub=np.array([1.0]))
    cases = [
        (np.array([0.5]), None, np.zeros(1), np.ones(1)),  # no multipliers: recovered
        (np.array([math.nan]), np.array([0.5]), np.zeros(1), np.ones(1)),  # non-finite answer
        (np.array([0.5]), np.array([0.5]), np.zeros(1), np.zeros(1)),  # a variable without curvature
    ]
    for x, z, zb, curv in cases:
        fast = certify_dense(qp, x, z, zb, curv)
        ref = certify(qp, x, z=z, z_box=zb, curvature=curv)
        assert fast == ref
