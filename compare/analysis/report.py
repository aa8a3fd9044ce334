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

from compare.analysis.atomic_files import write_text_atomic
from compare.analysis.avoidability import report_lines
from compare.analysis.metrics import GROUPS, group_summary, summary_groups
from compare.analysis.person_speeds import report_lines as person_speed_lines
from compare.analysis.results import REPORT_FILE, SWEEP_REPORT_FILE, load_summary
from compare.analysis.statistics import rate_value

PLOTS_DIR = "plots"  # as compare.analysis.plots.PLOTS_DIR; not imported to keep matplotlib out of the CLI table

_GROUP_HEADERS = {"joint_limits": "joint margin [rad]", "walls": "wall margin [m]", "obstacles": "obstacle margin [m]"}
_FIRST_GROUP_COLUMN = 4


def _groups(methods: dict[str, dict[str, Any]]) -> list[str]:
    """:data:`GROUPS`, then any other set-task group of some method (a new safety task's)."""
    found = [g for m in methods.values() for g in summary_groups(m)]
    return list(dict.fromkeys([*GROUPS, *found]))


def _headers(groups: list[str]) -> list[tuple[str, str]]:
    return [
        ("method", "left"),
        ("solve median [µs]", "right"),
        ("solve p99 [µs]", "right"),
        ("realtime ×", "right"),
        *[(_GROUP_HEADERS.get(g, f"{g} margin"), "right") for g in groups],
        ("min obstacle dist. [m]", "right"),
        ("EE final error [m]", "right"),
        ("degraded / failed / fallback steps", "right"),
    ]


