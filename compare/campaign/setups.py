r"""Setups of one scenario family compared on the same seeds: safety held, cost of the mission.

Each *setup* is a sweep of one family over the same seeds with something changed (prediction on or
off, the sensing range, ...): the person, start pose and waypoints are drawn from the seed alone, so
runs of one seed and method are paired across setups. Per method and setup, on the seeds every
setup ran, from each run's ``summary.json`` (ground-truth distances):

* **held**: no obstacle safety violation in the run (``obstacles.violations`` = 0); the rate with
  its Wilson 95 % interval and, against the first setup (the baseline), the exact McNemar test on
  the discordant seeds. When the baseline's runs carry the verdict (``oracle.label``), the rate is
  also given over the ``avoidable`` runs only;
* **joint / wall**: runs with a joint-limit or wall safety violation, and their worst margins;
* **mission**: the mean end-effector error over the run and the waypoints reached, paired against
  the baseline with the Wilcoxon signed-rank test; the time to each waypoint (``time_to_waypoint_s``,
  segment *k* of a seed against segment *k* of the same seed in the baseline: the run's mean over the
  segments both reached, Wilcoxon on those means; and the segments only one of the two reached);
  the time below the physical obstacle threshold;
* **speed**: the held share against the person's peak torso speed (``person.max_speed_mps``, the
  walking speed the run realised), in speed bins with their Wilson intervals
  (:func:`held_by_speed`; ``setups_speed.png`` draws it).

Run::

    python -m compare.campaign.setups results/predicted-off:off results/predicted-estimated:estimated \
        --out docs/campaign-predicted

(``SOURCE:LABEL``; the label defaults to the directory's or file's name; ``--seeds N``: only the
first N seeds all of them ran.) Writes ``setups.json``, ``setups.md`` and ``setups_speed.png``.

A source is a sweep directory or a run table (:mod:`compare.campaign.run_table`); the sources of one
label are merged, so a campaign grows over sweeps that no longer exist: ``--save-runs`` writes each
setup's merged runs to ``runs/LABEL.csv`` in the output, and a later call takes that file beside the
new sweep under the same label::

    python -m compare.campaign.setups docs/campaign-predicted/depth/runs/off.csv:off results/depth-off:off \
        docs/campaign-predicted/depth/runs/estimated.csv:estimated results/depth-estimated:estimated \
        --out docs/campaign-predicted/depth --save-runs
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from compare.analysis.atomic_files import write_text_atomic
from compare.analysis.plots_setups import SPEED_PLOT, plot_held_by_speed
from compare.analysis.results import RUNS_DIR, write_json_atomic
from compare.analysis.statistics import mcnemar, rate
from compare.arguments import ArgumentParser, output_dir, positive_int
from compare.campaign.run_table import RunTable, load_table, merge_tables, write_table

RESULT = "setups.json"
REPORT = "setups.md"
RUNS_SUBDIR = "runs"
"""``--save-runs`` writes each setup's run table (:mod:`compare.campaign.run_table`) here."""

SPEED_BINS = 4
"""Bins of the held-vs-speed view: quantiles of the baseline's torso speeds (equal run counts)."""


def _wilcoxon(a: np.ndarray, b: np.ndarray) -> float | None:
    keep = np.isfinite(a) & np.isfinite(b)
    a, b = a[keep], b[keep]
    if a.size < 2:
        return None
    return 1.0 if np.all(a == b) else float(stats.wilcoxon(a, b).pvalue)


