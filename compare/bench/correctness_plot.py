"""The "timing vs correctness" figure of the QP backends (docs/design.md §7 plots)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from compare.bench.correctness import TOLERANCE, StepRecord, Summary  # noqa: E402

_FLOOR = 1e-12
"""Level errors below this are drawn at it (log axis)."""

MIN_STATES = 20
"""State sets smaller than this (the three case-2 states) are left out of the rate panel: their
Wilson interval says nothing; their steps are in the error panel."""


def plot_time_vs_correctness(
    summaries: Sequence[Summary], records: Sequence[StepRecord], path: Path, tolerance: float = TOLERANCE
) -> Path:
    """Draw the time-vs-correctness figure: success rate and every step's level error against time.

    Left: success rate (Wilson 95 % bars) against median step time per backend, for each state
    set of at least :data:`MIN_STATES` states. Right: every step's worst level error against its
    time, the tolerance drawn, flagged steps as crosses.

    Args:
        summaries: :func:`compare.bench.correctness.summarize` output.
        records: The per-step records it was made from.
        path: Output file (PNG or SVG by suffix); parent directories are created.
        tolerance: The level tolerance the records were judged with (drawn).

    Returns:
        ``path``.
    """
    methods = list(dict.fromkeys(s.name for s in summaries))
    colors = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    fig, (ax_rate, ax_err) = plt.subplots(1, 2, figsize=(12.0, 4.6))
    for s in summaries:
        t = s.time_us.get("median")
        if t is None or s.count < MIN_STATES:
            continue
        rate = 100.0 * s.success_rate["rate"]
        lo, hi = (100.0 * v for v in s.success_rate["ci95"])
        ax_rate.errorbar(
            [t],
            [rate],
            yerr=[[rate - lo], [hi - rate]],
            fmt="o",
            color=colors[s.name],
            capsize=3,
            label=f"{s.name} ({s.states}, {s.count})",
        )
        if s.silent:
            ax_rate.annotate(f"{s.silent} silent", (t, rate), textcoords="offset points", xytext=(5, -12), fontsize=8)
    ax_rate.set_xscale("log")
    ax_rate.set_xlabel("median step time [µs] (kinematics + solve)")
    ax_rate.set_ylabel("correct steps [%] (Wilson 95 %)")
    ax_rate.set_title("success rate vs time")
    ax_rate.grid(True, which="both", alpha=0.3)
    ax_rate.legend(fontsize=7, loc="lower left")
    for m in methods:
        rs = [r for r in records if r.method == m]
        times = np.array([r.time_us for r in rs])
        errors = np.maximum(np.array([r.worst_error for r in rs]), _FLOOR)
        flagged = np.array([r.flagged for r in rs])
        ax_err.scatter(times[~flagged], errors[~flagged], s=9, color=colors[m], alpha=0.6, label=m)
        if flagged.any():
            ax_err.scatter(times[flagged], errors[flagged], s=22, marker="x", color=colors[m], alpha=0.9)
    ax_err.axhline(tolerance, color="k", ls="--", lw=1, label=f"tolerance {tolerance:g}")
    ax_err.set_xscale("log")
    ax_err.set_yscale("log")
    ax_err.set_xlabel("step time [µs]")
    ax_err.set_ylabel(f"worst level error e_k (floor {_FLOOR:g})")
    ax_err.set_title("every step (x: flagged DEGRADED/FAILED by the certificate)")
    ax_err.grid(True, which="both", alpha=0.3)
    ax_err.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path
