"""Obstacle violations against the clairvoyant oracle: avoidable or unavoidable (DESIGN §7).

Per run, the oracle (:mod:`compare.campaign.oracle`) says whether a controller that knew the
person's future could have kept every control point beyond the safety threshold
(``summary.json["oracle"]["held_safety"]``). A method's obstacle violations in that run are then
*avoidable* (the oracle held) or *unavoidable* (it did not):
``summary.json["methods"][m]["obstacle_violations"] = {"avoidable": n, "unavoidable": n}``, n the
method's obstacle violation episodes.

Over a sweep (:func:`oracle_sweep_summary`), every share is a rate
``{"count": k, "runs": n, "rate": k/n, "ci95": [lo, hi]}`` with the Wilson score interval.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from compare.analysis.results import RUNS_DIR, SUMMARY_FILE
from compare.analysis.statistics import rate


def split_obstacle_violations(method_summary: dict[str, Any], oracle: dict[str, Any]) -> dict[str, int]:
    """The method's obstacle violation episodes as ``{"avoidable": n, "unavoidable": n}``.

    Args:
        method_summary: One entry of ``summary.json["methods"]``.
        oracle: The run's ``summary.json["oracle"]``.
    """
    group = method_summary.get("obstacles")
    episodes = int((group or {}).get("violations") or 0) if isinstance(group, dict) else 0
    held = bool(oracle.get("held_safety"))
    return {"avoidable": episodes if held else 0, "unavoidable": 0 if held else episodes}


def has_oracle(run_dir: Path) -> bool:
    """Whether the run's ``summary.json`` carries an ``oracle`` entry.

    A resumed sweep with the oracle on re-runs the runs that lack one.
    """
    try:
        summary = json.loads((Path(run_dir) / SUMMARY_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(summary.get("oracle"), dict)


def _run_summaries(sweep_dir: Path) -> list[dict[str, Any]]:
    runs_dir = Path(sweep_dir) / RUNS_DIR
    out = []
    for run_dir in sorted(p for p in runs_dir.glob("*") if p.is_dir()) if runs_dir.is_dir() else []:
        try:
            out.append(json.loads((run_dir / SUMMARY_FILE).read_text(encoding="utf-8")))
        except (OSError, ValueError):
            continue
    return out


def oracle_sweep_summary(sweep_dir: Path) -> dict[str, Any] | None:
    """Oracle and avoidable/unavoidable aggregates of a sweep; None when no run has an oracle.

    Returns:
        ``{"oracle": {"runs", "held_safety": rate, "min_distance_m": {"min", "median"},
        "draws": {"total", "rejected", "rejection_rate", "runs_without_avoidable_draw"}},
        "methods": {m: {"obstacle_violations": {"avoidable": rate, "unavoidable": rate,
        "avoidable_given_held": rate, "unavoidable_given_not_held": rate,
        "episodes": {"avoidable": n, "unavoidable": n}}}}}``. ``avoidable`` counts the runs with
        at least one avoidable violation over all runs with an oracle; ``*_given_*`` conditions on
        the oracle's verdict.
    """
    import numpy as np

    summaries = [s for s in _run_summaries(sweep_dir) if isinstance(s.get("oracle"), dict)]
    if not summaries:
        return None
    held = [bool(s["oracle"].get("held_safety")) for s in summaries]
    dists = np.array([d for s in summaries if (d := s["oracle"].get("min_distance_m")) is not None])
    draws = [int(s["oracle"].get("draws") or 1) for s in summaries]
    without = sum(1 for s in summaries if s["oracle"].get("avoidable_draw_found") is False)
    total = sum(draws)
    methods: dict[str, Any] = {}
    names = list(dict.fromkeys(m for s in summaries for m in (s.get("methods") or {})))
    for name in names:
        rows = [(s["methods"][name], h) for s, h in zip(summaries, held, strict=True) if name in s.get("methods", {})]
        split = [m.get("obstacle_violations") or split_obstacle_violations(m, {"held_safety": h}) for m, h in rows]
        n = len(rows)
        n_held = sum(1 for _, h in rows if h)
        avoidable = sum(1 for v in split if v["avoidable"] > 0)
        unavoidable = sum(1 for v in split if v["unavoidable"] > 0)
        methods[name] = {
            "obstacle_violations": {
                "avoidable": rate(avoidable, n),
                "unavoidable": rate(unavoidable, n),
                "avoidable_given_held": rate(avoidable, n_held),
                "unavoidable_given_not_held": rate(unavoidable, n - n_held),
                "episodes": {
                    "avoidable": int(sum(v["avoidable"] for v in split)),
                    "unavoidable": int(sum(v["unavoidable"] for v in split)),
                },
            }
        }
    return {
        "oracle": {
            "runs": len(summaries),
            "held_safety": rate(sum(held), len(held)),
            "min_distance_m": {
                "min": float(dists.min()) if dists.size else None,
                "median": float(np.median(dists)) if dists.size else None,
            },
            "draws": {
                "total": total,
                "rejected": total - len(summaries) + without,
                "rejection_rate": (total - len(summaries) + without) / total if total else None,
                "runs_without_avoidable_draw": without,
            },
        },
        "methods": methods,
    }


def _fmt_rate(r: dict[str, Any] | None) -> str:
    if not r or r.get("rate") is None:
        return "–"
    lo, hi = r["ci95"]
    return f"{r['count']}/{r['runs']} = {100.0 * r['rate']:.1f} % [{100.0 * lo:.1f}, {100.0 * hi:.1f}]"


def report_lines(sweep_summary: dict[str, Any]) -> list[str]:
    """Markdown section of the sweep report on the oracle split (empty without an oracle)."""
    oracle = sweep_summary.get("oracle")
    if not isinstance(oracle, dict):
        return []
    draws = oracle.get("draws") or {}
    dist = oracle.get("min_distance_m") or {}
    out = [
        "",
        "## Obstacle violations against the clairvoyant oracle",
        "",
        f"- oracle held the obstacle safety threshold in {_fmt_rate(oracle.get('held_safety'))} of the runs"
        f" (its minimum distance: median {dist.get('median') or float('nan'):.3f} m,"
        f" lowest {dist.get('min') or float('nan'):.3f} m)",
    ]
    if draws.get("total", 0) > oracle.get("runs", 0):
        out.append(
            f"- avoidable family: {draws['total']} draws for {oracle['runs']} runs, rejection rate"
            f" {100.0 * (draws.get('rejection_rate') or 0.0):.1f} %"
            + (
                f"; {draws['runs_without_avoidable_draw']} runs found no avoidable draw"
                if draws.get("runs_without_avoidable_draw")
                else ""
            )
        )
    out += [
        "",
        "| method | runs with an avoidable violation | runs with an unavoidable violation"
        " | avoidable, among runs the oracle held | episodes avoidable / unavoidable |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, m in (sweep_summary.get("methods") or {}).items():
        ov = m.get("obstacle_violations")
        if not isinstance(ov, dict):
            continue
        ep = ov.get("episodes") or {}
        out.append(
            f"| {name} | {_fmt_rate(ov.get('avoidable'))} | {_fmt_rate(ov.get('unavoidable'))}"
            f" | {_fmt_rate(ov.get('avoidable_given_held'))} | {ep.get('avoidable', 0)} / {ep.get('unavoidable', 0)} |"
        )
    out += [
        "",
        "Rates with 95 % Wilson intervals. A violation is *avoidable* when the oracle (receding-horizon"
        " optimiser over joint velocities that knows the person's future motion, same limits and plant;"
        " compare/campaign/oracle.py) kept every control point beyond the threshold in that run: a trajectory"
        " that holds it exists, for a controller that anticipates. *Unavoidable* means the oracle did not"
        " find one (not a proof that none exists).",
    ]
    return out
