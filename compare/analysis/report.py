"""Human-readable views of a run: a rich table for the terminal and a Markdown report.

Both read only ``summary.json`` (DESIGN §7); the report links the PNGs of :mod:`compare.analysis.plots`.
"""

from __future__ import annotations

import datetime as dt
import json
import math
from pathlib import Path
from typing import Any

from rich.table import Table
from rich.text import Text

from compare.analysis.avoidability import report_lines
from compare.analysis.metrics import GROUPS
from compare.analysis.results import load_summary

REPORT_FILE = "report.md"
PLOTS_DIR = "plots"  # as compare.analysis.plots.PLOTS_DIR; not imported to keep matplotlib out of the CLI table

_HEADERS: tuple[tuple[str, str], ...] = (
    ("method", "left"),
    ("solve median [µs]", "right"),
    ("solve p99 [µs]", "right"),
    ("realtime ×", "right"),
    ("joint margin [rad]", "right"),
    ("wall margin [m]", "right"),
    ("obstacle margin [m]", "right"),
    ("min obstacle dist. [m]", "right"),
    ("EE final error [m]", "right"),
    ("failures / fallbacks", "right"),
)
_GROUP_COLUMNS = {"joint_limits": 4, "walls": 5, "obstacles": 6}


def _fmt(x: Any, fmt: str = ".3g") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(x, fmt)


def _min_finite(values: list[Any]) -> float | None:
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return min(finite) if finite else None


def _cells(name: str, m: dict[str, Any]) -> list[str]:
    solve = m.get("solve_time_us") or {}
    cells = [
        name,
        _fmt(solve.get("median"), ".1f"),
        _fmt(solve.get("p99"), ".1f"),
        _fmt(m.get("realtime_factor"), ".2f"),
    ]
    for group in GROUPS:
        g = m.get(group)
        if not isinstance(g, dict):
            cells.append("n/a")
            continue
        cell = _fmt(g.get("safety_margin_min"), "+.3f")
        if g.get("violations"):
            cell += f" ({g['violations']}× {g.get('violation_time_s', 0.0):.2f} s)"
        cells.append(cell)
    cells += [
        _fmt(_min_finite(m.get("min_obstacle_distance_m") or []), ".3f"),
        _fmt((m.get("ee_error_m") or {}).get("final"), ".4f"),
        f"{m.get('failures', 0)} / {m.get('fallbacks', 0)}",
    ]
    return cells


def _negative(m: dict[str, Any], group: str) -> bool:
    g = m.get(group)
    return isinstance(g, dict) and g.get("safety_margin_min") is not None and g["safety_margin_min"] < 0


def summary_table(summary: dict[str, Any]) -> Table:
    """Terminal table of a run's ``summary.json``: one row per method, failed methods in red.

    Margins are the worst safety margins (negative = violated, shown in red with the number of
    violations and their total time); ``n/a`` when the scenario has no task of that group.
    """
    title = f"{summary.get('scenario', '?')} (seed {summary.get('seed', '?')}, {_fmt(summary.get('sim_time_s'))} s)"
    table = Table(title=title)
    for header, justify in _HEADERS:
        table.add_column(Text(header), justify=justify)  # type: ignore[arg-type]
    for name, m in (summary.get("methods") or {}).items():
        cells = [Text(cell) for cell in _cells(name, m)]  # Text: no rich markup in names or messages
        for group, col in _GROUP_COLUMNS.items():
            if _negative(m, group):
                cells[col].stylize("bold red")
        if m.get("failures") or m.get("fallbacks"):
            cells[-1].stylize("yellow")
        table.add_row(*cells)
    for name, message in (summary.get("errors") or {}).items():
        table.add_row(Text(name, style="red"), Text(f"failed: {message}", style="red"), *[""] * (len(_HEADERS) - 2))
    return table


