"""Sweep statistics against independent formulas: Wilson interval, exact McNemar, bootstrap median."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from compare.analysis.results import paired_comparisons
from compare.analysis.statistics import bootstrap_median_ci, mcnemar, rate, rate_value

Z95 = 1.959963984540054


def wilson(k: int, n: int) -> tuple[float, float]:
    """The Wilson score interval, written out (Wilson 1927)."""
    p = k / n
    denom = 1.0 + Z95**2 / n
    center = (p + Z95**2 / (2 * n)) / denom
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n * n)) / denom
    return center - half, center + half


@pytest.mark.parametrize(("k", "n"), [(0, 1000), (1, 1000), (17, 20), (20, 20), (3, 7)])
def test_rate_has_the_wilson_interval(k, n):
    entry = rate(k, n)
    assert entry["count"] == k and entry["runs"] == n and entry["rate"] == pytest.approx(k / n)
    lo, hi = wilson(k, n)
    assert entry["ci95"] == pytest.approx([lo, hi], abs=1e-12)
    assert 0.0 <= entry["ci95"][0] <= entry["rate"] <= entry["ci95"][1] <= 1.0
    assert rate_value(entry) == entry["rate"] and rate_value(0.25) == 0.25 and rate_value(None) is None


def test_zero_of_a_thousand_runs_is_not_zero_risk():
    """0/1000: the interval still reaches ~0.38 % (the "rule of three" gives 0.3 %)."""
    assert rate(0, 1000)["ci95"][1] == pytest.approx(0.00383, abs=2e-5)
    assert rate(0, 0) == {"count": 0, "runs": 0, "rate": None, "ci95": None}


def test_exact_mcnemar_is_the_binomial_test_of_the_discordant_seeds():
    a = [True] * 1 + [False] * 9 + [True] * 5 + [False] * 85
    b = [False] * 1 + [True] * 9 + [True] * 5 + [False] * 85
    test = mcnemar(a, b)
    assert (test["a_only"], test["b_only"], test["both"], test["neither"], test["runs"]) == (1, 9, 5, 85, 100)
    # Two-sided exact: 2 · P(X ≤ 1), X ~ Bin(10, 1/2) = 2 · (1 + 10) / 1024.
    assert test["p_value"] == pytest.approx(2 * 11 / 1024, rel=1e-12)
    assert mcnemar([True, False], [True, False])["p_value"] == 1.0  # no discordant seed
    with pytest.raises(ValueError, match="length"):
        mcnemar([True], [True, False])


def test_bootstrap_interval_of_the_median_covers_it_and_narrows_with_more_runs():
    rng = np.random.default_rng(1)
    small = rng.lognormal(4.0, 0.5, 30)
    large = rng.lognormal(4.0, 0.5, 3000)
    ci_small, ci_large = bootstrap_median_ci(small), bootstrap_median_ci(large)
    assert ci_small[0] <= np.median(small) <= ci_small[1]
    assert ci_large[0] <= np.median(large) <= ci_large[1]
    assert ci_large[1] - ci_large[0] < 0.5 * (ci_small[1] - ci_small[0])
    assert bootstrap_median_ci(small) == ci_small  # fixed seed: the same sweep, the same interval
    # The true median of this lognormal, e^4, lies in the large sample's interval.
    assert ci_large[0] < math.exp(4.0) < ci_large[1]
    assert bootstrap_median_ci([5.0]) is None and bootstrap_median_ci([2.0, 2.0]) == [2.0, 2.0]


def test_paired_comparisons_pair_runs_by_seed_and_skip_unfinished_ones():
    rows = []
    for seed in range(12):
        rows.append({"seed": seed, "method": "tpik", "error": None, "joint_limits_violations": int(seed == 3)})
        hqp_wall = int(seed in (1, 2, 3, 4, 5, 6))
        rows.append({"seed": seed, "method": "hqp-daqp", "error": None, "walls_violations": hqp_wall})
    rows.append({"seed": 12, "method": "tpik", "error": None, "joint_limits_violations": 1})
    rows.append({"seed": 12, "method": "hqp-daqp", "error": "NoSolutionFound"})  # not paired
    table = pd.DataFrame(rows)
    for col in ("joint_limits_violations", "walls_violations", "obstacles_violations"):
        table[col] = pd.to_numeric(table.get(col), errors="coerce")
    paired = paired_comparisons(table)
    entry = paired["tpik vs hqp-daqp"]
    assert entry["runs"] == 12
    lw = entry["limit_or_wall_violation"]
    assert (lw["a_only"], lw["b_only"], lw["both"], lw["neither"]) == (0, 5, 1, 6)
    assert lw["p_value"] == pytest.approx(2 / 32)  # 2 · P(X ≤ 0), X ~ Bin(5, 1/2)
    assert entry["obstacle_violation"]["p_value"] == 1.0
