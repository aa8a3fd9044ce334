"""Obstacle violations by the run's verdict: avoidable, unavoidable or undecided (docs/design.md §7).

Per run, the verdict (``summary.json["oracle"]``, :mod:`compare.campaign.verdict`) labels the
scenario ``avoidable`` (a witness that knew the person's future kept every safety threshold:
holding them was possible), ``unavoidable`` (a reachability certificate proves no motion within
the joint velocity limits could) or ``undecided`` (neither). A method's obstacle violation
episodes in the run are counted under that label:
``summary.json["methods"][m]["obstacle_violations"] = {"avoidable": n, "unavoidable": n,
"undecided": n}``.

Over a sweep (:func:`oracle_sweep_summary`), every share is a rate
``{"count": k, "runs": n, "rate": k/n, "ci95": [lo, hi]}`` with the Wilson score interval, and
methods are compared pairwise (exact McNemar) on "an obstacle violation in a run labelled
avoidable".
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from compare.analysis.results import SUMMARY_FILE, run_summaries
from compare.analysis.statistics import mcnemar, rate

LABELS = ("avoidable", "unavoidable", "undecided")
"""The verdict's labels (:mod:`compare.campaign.verdict`)."""


def run_label(oracle: dict[str, Any]) -> str:
    """The label of a run's ``oracle`` entry (an entry without one: ``avoidable`` if it held, else ``undecided``)."""
    label = oracle.get("label")
    if label in LABELS:
        return str(label)
    return "avoidable" if oracle.get("held_safety") else "undecided"


def split_obstacle_violations(method_summary: dict[str, Any], oracle: dict[str, Any]) -> dict[str, int]:
    """The method's obstacle violation episodes under the run's label (``{"avoidable": n, "unavoidable": n, ...}``).

    Args:
        method_summary: One entry of ``summary.json["methods"]``.
        oracle: The run's ``summary.json["oracle"]``.
    """
    group = method_summary.get("obstacles")
    episodes = int((group or {}).get("violations") or 0) if isinstance(group, dict) else 0
    label = run_label(oracle)
    return {name: episodes if name == label else 0 for name in LABELS}


