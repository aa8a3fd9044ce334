"""Human-readable views of results: a run's table (terminal and Markdown), a sweep's Markdown report.

They read only ``summary.json`` / ``sweep_summary.json`` (docs/design.md §7), and show the columns of the
registered metrics (:mod:`compare.analysis.metric`); the sweep report links the PNGs of
:mod:`compare.analysis.plots`.
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rich.table import Table
from rich.text import Text

from compare.analysis.atomic_files import write_text_atomic
from compare.analysis.avoidability import report_lines
from compare.analysis.metric import Column, Entry, Section, fmt_number
from compare.analysis.metrics import registered_metrics
from compare.analysis.person_speeds import report_lines as person_speed_lines
from compare.analysis.results import SWEEP_REPORT_FILE

PLOTS_DIR = "plots"  # as compare.analysis.plots.PLOTS_DIR; not imported to keep matplotlib out of the CLI table


def _run_columns(entries: Sequence[Entry]) -> list[Column]:
    """The run table's columns: those of every registered metric, in registration order."""
    return [column for metric in registered_metrics() for column in metric.run_table(entries)]


def summary_table(summary: dict[str, Any], narrow: bool = False) -> Table:
    """Terminal table of a run's ``summary.json``: one row per method, failed methods in red.

    One column per figure of the registered metrics (:meth:`~compare.analysis.metric.Metric.run_table`).
    Margins are the worst safety margins (negative = violated, shown in red with the number of
    violations and their total time); ``n/a`` when the scenario has no task of that group. A
    set-task group beyond joint limits, walls and obstacles (a new safety task's) gets its own
    column. ``narrow``: one row per figure and one column per method instead (an 80-column
    terminal).
    """
    sim_time = fmt_number(summary.get("sim_time_s"))
    title = f"{summary.get('scenario', '?')} (seed {summary.get('seed', '?')}, {sim_time} s)"
    table = Table(title=title)
    methods: dict[str, dict[str, Any]] = summary.get("methods") or {}
    columns = _run_columns(list(methods.values()))
    headers = [("method", "left"), *[(column.header, "right") for column in columns]]
    rows: list[list[Text]] = []
    for name, m in methods.items():
        cells = [Text(name)]  # Text: no rich markup in names or messages
        for column in columns:
            cell = Text(column.cell(m))
            style = column.style(m)
            if style:
                cell.stylize(style)
            cells.append(cell)
        rows.append(cells)
    for name, message in (summary.get("errors") or {}).items():
        rows.append(
            [Text(name, style="red"), Text(f"failed: {message}", style="red"), *[Text("")] * (len(headers) - 2)]
        )
    if narrow:
        table.add_column(Text(""), justify="left")
        for row in rows:
            table.add_column(row[0], justify="right")
        for k, (header, _) in enumerate(headers[1:], start=1):
            table.add_row(Text(header), *[row[k] for row in rows])
        return table
    for header, justify in headers:
        table.add_column(Text(header), justify=justify)  # type: ignore[arg-type]
    for row in rows:
        table.add_row(*row)
    return table


def summary_markdown(summary: dict[str, Any]) -> str:
    """Markdown form of :func:`summary_table`: the same columns and cells, one row per method.

    A failed method's row reads ``failed: <message>`` (first line of the message).
    """
    methods: dict[str, dict[str, Any]] = summary.get("methods") or {}
    columns = _run_columns(list(methods.values()))
    headers = ["method", *[column.header for column in columns]]
    rows = [[name, *[column.cell(m) for column in columns]] for name, m in methods.items()]
    for name, message in (summary.get("errors") or {}).items():
        first = str(message).strip().splitlines()[0] if str(message).strip() else "unknown error"
        rows.append([name, f"failed: {first}", *[""] * (len(headers) - 2)])
    return markdown_table(headers, rows)


def markdown_table(headers: list[str], rows: list[list[str]], right: bool = True) -> str:
    """A Markdown table (first column left-aligned, the others right-aligned unless not ``right``; "|" escaped)."""

    def esc(cell: str) -> str:
        return cell.replace("|", "\\|")

    lines = ["| " + " | ".join(esc(h) for h in headers) + " |"]
    lines.append("|" + "|".join("---:" if i and right else "---" for i in range(len(headers))) + "|")
    lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


