"""The compiled helpers of the HQP cascade against the NumPy code they replace, on random inputs."""

from __future__ import annotations

import numpy as np
import pytest

from qp_baseline.cascade_kernels import equality_rows
from qp_baseline.set_rows import _binding_rows
from tpik.evaluation import EQ_ERROR, EQ_FEEDFORWARD, EQ_GAIN, EQ_JAC
from tpik.reference import effective_gain


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("gain_cap", [True, False])
def test_equality_rows_equal_the_references_of_eq_2_bit_for_bit(seed, gain_cap):
    rng = np.random.default_rng(seed)
    n, dims = 7, rng.integers(1, 4, size=rng.integers(0, 4))
    ptr = np.concatenate([[0], np.cumsum(dims)]).astype(np.int64)
    M = int(ptr[-1])
    eq_out = rng.normal(size=(M, EQ_JAC + n))
    eq_in = rng.normal(size=(dims.size, EQ_GAIN + 1))
    eq_in[:, EQ_GAIN] = rng.uniform(0.0, 300.0, dims.size)
    dt = float(rng.uniform(0.001, 0.05))
    J, r = np.full((M, n), np.nan), np.full(M, np.nan)
    assert equality_rows(eq_out, eq_in, ptr, dt, gain_cap, J, r)
    for e in range(dims.size):
        block = eq_out[ptr[e] : ptr[e + 1]]
        k = effective_gain(float(eq_in[e, EQ_GAIN]), dt, gain_cap)
        assert np.array_equal(r[ptr[e] : ptr[e + 1]], block[:, EQ_FEEDFORWARD] + k * block[:, EQ_ERROR])
        assert np.array_equal(J[ptr[e] : ptr[e + 1]], block[:, EQ_JAC:])
    if M:
        eq_out[rng.integers(M), EQ_JAC + rng.integers(n)] = np.inf
        assert not equality_rows(eq_out, eq_in, ptr, dt, gain_cap, J, r)


@pytest.mark.parametrize("seed", range(10))
def test_binding_rows_keep_the_rows_the_box_lets_bind_and_cut_them_by_level(seed):
    rng = np.random.default_rng(seed)
    n, S, L = 7, int(rng.integers(0, 12)), 4
    task_level = np.sort(rng.integers(0, L, S)).astype(np.int64)
    owner = np.sort(rng.integers(0, max(S, 1), 2 * S)).astype(np.int64)[: rng.integers(0, 2 * S + 1)]
    count = owner.size
    G = rng.normal(size=(2 * S, n))
    h = rng.normal(scale=3.0, size=2 * S)
    lb = -rng.uniform(0.0, 2.0, n)
    ub = lb + rng.uniform(0.0, 3.0, n)
    G_ref, h_ref, owner_ref = G[:count].copy(), h[:count].copy(), owner.copy()
    # The NumPy code this replaced (HqpSolver._evaluate before).
    reach = G_ref @ (0.5 * (ub + lb)) + np.abs(G_ref) @ (0.5 * (ub - lb))
    keep = np.flatnonzero(reach > h_ref)
    level_end = np.searchsorted(task_level[owner_ref], np.arange(L + 1), side="left")
    cuts_ref = np.searchsorted(keep, level_end)
    own = np.zeros(2 * S, dtype=np.int64)
    own[:count] = owner
    cuts = np.full(L + 1, -1, dtype=np.int64)
    kept = _binding_rows(G, h, own, count, lb, ub, task_level, cuts)
    assert kept == keep.size
    assert np.array_equal(G[:kept], G_ref[keep]) and np.array_equal(h[:kept], h_ref[keep])
    assert np.array_equal(own[:kept], owner_ref[keep]) and np.array_equal(cuts, cuts_ref)


@pytest.mark.parametrize("seed", range(10))
def test_box_and_row_checks_equal_their_numpy_expressions(seed):
    from qp_baseline.cascade_kernels import binds, clip_into, feasible, raise_to, zero_feasible

    rng = np.random.default_rng(seed)
    n, m, tol = 7, int(rng.integers(0, 6)), 1e-6
    lb = -rng.uniform(0.0, 1.0, n) * (rng.uniform(size=n) > 0.2)
    ub = lb + rng.uniform(0.0, 2.0, n) * (rng.uniform(size=n) > 0.2)
    v = rng.normal(size=n) * (rng.uniform(size=n) > 0.3)
    Gv, h = rng.normal(size=m), rng.normal(size=m) * (rng.uniform(size=m) > 0.3)
    if rng.uniform() < 0.5:
        v = np.clip(v, lb, ub)
        v[rng.integers(n)] = ub[0] - 0.5 * tol  # within tolerance of a bound, sometimes
    clipped = v.copy()
    clip_into(clipped, lb, ub)
    assert np.array_equal(clipped, np.minimum(np.maximum(v, lb), ub))
    assert feasible(v, lb, ub, Gv, h) == bool(((v >= lb) & (v <= ub)).all() and (Gv <= h).all())
    expected = bool((v <= lb + tol).any() or (v >= ub - tol).any() or (Gv >= h - tol).any())
    assert binds(v, lb, ub, Gv, h, tol) == expected
    assert zero_feasible(lb, ub, h) == bool(not ((lb > 0.0).any() or (ub < 0.0).any()) and (h >= 0.0).all())
    raised = h.copy()
    raise_to(raised, Gv)
    assert np.array_equal(raised, np.maximum(h, Gv))


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("at_zero", [True, False])
def test_level_objective_equals_the_numpy_level_value(seed, at_zero):
    from qp_baseline.cascade_kernels import level_objective

    rng = np.random.default_rng(seed)
    n, m, eps = 7, int(rng.integers(0, 4)), 1e-9
    M = rng.normal(size=(n + m, n + m))
    P, q, x = M.T @ M, rng.normal(size=n + m), rng.normal(size=n + m)
    qd = np.zeros(n) if at_zero else rng.normal(size=n)
    offset = float(rng.uniform(0.0, 2.0))
    qdot = x[:n] if at_zero else qd + x[:n]
    expected = float(x @ (0.5 * (P @ x) + q)) + offset - 0.5 * eps * float(qdot @ qdot)
    assert level_objective(P, q, x, qd, at_zero, offset, eps) == pytest.approx(expected, rel=1e-12, abs=1e-12)