def _markdown_table(headers: list[str], rows: list[list[str]]) -> str:
    def esc(cell: str) -> str:
        return cell.replace("|", "\\|")

    lines = ["| " + " | ".join(esc(h) for h in headers) + " |"]
    lines.append("|" + "|".join("---" if i == 0 else "---:" for i in range(len(headers))) + "|")
    lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def render_report(results_dir: Path, command: str | None = None) -> Path:
    """Write ``results_dir/report.md``: provenance header, results table, violations, plots.

    Args:
        results_dir: Run directory with ``summary.json`` (plots are linked if present).
        command: Command line that produced the results, shown in the header.

    Returns:
        Path of the report.
    """
    results_dir = Path(results_dir)
    summary = load_summary(results_dir)
    versions: dict[str, str] = summary.get("versions") or {}
    methods: dict[str, dict[str, Any]] = summary.get("methods") or {}
    now = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    out: list[str] = [
        f"# Results: {summary.get('scenario', '?')} (seed {summary.get('seed', '?')})",
        "",
        f"- generated: {now}",
        f"- simulated time: {_fmt(summary.get('sim_time_s'))} s",
        f"- git commit: `{versions.get('git_commit', 'unknown')}`",
        f"- machine: {versions.get('cpu', 'unknown')} ({versions.get('machine', '?')}), "
        f"Python {versions.get('python', '?')}",
    ]
    if command:
        out.append(f"- command: `{command}`")
    if (results_dir / "config.toml").is_file():
        out.append(
            f"- configuration: [config.toml](config.toml) (reproduce: `tpik-compare run {results_dir / 'config.toml'}`)"
        )
    libs = {k: v for k, v in versions.items() if k not in {"git_commit", "cpu", "machine", "python"}}
    if libs:
        out.append("- versions: " + ", ".join(f"{k} {v}" for k, v in sorted(libs.items())))
    out += ["", "## Summary", ""]
    if methods:
        out.append(_markdown_table([h for h, _ in _HEADERS], [_cells(n, m) for n, m in methods.items()]))
        out += [
            "",
            "Margins: worst signed distance to the safety threshold over the run (negative = violated;"
            " in brackets: number of violation episodes × total time). Obstacle margins and distances use the"
            " ground-truth geometry.",
        ]
    else:
        out.append("No method finished.")
    errors = summary.get("errors") or {}
    if errors:
        out += ["", "## Failed methods", ""]
        out += [f"- `{name}`: {message}" for name, message in errors.items()]
    out += _figures(results_dir, "*.png", "Plots")
    return _write_markdown(results_dir / REPORT_FILE, out)


# --------------------------------------------------------------------------------------- sweeps

SWEEP_REPORT_FILE = "sweep_report.md"


def _pct(x: Any) -> str:
    return "–" if x is None else f"{100.0 * float(x):.1f} %"


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
    headers = [
        "method",
        "runs",
        "joint-limit or wall violation",
        "obstacle violation",
        "worst joint margin [rad]",
        "worst wall margin [m]",
        "runs with failures / fallbacks",
        "failures / fallbacks (steps)",
        "unsafe commands",
    ]
    rows = []
    for name, m in methods.items():
        worst = m.get("worst_safety_margin") or {}
        rows.append(
            [
                name,
                f"{m.get('runs', 0)}" + (f" (+{m['errors']} errors)" if m.get("errors") else ""),
                _pct(m.get("share_runs_limit_or_wall_violation")),
                _pct(m.get("share_runs_obstacle_violation")),
                _fmt(worst.get("joint_limits"), "+.4f"),
                _fmt(worst.get("walls"), "+.4f"),
                f"{_pct(m.get('share_runs_with_failures'))} / {_pct(m.get('share_runs_with_fallbacks'))}",
                f"{m.get('failures', 0)} / {m.get('fallbacks', 0)}",
                str(m.get("unsafe_commands", 0)),
            ]
        )
    out.append(_markdown_table(headers, rows) if rows else "No finished run.")
    out += [
        "",
        "A violation is a safety-margin episode beyond the metrics' tolerance (1 mm / 1 mrad); worst margins are"
        " exact. Obstacle distances use the ground-truth geometry. Unsafe commands (non-finite or beyond the"
        " velocity limits) are counted on what the loop sent: 0 by construction.",
        "",
        "## Cost and ISO/TS 15066 margin",
        "",
    ]
    headers = [
        "method",
        "solve median [µs]",
        "median of run p99 [µs]",
        "p95 of run p99 [µs]",
        "max [µs]",
        "realtime × (median)",
        "ISO min margin [m]",
        "runs below S_p",
    ]
    rows = []
    for name, m in methods.items():
        solve = m.get("solve_time_us") or {}
        pct = m.get("solve_time_percentiles_us") or {}
        iso = m.get("iso15066") or {}
        rows.append(
            [
                name,
                _fmt(solve.get("median_of_medians"), ".0f"),
                _fmt(solve.get("median_of_p99"), ".0f"),
                _fmt(pct.get("p95_of_run_p99"), ".0f"),
                _fmt(solve.get("max"), ".0f"),
                _fmt((m.get("realtime_factor") or {}).get("median"), ".1f"),
                _fmt(iso.get("min_margin_m"), "+.3f"),
                _pct(iso.get("share_runs_below_zero")),
            ]
        )
    if rows:
        out.append(_markdown_table(headers, rows))
    out += [
        "",
        "ISO margin: measured separation minus the protective separation distance S_p of ISO/TS 15066 clause"
        " 5.5.4 (formula (1)), with the human speed estimated from the sensing; negative = the arm could not stop"
        " before contact if the person kept coming (compare/analysis/iso15066.py).",
    ]
    out += report_lines(summary)  # avoidable / unavoidable obstacle violations (oracle)
    failed = summary.get("failed_runs") or []
    if failed:
        out += ["", "## Failed runs", ""] + [f"- {line}" for line in failed[:50]]
    out += _figures(sweep_dir, "sweep_*.png", "Figures")
    return _write_markdown(sweep_dir / SWEEP_REPORT_FILE, out)


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


def _write_markdown(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines).rstrip() + "\n", encoding="utf-8")
    return path