def has_oracle(run_dir: Path) -> bool:
    """Whether the run's ``summary.json`` carries a verdict (``oracle`` with a ``label``).

    A resumed sweep with the verdict on re-runs the runs that lack one.
    """
    try:
        summary = json.loads((Path(run_dir) / SUMMARY_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    oracle = summary.get("oracle")
    return isinstance(oracle, dict) and oracle.get("label") in LABELS


def _witness_counts(summaries: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Per witness: runs it was tried in, runs it held, and runs it is the verdict's witness of."""
    out: dict[str, dict[str, int]] = {}
    for s in summaries:
        oracle = s["oracle"]
        for name, entry in (oracle.get("witnesses") or {}).items():
            row = out.setdefault(name, {"tried": 0, "held": 0, "chosen": 0})
            row["tried"] += 1
            row["held"] += int(bool(entry.get("held")))
            row["chosen"] += int(oracle.get("witness") == name)
    return out


def oracle_sweep_summary(sweep_dir: Path) -> dict[str, Any] | None:
    """Verdict aggregates of a sweep; None when no run has a verdict.

    Returns:
        ``{"oracle": {"runs", "labels": {label: rate}, "held_safety": rate, "min_distance_m":
        {"min", "median"}, "witnesses": {name: {"tried", "held", "chosen"}}, "draws": {"total",
        "rejected", "rejection_rate", "runs_without_avoidable_draw", "avoidable_family"}}, "methods": {m:
        {"obstacle_violations": {label: rate, "avoidable_given_held": rate,
        "episodes": {label: n}}}}, "paired_avoidable": {"<a> vs <b>": mcnemar}}``. A label's
        rate for a method counts the runs with that label and at least one obstacle violation over
        all its runs; ``avoidable_given_held`` conditions on the runs labelled ``avoidable``.
    """
    summaries = [s for s in run_summaries(sweep_dir) if isinstance(s.get("oracle"), dict)]
    if not summaries:
        return None
    labels = [run_label(s["oracle"]) for s in summaries]
    dists = np.array([d for s in summaries if (d := s["oracle"].get("min_distance_m")) is not None])
    draws = [int(s["oracle"].get("draws") or 1) for s in summaries]
    without = sum(1 for s in summaries if s["oracle"].get("avoidable_draw_found") is False)
    family = any("avoidable_draw_found" in s["oracle"] for s in summaries)
    total = sum(draws)
    methods: dict[str, Any] = {}
    flags: dict[str, dict[int, bool]] = {}
    names = list(dict.fromkeys(m for s in summaries for m in (s.get("methods") or {})))
    for name in names:
        rows = [
            (s["methods"][name], lab, s)
            for s, lab in zip(summaries, labels, strict=True)
            if name in s.get("methods", {})
        ]
        split = [split_obstacle_violations(m, s["oracle"]) for m, _, s in rows]
        n = len(rows)
        n_avoidable = sum(1 for _, lab, _ in rows if lab == "avoidable")
        entry: dict[str, Any] = {lab: rate(sum(1 for v in split if v[lab] > 0), n) for lab in LABELS}
        entry["avoidable_given_held"] = rate(sum(1 for v in split if v["avoidable"] > 0), n_avoidable)
        entry["episodes"] = {lab: int(sum(v[lab] for v in split)) for lab in LABELS}
        methods[name] = {"obstacle_violations": entry}
        flags[name] = {
            int(s.get("seed", i)): v["avoidable"] > 0
            for i, ((_, lab, s), v) in enumerate(zip(rows, split, strict=True))
            if lab == "avoidable"
        }
    paired: dict[str, Any] = {}
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            seeds = sorted(set(flags[a]) & set(flags[b]))
            if seeds:
                paired[f"{a} vs {b}"] = mcnemar([flags[a][k] for k in seeds], [flags[b][k] for k in seeds])
    return {
        "oracle": {
            "runs": len(summaries),
            "labels": {lab: rate(labels.count(lab), len(labels)) for lab in LABELS},
            "held_safety": rate(labels.count("avoidable"), len(labels)),
            "min_distance_m": {
                "min": float(dists.min()) if dists.size else None,
                "median": float(np.median(dists)) if dists.size else None,
            },
            "witnesses": _witness_counts(summaries),
            "draws": {
                "total": total,
                "rejected": total - len(summaries) + without,
                "rejection_rate": (total - len(summaries) + without) / total if total else None,
                "runs_without_avoidable_draw": without,
                "avoidable_family": family,
            },
        },
        "methods": methods,
        "paired_avoidable": paired,
    }


def _fmt_rate(r: dict[str, Any] | None) -> str:
    if not r or r.get("rate") is None:
        return "–"
    lo, hi = r["ci95"]
    return f"{r['count']}/{r['runs']} = {100.0 * r['rate']:.1f} % [{100.0 * lo:.1f}, {100.0 * hi:.1f}]"


def report_lines(sweep_summary: dict[str, Any]) -> list[str]:
    """Markdown section of the sweep report on the verdicts (empty without one)."""
    oracle = sweep_summary.get("oracle")
    if not isinstance(oracle, dict):
        return []
    draws = oracle.get("draws") or {}
    dist = oracle.get("min_distance_m") or {}
    labels = oracle.get("labels") or {}
    out = [
        "",
        "## Obstacle violations by the run's verdict",
        "",
        "- runs: " + ", ".join(f"{lab} {_fmt_rate(labels.get(lab))}" for lab in LABELS),
        f"- the witnesses' best minimum distance: median {dist.get('median') or float('nan'):.3f} m,"
        f" lowest {dist.get('min') or float('nan'):.3f} m",
    ]
    if draws.get("avoidable_family") or draws.get("total", 0) > oracle.get("runs", 0):
        out.append(
            f"- avoidable family: {draws['total']} draws for {oracle['runs']} runs, rejection rate"
            f" {100.0 * (draws.get('rejection_rate') or 0.0):.1f} %"
            + (
                f"; {draws['runs_without_avoidable_draw']} runs found no avoidable draw"
                if draws.get("runs_without_avoidable_draw")
                else ""
            )
        )
    witnesses = oracle.get("witnesses") or {}
    if witnesses:
        out += ["", "| witness | runs tried | held | the verdict's witness |", "|---|---:|---:|---:|"]
        out += [f"| {n} | {w['tried']} | {w['held']} | {w['chosen']} |" for n, w in witnesses.items()]
    out += [
        "",
        "| method | violation, run avoidable | violation, run unavoidable | violation, run undecided"
        " | violation among avoidable runs | episodes avoidable / unavoidable / undecided |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, m in (sweep_summary.get("methods") or {}).items():
        ov = m.get("obstacle_violations")
        if not isinstance(ov, dict):
            continue
        ep = ov.get("episodes") or {}
        out.append(
            f"| {name} | {_fmt_rate(ov.get('avoidable'))} | {_fmt_rate(ov.get('unavoidable'))}"
            f" | {_fmt_rate(ov.get('undecided'))} | {_fmt_rate(ov.get('avoidable_given_held'))}"
            f" | {' / '.join(str(ep.get(lab, 0)) for lab in LABELS)} |"
        )
    paired = sweep_summary.get("paired_avoidable") or {}
    if paired:
        out += [
            "",
            "Paired on the runs labelled avoidable (exact McNemar, obstacle violation):",
            "",
            "| pair (a vs b) | runs | a only / b only | p |",
            "|---|---:|---:|---:|",
        ]
        out += [
            f"| {k} | {v['runs']} | {v['a_only']} / {v['b_only']} | {v['p_value']:.3g} |" for k, v in paired.items()
        ]
    out += [
        "",
        "Rates with 95 % Wilson intervals. A run is *avoidable* when a witness (a policy that knows the person's"
        " future and drives the same plant under the same limits: the oracle at several horizons, greedy preview"
        " policies; compare/campaign/verdict.py) kept every obstacle, joint-limit and wall safety threshold: holding"
        " them was possible. *Unavoidable* needs a proof (compare/campaign/reachability.py): no motion within the"
        " joint velocity limits keeps the control point beyond the threshold. *Undecided*: no witness held and no"
        " proof was found; that is not evidence that the run was unavoidable.",
    ]
    return out
