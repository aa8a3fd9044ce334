"""The TPIK ablation: each deviation of ``tpik`` from the paper switched off alone, on the same seeds.

``tpik-compare ablation CONFIG`` is a sweep (:func:`compare.campaign.sweep.run_sweep`, resumable)
with the methods of :func:`compare.methods.ablation_methods` — ``tpik``, ``tpik-paper`` and one
``tpik-no-<deviation>`` per entry of :data:`tpik.solver.DEVIATIONS` — followed by one table,
``ablation.md`` and ``ablation.json``: per method the runs with a joint-limit or wall violation and
with an obstacle violation (Wilson 95 % intervals, exact McNemar p-value against ``tpik`` on the
same seeds), activation toggles per second, final EE error, solve time (bootstrap 95 % interval of
the median) and the failed / degraded steps.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from compare.analysis.metric import fmt_number, rate_with_ci
from compare.analysis.metrics import to_jsonable
from compare.analysis.report import markdown_table, write_markdown
from compare.analysis.results import SWEEP_SUMMARY_FILE, write_json_atomic
from compare.methods import ABLATION_PREFIX, ablation_methods
from tpik.solver import DEVIATIONS

ABLATION_FILE = "ablation.json"
ABLATION_REPORT = "ablation.md"
BASELINE = "tpik"


def _pair(paired: dict[str, Any], method: str) -> dict[str, Any]:
    """The paired entry of ``method`` against :data:`BASELINE`, oriented as (method vs tpik)."""
    direct = paired.get(f"{method} vs {BASELINE}")
    if direct is not None:
        return direct
    flipped = paired.get(f"{BASELINE} vs {method}")
    if flipped is None:
        return {}
    out: dict[str, Any] = {"runs": flipped.get("runs")}
    for outcome, test in flipped.items():
        if isinstance(test, dict):
            out[outcome] = {**test, "a_only": test.get("b_only"), "b_only": test.get("a_only")}
    return out


def ablation_table(sweep_summary: dict[str, Any]) -> dict[str, Any]:
    """Rows of the ablation from a sweep summary (``sweep_summary.json``)."""
    methods = sweep_summary.get("methods") or {}
    paired = sweep_summary.get("paired") or {}
    rows: dict[str, Any] = {}
    for name in ablation_methods():
        m = methods.get(name)
        if m is None:
            continue
        deviation = name.removeprefix(ABLATION_PREFIX) if name.startswith(ABLATION_PREFIX) else None
        pair = _pair(paired, name) if name != BASELINE else {}
        rows[name] = {
            "switched_off": deviation if deviation else ("all" if name == "tpik-paper" else "none"),
            "setting": None if deviation is None else {DEVIATIONS[deviation].setting: DEVIATIONS[deviation].paper},
            "runs": m.get("runs"),
            "limit_or_wall_violation": m.get("share_runs_limit_or_wall_violation"),
            "obstacle_violation": m.get("share_runs_obstacle_violation"),
            "p_vs_tpik": {
                "limit_or_wall_violation": (pair.get("limit_or_wall_violation") or {}).get("p_value"),
                "obstacle_violation": (pair.get("obstacle_violation") or {}).get("p_value"),
            },
            "activation_toggles_per_s_median": m.get("activation_toggles_per_s_median"),
            "ee_error_final_m_median": (m.get("ee_error_final_m") or {}).get("median"),
            "solve_time_us_median": (m.get("solve_time_us") or {}).get("median_of_medians"),
            "solve_time_us_median_ci95": (m.get("solve_time_us") or {}).get("median_of_medians_ci95"),
            "status_steps": m.get("status_steps"),
            "time_below_physical_s": m.get("time_below_physical_s"),
        }
    return {"baseline": BASELINE, "deviations": {k: v.why for k, v in DEVIATIONS.items()}, "methods": rows}


def write_ablation(sweep_dir: Path) -> Path:
    """Write ``ablation.json`` and ``ablation.md`` of a finished ablation sweep; returns the report path."""
    sweep_dir = Path(sweep_dir)
    summary = json.loads((sweep_dir / SWEEP_SUMMARY_FILE).read_text(encoding="utf-8"))
    table = ablation_table(summary)
    write_json_atomic(sweep_dir / ABLATION_FILE, to_jsonable(table))
    campaign = summary.get("campaign") or {}
    lines = [
        f"# TPIK ablation: {summary.get('scenario', '?')} ({summary.get('runs', 0)} runs)",
        "",
        f"- command: `{campaign.get('command', '?')}`",
        f"- git commit: `{(summary.get('versions') or {}).get('git_commit', 'unknown')}`",
        "- every method on the same seeds; p: exact McNemar test against `tpik` on those seeds",
        "",
    ]
    headers = [
        "method",
        "switched off",
        "joint-limit/wall violation (Wilson 95 %)",
        "p vs tpik",
        "obstacle violation (Wilson 95 %)",
        "p vs tpik",
        "toggles/s (median)",
        "EE final error [m] (median)",
        "solve median [µs] (95 %)",
        "steps degraded / failed",
        "time below a physical threshold [s]",
    ]
    rows = []
    for name, r in table["methods"].items():
        ci = r["solve_time_us_median_ci95"]
        st = r["status_steps"] or {}
        rows.append(
            [
                name,
                r["switched_off"],
                rate_with_ci(r["limit_or_wall_violation"]),
                fmt_number(r["p_vs_tpik"]["limit_or_wall_violation"], ".3g"),
                rate_with_ci(r["obstacle_violation"]),
                fmt_number(r["p_vs_tpik"]["obstacle_violation"], ".3g"),
                fmt_number(r["activation_toggles_per_s_median"], ".2f"),
                fmt_number(r["ee_error_final_m_median"], ".3f"),
                fmt_number(r["solve_time_us_median"], ".0f") + (f" [{ci[0]:.0f}, {ci[1]:.0f}]" if ci else ""),
                f"{st.get('degraded', '–')} / {st.get('failed', '–')}",
                fmt_number(r["time_below_physical_s"], ".2f"),
            ]
        )
    lines.append(markdown_table(headers, rows) if rows else "No finished run.")
    lines += ["", "## The deviations", ""]
    lines += [f"- `{name}`: {why}" for name, why in table["deviations"].items()]
    return write_markdown(sweep_dir / ABLATION_REPORT, lines)


__all__ = ["ABLATION_FILE", "ABLATION_REPORT", "ablation_table", "write_ablation"]
