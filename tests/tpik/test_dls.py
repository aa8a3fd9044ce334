"""The compiled damped least squares of tpik.dls against the SVD of the test reference (conftest)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.tpik.conftest import svd_dls
from tpik.dls import gram_dls_star, min_eigenvalue


@pytest.mark.parametrize("m", [1, 2, 3, 4, 6])
@pytest.mark.parametrize("kind", ["regular", "ill_conditioned", "rank_deficient"])
def test_gram_dls_matches_the_svd_formula(m, kind):
    """With σ* = ‖r‖/‖q̇‖_max (the reference of the level in place of the paper's task error)."""
    rng = np.random.default_rng(m)
    for _ in range(20):
        B = rng.normal(size=(m, 7))
        if kind == "ill_conditioned":
            B[-1] = B[0] + 1e-3 * rng.normal(size=7)
        elif kind == "rank_deficient" and m > 1:
            B[-1] = 2.0 * B[0]
        elif kind == "rank_deficient":
            B[:] = 0.0
        r = rng.normal(size=m) * 3.0
        vnorm = 2.0
        S = B @ B.T
        y = np.zeros(m)
        lam = gram_dls_star(S, r, m, float(np.linalg.norm(r)) / vnorm, 1e-6, np.empty((m, m)), y)
        expected, expected_lam = svd_dls(B, r, vnorm, 1e-6)
        assert lam == pytest.approx(expected_lam, rel=1e-6, abs=1e-9)
        np.testing.assert_allclose(B.T @ y, expected, atol=1e-8)
        assert np.linalg.norm(B.T @ y) <= vnorm * (1.0 + 1e-9)  # the damping bound of sec. II-A


@pytest.mark.parametrize("m", [1, 2, 3, 5])
def test_min_eigenvalue_matches_numpy(m):
    rng = np.random.default_rng(10 + m)
    for _ in range(50):
        B = rng.normal(size=(m, m + 1))
        S = B @ B.T
        assert min_eigenvalue(S, m) == pytest.approx(np.linalg.eigvalsh(S)[0], abs=1e-9)