_ACCOUNTING_NOTE = (
    "Every step of every method by the same rules (docs/design.md §3): failed = no usable command (a solver-domain"
    " error, a backend's no-solution, a command the loop's guard refused: the fallback acts); degraded = the"
    " solver reports a relaxation (slack, level given up, damping, velocity scaling) or its command misses the"
    " reference rate of a set task at or past an activation threshold; ok otherwise. Deadline: the control"
    " period (or the solver time limit). Warm-up solves are made before the first step and are not timed."
)


# --------------------------------------------------------------------------------------- sweeps


def _sweep_columns(entries: Sequence[Entry], section: Section) -> list[Column]:
    """The sweep report's columns of one table: those of every registered metric in ``section``."""
    columns = [column for metric in registered_metrics() for column in metric.sweep_table(entries)]
    return [column for column in columns if column.section == section]


def _sweep_table(methods: dict[str, dict[str, Any]], section: Section, runs: bool = False) -> str | None:
    """One table of the sweep report, one row per method (``runs``: a column of finished runs first)."""
    columns = _sweep_columns(list(methods.values()), section)
    if not methods or not columns:
        return None
    headers = ["method", *(["runs"] if runs else []), *[column.header for column in columns]]
    rows = []
    for name, m in methods.items():
        finished = [f"{m.get('runs', 0)}" + (f" (+{m['errors']} errors)" if m.get("errors") else "")]
        rows.append([name, *(finished if runs else []), *[column.cell(m) for column in columns]])
    return markdown_table(headers, rows)


def render_sweep_report(sweep_dir: Path, command: str | None = None) -> Path:
    """Write ``sweep_dir/sweep_report.md`` from ``sweep_summary.json`` and the sweep plots.

    Per method: runs, share of runs with a joint-limit or wall safety violation (the goal for
    TPIK and HQP is 0), with an obstacle violation, with failures / fallbacks, unsafe commands,
    solve time percentiles, ISO/TS 15066 margin; then the figures (minimum-distance CDF, ISO
    margin CDF, solve time vs violation) and the provenance (command, executor, machine).

    Args:
        sweep_dir: Sweep directory (``sweep_summary.json`` must exist).
        command: Command line; default the one stored in the summary's ``campaign`` entry.

    Returns:
        Path of the report.
    """
    sweep_dir = Path(sweep_dir)
    summary = json.loads((sweep_dir / "sweep_summary.json").read_text(encoding="utf-8"))
    versions: dict[str, str] = summary.get("versions") or {}
    campaign = summary.get("campaign") or {}
    methods: dict[str, dict[str, Any]] = summary.get("methods") or {}
    now = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    cmd = command or campaign.get("command")
    out = [
        f"# Sweep report: {summary.get('scenario', '?')} ({summary.get('runs', 0)} runs)",
        "",
        f"- generated: {now}",
        f"- git commit: `{versions.get('git_commit', 'unknown')}`",
        f"- machine: {versions.get('cpu', 'unknown')} ({versions.get('machine', '?')}), "
        f"Python {versions.get('python', '?')}",
    ]
    if cmd:
        out.append(f"- command: `{cmd}`")
    if campaign:
        wall = campaign.get("wall_time_s")
        per = campaign.get("wall_time_per_run_s")
        out.append(
            f"- executor: {campaign.get('executor', '?')}"
            + (f", {campaign['workers']} workers" if campaign.get("workers") else "")
            + (f", cluster {campaign['address']}" if campaign.get("address") not in (None, "local") else "")
            + f"; this invocation ran {campaign.get('runs_executed', '?')}"
            + f" of {campaign.get('runs_requested', '?')} runs"
            + (f" in {wall / 60.0:.1f} min ({per:.2f} s per run)" if wall and per else "")
            + _throughput(campaign)
        )
    plant = campaign.get("plant")
    if plant:
        drive = f", {plant['drive']} joint drive" if plant.get("drive") else ""
        if plant.get("drive_bandwidth_rad_s"):
            drive += f" (λ = {plant['drive_bandwidth_rad_s']:g} rad/s)"
        out.append(f"- plant: {plant.get('simulation', '?')} simulation{drive}, {plant.get('sensing', '?')} sensing")
    if summary.get("skipped_finished_runs"):
        out.append(f"- resumed: {summary['skipped_finished_runs']} runs were already finished")
    out += ["", "## Safety and failures per method", ""]
    out.append(_sweep_table(methods, "safety", runs=True) or "No finished run.")
    out += [
        "",
        "A violation is a safety-margin episode beyond the metrics' tolerance (1 mm / 1 mrad); worst margins are"
        " exact. Obstacle distances use the ground-truth geometry. Unsafe commands (non-finite or beyond the"
        " velocity limits) are counted on what the loop sent: 0 by construction. Rates: share of runs, Wilson 95 %"
        " interval in brackets, (runs with / runs).",
        "",
        "## Step accounting per method",
        "",
    ]
    out.append(_sweep_table(methods, "accounting") or "No finished run.")
    out += [
        "",
        _ACCOUNTING_NOTE,
        "",
        "## Cost and ISO/TS 15066 margin",
        "",
    ]
    cost = _sweep_table(methods, "cost")
    if cost:
        out.append(cost)
    out += [
        "",
        "ISO margin: measured separation minus the protective separation distance S_p of ISO/TS 15066 clause"
        " 5.5.4 (formula (1)), with the human speed estimated from the sensing; negative = the arm could not stop"
        " before contact if the person kept coming (compare/analysis/iso15066.py).",
    ]
    other = _sweep_table(methods, "other")
    if other:
        out += ["", "## Other metrics per method", "", other]
    out += _paired_section(summary.get("paired") or {})
    out += report_lines(summary)  # obstacle violations by the run's verdict
    out += person_speed_lines(summary)
    failed = summary.get("failed_runs") or []
    if failed:
        out += ["", "## Failed runs", ""] + [f"- {line}" for line in failed[:50]]
    out += _figures(sweep_dir, "sweep_*.png", "Figures")
    return write_markdown(sweep_dir / SWEEP_REPORT_FILE, out)