def fmt_number(x: Any, fmt: str = ".3g") -> str:
    """``x`` formatted with ``fmt``; "–" for None and non-finite numbers."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(x, fmt)


def _min_finite(values: list[Any]) -> float | None:
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return min(finite) if finite else None


def _cells(name: str, m: dict[str, Any], groups: list[str]) -> list[str]:
    solve = m.get("solve_time_us") or {}
    cells = [
        name,
        fmt_number(solve.get("median"), ".1f"),
        fmt_number(solve.get("p99"), ".1f"),
        fmt_number(m.get("realtime_factor"), ".2f"),
    ]
    for group in groups:
        g = group_summary(m, group)
        if g is None:
            cells.append("n/a")
            continue
        cell = fmt_number(g.get("safety_margin_min"), "+.3f")
        if g.get("violations"):
            cell += f" ({g['violations']}× {g.get('violation_time_s', 0.0):.2f} s)"
        cells.append(cell)
    cells += [
        fmt_number(_min_finite(m.get("min_obstacle_distance_m") or []), ".3f"),
        fmt_number((m.get("ee_error_m") or {}).get("final"), ".4f"),
        f"{(m.get('status_steps') or {}).get('degraded', '–')} / {m.get('failures', 0)} / {m.get('fallbacks', 0)}",
    ]
    return cells


_ACCOUNTING_HEADERS = [
    "method",
    "steps ok / degraded / failed",
    "fallback steps",
    "time below a physical threshold [s]",
    "deadline misses",
    "warm-up solves",
]


def misses_cell(m: dict[str, Any]) -> str:
    """Deadline misses, with the solves kept once the hypervisor's steal was taken out ("+ k steal").

    After ``tpik-compare recheck-misses``: how many misses were re-timed and how many of them
    the method's own cost at that state reproduced (:mod:`compare.campaign.miss_recheck`).
    """
    excused = m.get("deadline_steal_excused")
    if isinstance(excused, dict):
        excused = excused.get("steps")
    text = str(m.get("deadline_misses", "–"))
    if isinstance(excused, int) and excused > 0:
        text += f" (+{excused} steal)"
    recheck = m.get("deadline_recheck")  # tpik-compare recheck-misses (compare.campaign.miss_recheck)
    if isinstance(recheck, dict) and recheck.get("rechecked"):
        text += f"; re-timed {recheck['rechecked']}: {recheck.get('reproduced', 0)} reproduced"
    return text


def _accounting_cells(name: str, m: dict[str, Any]) -> list[str]:
    """One row of the step accounting (DESIGN §3: the same definitions for every method)."""
    st = m.get("status_steps") or {}
    return [
        name,
        " / ".join(str(st.get(k, "–")) for k in ("ok", "degraded", "failed")),
        str(m.get("fallback_steps", m.get("fallbacks", "–"))),
        fmt_number(m.get("time_below_physical_s"), ".2f"),
        misses_cell(m),
        str(m.get("warmup_steps", "–")),
    ]


_ACCOUNTING_NOTE = (
    "Every step of every method by the same rules (DESIGN §3): failed = no usable command (a solver-domain"
    " error, a backend's no-solution, a command the loop's guard refused: the fallback acts); degraded = the"
    " solver reports a relaxation (slack, level given up, damping, velocity scaling) or its command misses the"
    " reference rate of a set task at or past an activation threshold; ok otherwise. Deadline: the control"
    " period (or the solver time limit). Warm-up solves are made before the first step and are not timed."
)


def _negative(m: dict[str, Any], group: str) -> bool:
    g = group_summary(m, group)
    return g is not None and g.get("safety_margin_min") is not None and g["safety_margin_min"] < 0


def summary_table(summary: dict[str, Any], narrow: bool = False) -> Table:
    """Terminal table of a run's ``summary.json``: one row per method, failed methods in red.

    Margins are the worst safety margins (negative = violated, shown in red with the number of
    violations and their total time); ``n/a`` when the scenario has no task of that group. A
    set-task group beyond joint limits, walls and obstacles (a new safety task's) gets its own
    column. ``narrow``: one row per figure and one column per method instead (an 80-column
    terminal).
    """
    sim_time = fmt_number(summary.get("sim_time_s"))
    title = f"{summary.get('scenario', '?')} (seed {summary.get('seed', '?')}, {sim_time} s)"
    table = Table(title=title)
    methods = summary.get("methods") or {}
    groups = _groups(methods)
    headers = _headers(groups)
    rows: list[list[Text]] = []
    for name, m in methods.items():
        cells = [Text(cell) for cell in _cells(name, m, groups)]  # Text: no rich markup in names or messages
        for col, group in enumerate(groups, start=_FIRST_GROUP_COLUMN):
            if _negative(m, group):
                cells[col].stylize("bold red")
        if m.get("failures") or m.get("fallbacks"):
            cells[-1].stylize("yellow")
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


def markdown_table(headers: list[str], rows: list[list[str]]) -> str:
    """A Markdown table (first column left-aligned, the others right-aligned; "|" escaped)."""

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
        f"- simulated time: {fmt_number(summary.get('sim_time_s'))} s",
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
        groups = _groups(methods)
        rows = [_cells(n, m, groups) for n, m in methods.items()]
        out.append(markdown_table([h for h, _ in _headers(groups)], rows))
        out += [
            "",
            "Margins: worst signed distance to the safety threshold over the run (negative = violated;"
            " in brackets: number of violation episodes × total time). Obstacle margins and distances use the"
            " ground-truth geometry.",
            "",
            "## Step accounting",
            "",
            markdown_table(_ACCOUNTING_HEADERS, [_accounting_cells(n, m) for n, m in methods.items()]),
            "",
            _ACCOUNTING_NOTE,
        ]
    else:
        out.append("No method finished.")
    errors = summary.get("errors") or {}
    if errors:
        out += ["", "## Failed methods", ""]
        out += [f"- `{name}`: {message}" for name, message in errors.items()]
    out += _figures(results_dir, "*.png", "Plots")
    return write_markdown(results_dir / REPORT_FILE, out)


# --------------------------------------------------------------------------------------- sweeps


def _pct(x: Any) -> str:
    value = rate_value(x)
    return "–" if value is None else f"{100.0 * value:.1f} %"


def rate_with_ci(x: Any) -> str:
    """``1.2 % [0.6, 2.3] (12/1000)`` from a rate entry (Wilson 95 % interval)."""
    if not isinstance(x, dict) or x.get("rate") is None:
        return _pct(x)
    interval = x.get("ci95")
    ci = f" [{100.0 * interval[0]:.1f}, {100.0 * interval[1]:.1f}]" if interval else ""
    return f"{100.0 * float(x['rate']):.1f} %{ci} ({x['count']}/{x['runs']})"


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
    other_groups = list(
        dict.fromkeys(g for m in methods.values() for g in (m.get("worst_safety_margin") or {}) if g not in GROUPS)
    )
    headers = [
        "method",
        "runs",
        "joint-limit or wall violation",
        "obstacle violation",
        "worst joint margin [rad]",
        "worst wall margin [m]",
        *[f"worst {g} margin" for g in other_groups],
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
                rate_with_ci(m.get("share_runs_limit_or_wall_violation")),
                rate_with_ci(m.get("share_runs_obstacle_violation")),
                fmt_number(worst.get("joint_limits"), "+.4f"),
                fmt_number(worst.get("walls"), "+.4f"),
                *[fmt_number(worst.get(g), "+.4f") for g in other_groups],
                f"{_pct(m.get('share_runs_with_failures'))} / {_pct(m.get('share_runs_with_fallbacks'))}",
                f"{m.get('failures', 0)} / {m.get('fallbacks', 0)}",
                str(m.get("unsafe_commands", 0)),
            ]
        )
    out.append(markdown_table(headers, rows) if rows else "No finished run.")
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
    rows = []
    for name, m in methods.items():
        st = m.get("status_steps") or {}
        steps = m.get("steps") or 0
        failed_share = f" ({100.0 * st.get('failed', 0) / steps:.2f} %)" if steps else ""
        rows.append(
            [
                name,
                str(steps),
                " / ".join(str(st.get(k, "–")) for k in ("ok", "degraded", "failed")) + failed_share,
                str(m.get("fallback_steps", "–")),
                fmt_number(m.get("time_below_physical_s"), ".2f"),
                rate_with_ci(m.get("share_runs_below_physical")),
                misses_cell(m),
                str(m.get("warmup_steps", "–")),
            ]
        )
    headers = [
        "method",
        "steps",
        "ok / degraded / failed (failed share)",
        "fallback steps",
        "time below a physical threshold [s]",
        "runs below a physical threshold",
        "deadline misses",
        "warm-up solves",
    ]
    out.append(markdown_table(headers, rows) if rows else "No finished run.")
    out += [
        "",
        _ACCOUNTING_NOTE,
        "",
        "## Cost and ISO/TS 15066 margin",
        "",
    ]
    headers = [
        "method",
        "solve median [µs] (bootstrap 95 %)",
        "median of run p99 [µs]",
        "p95 of run p99 [µs]",
        "worst step after warm-up [µs] (wall / limit clock)",
        "realtime × (median)",
        "ISO min margin [m]",
        "runs below S_p",
    ]
    rows = []
    for name, m in methods.items():
        solve = m.get("solve_time_us") or {}
        pct = m.get("solve_time_percentiles_us") or {}
        iso = m.get("iso15066") or {}
        ci = solve.get("median_of_medians_ci95")
        rows.append(
            [
                name,
                fmt_number(solve.get("median_of_medians"), ".0f") + (f" [{ci[0]:.0f}, {ci[1]:.0f}]" if ci else ""),
                fmt_number(solve.get("median_of_p99"), ".0f"),
                fmt_number(pct.get("p95_of_run_p99"), ".0f"),
                fmt_number(solve.get("max"), ".0f") + " / " + fmt_number(solve.get("max_on_limit_clock"), ".0f"),
                fmt_number((m.get("realtime_factor") or {}).get("median"), ".1f"),
                fmt_number(iso.get("min_margin_m"), "+.3f"),
                _pct(iso.get("share_runs_below_zero")),
            ]
        )
    if rows:
        out.append(markdown_table(headers, rows))
    out += [
        "",
        "ISO margin: measured separation minus the protective separation distance S_p of ISO/TS 15066 clause"
        " 5.5.4 (formula (1)), with the human speed estimated from the sensing; negative = the arm could not stop"
        " before contact if the person kept coming (compare/analysis/iso15066.py).",
    ]
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
