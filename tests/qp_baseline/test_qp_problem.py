"""One QP type: a qpsolvers ``Problem``, dense where the package computes, as given where a backend reads it."""

from __future__ import annotations

import numpy as np
import qpsolvers
import scipy.sparse as spa

from qp_baseline.qp_problem import DenseProblem, dense_problem, without_empty_rows


def test_a_dense_problem_is_a_qpsolvers_problem_with_every_field_an_array():
    qp = DenseProblem(spa.csc_matrix(np.eye(3)), np.ones(3))
    assert isinstance(qp, qpsolvers.Problem)
    assert type(qp.P) is np.ndarray and np.array_equal(qp.P, np.eye(3))
    assert qp.G.shape == (0, 3) and qp.h.shape == (0,) and qp.A.shape == (0, 3) and qp.b.shape == (0,)
    assert np.all(qp.lb == -np.inf) and np.all(qp.ub == np.inf)


def test_dense_arrays_are_kept_not_copied():
    P, q, G, h, lb, ub = np.eye(2), np.zeros(2), np.ones((1, 2)), np.ones(1), -np.ones(2), np.ones(2)
    qp = DenseProblem(P, q, G, h, lb=lb, ub=ub)
    assert qp.P is P and qp.q is q and qp.G is G and qp.lb is lb and qp.ub is ub
    assert dense_problem(qp) is qp


def test_a_plain_problem_becomes_dense_and_back():
    plain = qpsolvers.Problem(np.eye(2), np.zeros(2), lb=-np.ones(2), ub=np.ones(2))
    dense = dense_problem(plain)
    back = without_empty_rows(dense)
    assert back.G is None and back.h is None and back.A is None and back.b is None
    assert back.P is dense.P and back.lb is dense.lb and back.ub is dense.ub


def test_an_unbounded_side_is_left_out_for_the_backend():
    qp = without_empty_rows(DenseProblem(np.eye(2), np.zeros(2), np.ones((1, 2)), np.ones(1), ub=np.ones(2)))
    assert qp.lb is None and qp.ub is not None and qp.G is not None