def _paired_section(paired: dict[str, Any]) -> list[str]:
    """Markdown of the paired per-seed comparisons (exact McNemar p-values)."""
    if not paired:
        return []
    out = ["", "## Paired comparisons (same seeds, exact McNemar test)", ""]
    headers = [
        "pair (a vs b)",
        "runs",
        "joint-limit/wall violation: a only / b only",
        "p",
        "obstacle violation: a only / b only",
        "p",
    ]
    rows = []
    for pair, entry in paired.items():
        lw = entry.get("limit_or_wall_violation") or {}
        ob = entry.get("obstacle_violation") or {}
        rows.append(
            [
                pair,
                str(entry.get("runs", "–")),
                f"{lw.get('a_only', '–')} / {lw.get('b_only', '–')}",
                fmt_number(lw.get("p_value"), ".3g"),
                f"{ob.get('a_only', '–')} / {ob.get('b_only', '–')}",
                fmt_number(ob.get("p_value"), ".3g"),
            ]
        )
    out.append(markdown_table(headers, rows))
    out += [
        "",
        'Only the seeds where exactly one method had the outcome ("a only", "b only") carry information; p is'
        ' the two-sided exact binomial test of those against 1/2. p < 0.05 supports "one of the two is better" on'
        " this family of scenarios, not a general ranking.",
    ]
    return out


def _throughput(campaign: dict[str, Any]) -> str:
    """The throughput of a local sweep (docs/benchmarks.md, "Campaign throughput").

    E.g. ``", 2.7 CPU-h (4% of it in the kernel), 15.9 simulated s per CPU s"``.
    """
    cpu, rate = campaign.get("cpu_time_s"), campaign.get("sim_s_per_cpu_s")
    if not cpu or not rate:
        return ""
    system = campaign.get("cpu_system_s")
    kernel = f" ({system / cpu:.0%} of it in the kernel)" if system is not None else ""
    steal = campaign.get("steal_time_s")
    stolen = f", hypervisor steal {steal:.1f} s" if steal is not None else ""
    return f", {cpu / 3600.0:.2f} CPU-h{kernel}, {rate:.1f} simulated s per CPU s{stolen}"


def _figures(directory: Path, pattern: str, title: str) -> list[str]:
    """Markdown section embedding ``directory/plots/<pattern>``, or a hint to draw them."""
    plots_dir = directory / PLOTS_DIR
    plots = sorted(plots_dir.glob(pattern)) if plots_dir.is_dir() else []
    out = ["", f"## {title}", ""]
    for p in plots:
        rel = p.relative_to(directory).as_posix()
        out += [f"### {p.stem}", "", f"![{p.stem}]({rel})", ""]
    if not plots:
        out.append(f"No plots yet: `tpik-compare plot {directory}`.")
    return out


def write_markdown(path: Path, lines: list[str]) -> Path:
    """Write ``lines`` as one Markdown file, atomically; returns ``path``."""
    write_text_atomic(path, "\n".join(lines).rstrip() + "\n")
    return path
