"""How fast the realized person moved: per run (``summary.json["person"]``) and over a sweep.

Each run records the fastest capsule end of each body part, sampled at the control rate
(:func:`compare.sensing.person_track.max_speeds_by_part`); a sweep gives the distribution of
those per-run maxima (median, 95th percentile, largest) per part, so that a campaign's report
states the people its verdict is about.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def sweep_person_speeds(summaries: list[dict[str, Any]]) -> dict[str, dict[str, float]] | None:
    """``{part: {"median", "p95", "max", "runs"}}`` of the runs' per-part maximum speeds [m/s]; None without any."""
    values: dict[str, list[float]] = {}
    for s in summaries:
        for part, v in ((s.get("person") or {}).get("max_speed_mps") or {}).items():
            values.setdefault(part, []).append(float(v))
    if not values:
        return None
    return {
        part: {
            "median": float(np.median(v)),
            "p95": float(np.percentile(v, 95)),
            "max": float(np.max(v)),
            "runs": len(v),
        }
        for part, v in values.items()
    }


def report_lines(sweep_summary: dict[str, Any]) -> list[str]:
    """Markdown section of the sweep report on the realized person's speeds (empty without them)."""
    speeds = (sweep_summary.get("person") or {}).get("max_speed_mps")
    if not speeds:
        return []
    out = [
        "",
        "## The realized person",
        "",
        "| body part | runs | fastest per run: median [m/s] | p95 [m/s] | max [m/s] |",
        "|---|---:|---:|---:|---:|",
    ]
    out += [
        f"| {part} | {v['runs']} | {v['median']:.2f} | {v['p95']:.2f} | {v['max']:.2f} |" for part, v in speeds.items()
    ]
    out += [
        "",
        "Speed of the fastest capsule end of each body part, sampled at the control rate"
        " (compare/sensing/person_track.py); the family's walking and hand speeds bound them"
        " (compare/campaign/random_scenario.py).",
    ]
    return out
