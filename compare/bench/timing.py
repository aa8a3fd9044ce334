"""Timing helpers shared by the benchmarks: medians and percentiles of repeated calls."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class BenchRow:
    """One benchmark line (the ``results`` entries of ``bench --json``, docs/design.md §7).

    Attributes:
        name: Method or pipeline stage (``tpik``, ``hqp-daqp``, ``mink``, ``depth-distance``, ...).
        case: Case name (``case2-active3``, ``512x424-rho0.5``, ...).
        median_us: Median time per call [µs].
        p95_us: 95th percentile [µs].
        samples: Number of timed calls.
        extra: Free-form numbers (e.g. build/solve split).
    """

    name: str
    case: str
    median_us: float
    p95_us: float
    samples: int
    extra: dict[str, float]

    def to_dict(self) -> dict[str, object]:
        """JSON-ready dict with the docs/design.md §7 keys first."""
        return asdict(self)


def time_calls(
    fn: Callable[[], object], repeats: int, warmup: int = 20, outputs: list[object] | None = None
) -> np.ndarray:
    """Call ``fn`` ``warmup`` times untimed, then ``repeats`` times; return each duration [µs].

    With ``outputs``, the return value of every timed call is appended to it (outside the timing).
    """
    for _ in range(warmup):
        fn()
    out = np.empty(repeats)
    clock = time.perf_counter_ns
    for i in range(repeats):
        t0 = clock()
        value = fn()
        out[i] = (clock() - t0) * 1e-3
        if outputs is not None:
            outputs.append(value)
    return out


def summarize(name: str, case: str, samples_us: np.ndarray, **extra: float) -> BenchRow:
    """Median and p95 of ``samples_us`` as a :class:`BenchRow`."""
    return BenchRow(
        name,
        case,
        float(np.median(samples_us)),
        float(np.percentile(samples_us, 95)),
        int(samples_us.size),
        {k: float(v) for k, v in extra.items()},
    )