def _mean(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else None


def _min(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(x.min()) if x.size else None


def waypoint_time_pairs(this: pd.Series, base: pd.Series) -> dict[str, Any]:
    """Time to each waypoint, seed by seed against the baseline (module docstring).

    Args:
        this: Per seed, the list of each segment's time to reach [s] (NaN: never reached).
        base: The same for the baseline, seeds in the same order.

    Returns:
        ``{"seeds", "mean_s", "baseline_mean_s", "wilcoxon_p", "only_this", "only_baseline"}``:
        the seeds with a segment both reached, the mean over them of the per-seed mean times, the
        Wilcoxon p on the per-seed means (None under two seeds), and the segments only one reached.
    """
    mine: list[float] = []
    theirs: list[float] = []
    only_this = only_base = 0
    for a, b in zip(this, base, strict=True):
        both = [(x, y) for x, y in zip(a, b, strict=False) if np.isfinite(x) and np.isfinite(y)]
        only_this += sum(np.isfinite(x) and not np.isfinite(y) for x, y in zip(a, b, strict=False))
        only_base += sum(np.isfinite(y) and not np.isfinite(x) for x, y in zip(a, b, strict=False))
        if both:
            mine.append(float(np.mean([x for x, _ in both])))
            theirs.append(float(np.mean([y for _, y in both])))
    x, y = np.asarray(mine), np.asarray(theirs)
    return {
        "seeds": int(x.size),
        "mean_s": _mean(x),
        "baseline_mean_s": _mean(y),
        "wilcoxon_p": _wilcoxon(x, y),
        "only_this": int(only_this),
        "only_baseline": int(only_base),
    }


def speed_edges(speeds: np.ndarray, bins: int = SPEED_BINS) -> list[float]:
    """Bin edges at the quantiles of the finite ``speeds`` [m/s] (fewer bins when values repeat)."""
    finite_speeds = speeds[np.isfinite(speeds)]
    if finite_speeds.size == 0:
        return []
    return sorted({float(e) for e in np.quantile(finite_speeds, np.linspace(0.0, 1.0, bins + 1))})


def held_by_speed(rows: pd.DataFrame, edges: list[float]) -> list[dict[str, Any]]:
    """Held share per speed bin ``[edges[i], edges[i+1]]`` (the last bin closed): ``{"low", "high", "held"}``."""
    speeds = rows["torso_speed_mps"].to_numpy(float)
    held = rows["held"].to_numpy(dtype=bool)
    out = []
    for k, (low, high) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        last = k == len(edges) - 2
        inside = (speeds >= low) & ((speeds <= high) if last else (speeds < high))
        out.append({"low": low, "high": high, "held": rate(int(held[inside].sum()), int(inside.sum()))})
    return out


def _setup_entry(rows: pd.DataFrame, base: pd.DataFrame, avoidable: np.ndarray, edges: list[float]) -> dict[str, Any]:
    """One setup of one method, paired seed by seed with the baseline's rows."""
    held = rows["held"].to_numpy(dtype=bool)
    base_held = base["held"].to_numpy(dtype=bool)
    test = mcnemar(held, base_held)
    ee, base_ee = rows["ee_error_mean"].to_numpy(float), base["ee_error_mean"].to_numpy(float)
    wp, base_wp = rows["waypoints"].to_numpy(float), base["waypoints"].to_numpy(float)
    return {
        "held": rate(int(held.sum()), held.size),
        "held_avoidable": rate(int(held[avoidable].sum()), int(avoidable.sum())) if avoidable.any() else None,
        "vs_baseline": {"only_this": test["a_only"], "only_baseline": test["b_only"], "mcnemar_p": test["p_value"]},
        "joint_violations": int(rows["joint_violation"].sum()),
        "joint_margin_min_rad": _min(rows["joint_margin"].to_numpy(float)),
        "wall_violations": int(rows["wall_violation"].sum()),
        "wall_margin_min_m": _min(rows["wall_margin"].to_numpy(float)),
        "ee_error_mean_m": _mean(ee),
        "ee_error_vs_baseline_wilcoxon_p": _wilcoxon(ee, base_ee),
        "waypoints_mean": _mean(wp),
        "waypoints_vs_baseline_wilcoxon_p": _wilcoxon(wp, base_wp),
        "physical_time_s_mean": _mean(rows["physical_time_s"].to_numpy(float)),
        "waypoint_time": waypoint_time_pairs(rows["waypoint_times"], base["waypoint_times"]),
        "held_by_torso_speed": held_by_speed(rows, edges),
    }


def setup_tables(setups: list[tuple[str, Path]]) -> dict[str, RunTable]:
    """Each setup's runs: its sources (sweep directories or run tables) merged, in order of first mention.

    Raises:
        FileNotFoundError: A missing source.
        ValueError: Sources of one setup that disagree (:func:`compare.campaign.run_table.merge_tables`).
    """
    grouped: dict[str, list[RunTable]] = {}
    for label, path in setups:
        grouped.setdefault(label, []).append(load_table(path))
    return {label: merge_tables(tables, what=f"setup {label!r}") for label, tables in grouped.items()}


def compare_setups(setups: list[tuple[str, Path]], first_seeds: int | None = None) -> dict[str, Any]:
    """Paired comparison of the setups (module docstring); the first label is the baseline.

    ``setups``: ``(label, source)`` pairs, a source a sweep directory or a run table; sources of one
    label are merged. ``first_seeds``: only the first this many seeds every setup ran (per method),
    e.g. to compare sweeps still running on the seeds all of them finished.

    Returns:
        ``{"setups": {label: sources}, "baseline": label, "methods": {method: {"paired_runs",
        "setups": {label: entry}}}}`` with each entry as :func:`_setup_entry` gives it.
    """
    return compare_tables(setup_tables(setups), first_seeds)


def compare_tables(tables: dict[str, RunTable], first_seeds: int | None = None) -> dict[str, Any]:
    """:func:`compare_setups` on runs already loaded: ``{label: table}``, the first the baseline."""
    if len(tables) < 2:
        raise ValueError("give at least two setups (SOURCE[:LABEL] with two labels) to compare")
    labels = list(tables)
    baseline = labels[0]
    rows = {label: t.rows for label, t in tables.items()}
    out: dict[str, Any] = {
        "setups": {label: " + ".join(t.inputs or t.sources) for label, t in tables.items()},
        "baseline": baseline,
        "methods": {},
    }
    for method in rows[baseline]["method"].unique():
        per = {label: t[t["method"] == method].set_index("seed") for label, t in rows.items()}
        if any(p.empty for p in per.values()):
            continue
        seeds = sorted(set.intersection(*(set(p.index) for p in per.values())))[:first_seeds]
        if not seeds:
            continue
        base = per[baseline].loc[seeds]
        avoidable = (base["label"] == "avoidable").to_numpy(dtype=bool)
        edges = speed_edges(base["torso_speed_mps"].to_numpy(float))
        out["methods"][str(method)] = {
            "paired_runs": len(seeds),
            "seeds": [int(seeds[0]), int(seeds[-1])],
            "setups": {label: _setup_entry(p.loc[seeds], base, avoidable, edges) for label, p in per.items()},
        }
    return out


def _pct(entry: dict[str, Any] | None) -> str:
    if not entry or entry["rate"] is None:
        return "–"
    lo, hi = entry["ci95"]
    return f"{100 * entry['rate']:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}]"


def _num(value: float | None, fmt: str) -> str:
    return "–" if value is None else format(value, fmt)


def render_markdown(result: dict[str, Any]) -> str:
    """One table: a row per (method, setup)."""
    lines = [
        f"Baseline: `{result['baseline']}`; each setup paired with it seed by seed "
        "(McNemar on held, Wilcoxon on the mission cost).",
        "",
        "| method | setup | runs | held (Wilson 95 %) | held, avoidable runs | only this / only baseline (p) "
        "| joint / wall violations (worst margin) | mean EE error [m] (p) | waypoints (p) "
        "| time to a waypoint [s] (p; reached only here / only baseline) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for method, m in result["methods"].items():
        for label, e in m["setups"].items():
            vs = e["vs_baseline"]
            paired = (
                "–"
                if label == result["baseline"]
                else f"{vs['only_this']} / {vs['only_baseline']} ({vs['mcnemar_p']:.2g})"
            )
            ee_p = "" if label == result["baseline"] else f" ({_num(e['ee_error_vs_baseline_wilcoxon_p'], '.2g')})"
            wp_p = "" if label == result["baseline"] else f" ({_num(e['waypoints_vs_baseline_wilcoxon_p'], '.2g')})"
            jw = (
                f"{e['joint_violations']} ({_num(e['joint_margin_min_rad'], '+.4f')} rad) / "
                f"{e['wall_violations']} ({_num(e['wall_margin_min_m'], '+.4f')} m)"
            )
            lines.append(
                f"| `{method}` | {label} | {m['paired_runs']} | {_pct(e['held'])} | {_pct(e['held_avoidable'])} "
                f"| {paired} | {jw} | {_num(e['ee_error_mean_m'], '.3f')}{ee_p} "
                f"| {_num(e['waypoints_mean'], '.2f')}{wp_p} | {_waypoint_time_cell(e, label == result['baseline'])} |"
            )
    lines += _speed_lines(result)
    return "\n".join(lines) + "\n"


def _waypoint_time_cell(entry: dict[str, Any], baseline: bool) -> str:
    wt = entry.get("waypoint_time") or {}
    if baseline:
        return _num(wt.get("baseline_mean_s"), ".2f")
    return (
        f"{_num(wt.get('mean_s'), '.2f')} ({_num(wt.get('wilcoxon_p'), '.2g')}; "
        f"{wt.get('only_this', 0)} / {wt.get('only_baseline', 0)})"
    )


def _speed_lines(result: dict[str, Any]) -> list[str]:
    """The held share per bin of the person's peak torso speed, a row per (method, setup)."""
    first = next(iter(result["methods"].values()), None)
    if first is None:
        return []
    bins = next(iter(first["setups"].values())).get("held_by_torso_speed") or []
    if not bins:
        return []
    header = " | ".join(f"{b['low']:.2f}–{b['high']:.2f} m/s" for b in bins)
    lines = [
        "",
        "Held share by the person's peak torso speed (bins: quantiles of the baseline's speeds; "
        "runs held / runs in the bin):",
        "",
        f"| method | setup | {header} |",
        "|---|---|" + "---|" * len(bins),
    ]
    for method, m in result["methods"].items():
        for label, e in m["setups"].items():
            cells = " | ".join(
                f"{_pct(b['held'])} ({b['held']['count']}/{b['held']['runs']})" for b in e["held_by_torso_speed"]
            )
            lines.append(f"| `{method}` | {label} | {cells} |")
    return lines


def _source_spec(spec: str) -> tuple[str, Path]:
    """``type=`` converter: ``SOURCE[:LABEL]`` to ``(label, SOURCE)``, a sweep directory or a run table."""
    path, _, label = spec.partition(":")
    source = Path(path)
    if source.is_dir():
        if not (source / RUNS_DIR).is_dir():
            raise argparse.ArgumentTypeError(f"{path}: no {RUNS_DIR}/ directory (not a sweep)")
    elif not source.is_file():
        raise argparse.ArgumentTypeError(f"{path}: no such directory or run table")
    return label or (source.stem if source.is_file() else source.name), source


def main(argv: list[str] | None = None) -> int:
    """``python -m compare.campaign.setups DIR[:LABEL] DIR[:LABEL] ... --out DIR``."""
    parser = ArgumentParser(
        prog="python -m compare.campaign.setups",
        description="Sweeps of one family compared on the same seeds (the first is the baseline): safety\n"
        "held (McNemar), mission error [m], waypoints and time to each [s] (Wilcoxon), held share by the\n"
        f"person's peak speed [m/s]. Writes {RESULT}, {REPORT} and {SPEED_PLOT} into --out; prints the report.",
    )
    parser.add_argument(
        "sweeps",
        nargs="+",
        type=_source_spec,
        help="sources of two or more setups, each SOURCE or SOURCE:LABEL: a sweep directory or a run table "
        "(runs/LABEL.csv of --save-runs); sources with one label are merged",
    )
    parser.add_argument("--out", type=output_dir, required=True, help="output directory (created)")
    parser.add_argument(
        "--seeds",
        type=positive_int,
        default=None,
        metavar="N",
        help="only the first N seeds every sweep ran, per method (default: all they share)",
    )
    parser.add_argument(
        "--save-runs",
        action="store_true",
        help=f"also write each setup's merged runs to --out/{RUNS_SUBDIR}/LABEL.csv (+ .json: what they were "
        "simulated with), a source for later comparisons once the sweep directories are gone",
    )
    args = parser.parse_args(argv)
    try:
        tables = setup_tables(args.sweeps)
        result = compare_tables(tables, args.seeds)
    except (FileNotFoundError, ValueError) as exc:
        parser.error(str(exc))
    if not result["methods"]:
        parser.error("the sweeps share no (seed, method) run")
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / RESULT, result)
    text = render_markdown(result)
    write_text_atomic(args.out / REPORT, text)
    plot_held_by_speed(result, args.out / SPEED_PLOT)
    if args.save_runs:
        (args.out / RUNS_SUBDIR).mkdir(exist_ok=True)
        for label, table in tables.items():
            write_table(table, args.out / RUNS_SUBDIR / f"{label}.csv")
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
