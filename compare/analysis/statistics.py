"""Statistics of a sweep (docs/design.md §7): rates with Wilson intervals, paired McNemar tests, bootstrap medians.

* :func:`rate` — a share of runs as ``{"count": k, "runs": n, "rate": k/n, "ci95": [lo, hi]}``,
  the Wilson score interval (``scipy.stats.binomtest(...).proportion_ci(method="wilson")``),
  which stays inside [0, 1] and is sensible at k = 0 (0 of 1000 runs: [0, 0.38 %]).
* :func:`mcnemar` — paired per-seed comparison of two methods on a yes/no outcome of each run
  (e.g. "the run had a joint-limit or wall violation"): the exact McNemar test, i.e. a two-sided
  binomial test of the discordant pairs against 1/2 (``scipy.stats.binomtest``). Runs on the same
  seed see the same person, start pose and waypoints, so only the discordant seeds carry
  information about a difference.
* :func:`bootstrap_median_ci` — percentile bootstrap 95 % interval of a median over runs
  (``scipy.stats.bootstrap``, fixed seed: the same sweep gives the same interval).
"""

from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType
from typing import Any

import numpy as np

CONFIDENCE = 0.95
"""Confidence level of every interval."""

BOOTSTRAP_RESAMPLES = 2000
"""Resamples of :func:`bootstrap_median_ci`."""


def _stats() -> ModuleType:
    """``scipy.stats``, imported on first use."""
    # Deferred: it costs ~0.25 s of CPU (measured after compare.run's imports) in every process that
    # writes a summary, sweep workers included, while only a sweep's aggregation needs it.
    from scipy import stats

    return stats


def rate(count: int, runs: int) -> dict[str, Any]:
    """A share of runs with its Wilson 95 % interval; ``rate`` and ``ci95`` are None when ``runs`` is 0."""
    count, runs = int(count), int(runs)
    if runs <= 0:
        return {"count": count, "runs": 0, "rate": None, "ci95": None}
    ci = _stats().binomtest(count, runs).proportion_ci(confidence_level=CONFIDENCE, method="wilson")
    return {"count": count, "runs": runs, "rate": count / runs, "ci95": [float(ci.low), float(ci.high)]}


def rate_value(entry: Any) -> float | None:
    """The ``rate`` of a :func:`rate` entry (a plain number from an older summary passes through)."""
    if isinstance(entry, dict):
        value = entry.get("rate")
        return None if value is None else float(value)
    return None if entry is None else float(entry)


def mcnemar(a: Sequence[bool], b: Sequence[bool]) -> dict[str, Any]:
    """Exact McNemar test of two paired yes/no outcomes (one pair per seed).

    Args:
        a: Outcome of method A per seed.
        b: Outcome of method B on the same seeds.

    Returns:
        ``{"runs", "a_only", "b_only", "both", "neither", "p_value"}``: the discordant counts and the
        two-sided exact p-value (1.0 when no seed is discordant).
    """
    x = np.asarray(a, dtype=bool)
    y = np.asarray(b, dtype=bool)
    if x.shape != y.shape:
        raise ValueError(f"paired outcomes differ in length: {x.shape} vs {y.shape}")
    a_only = int(np.count_nonzero(x & ~y))
    b_only = int(np.count_nonzero(~x & y))
    discordant = a_only + b_only
    p = 1.0 if discordant == 0 else float(_stats().binomtest(a_only, discordant, 0.5).pvalue)
    return {
        "runs": int(x.size),
        "a_only": a_only,
        "b_only": b_only,
        "both": int(np.count_nonzero(x & y)),
        "neither": int(np.count_nonzero(~x & ~y)),
        "p_value": p,
    }


def bootstrap_median_ci(values: Sequence[float] | np.ndarray, seed: int = 0) -> list[float] | None:
    """Percentile bootstrap 95 % interval of the median of ``values`` (non-finite values dropped).

    Returns:
        ``[lo, hi]``, or None with fewer than two finite values.
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 2:
        return None
    if np.all(x == x[0]):
        return [float(x[0]), float(x[0])]
    res = _stats().bootstrap(
        (x,),
        np.median,
        confidence_level=CONFIDENCE,
        n_resamples=BOOTSTRAP_RESAMPLES,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    return [float(res.confidence_interval.low), float(res.confidence_interval.high)]


__all__ = ["BOOTSTRAP_RESAMPLES", "CONFIDENCE", "bootstrap_median_ci", "mcnemar", "rate", "rate_value"]
