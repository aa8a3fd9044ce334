"""A run's Markdown report, ``report.md``, written next to its ``summary.json`` (docs/design.md §7).

It holds the run's results table (:func:`compare.analysis.report.summary_markdown`: the columns of
the registered metrics, the cells of the terminal table), links to the plots of ``plots/`` that
exist, and, for a case config (``[scenario] kind`` ``case1`` or ``case2`` with a moving person),
the paper's claims of Sec. IV (:mod:`compare.analysis.claims`) checked on each method's per-step
table. The claims read the run up to
:attr:`~compare.analysis.claims.ClaimContext.run_time_needed_s` (the person's last keyframe plus
2 s); a method whose run is shorter is not checked, and the report says so.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from compare.analysis.claims import (
    DEACTIVATION_GRACE_S,
    ClaimContext,
    claims_for_run,
    claims_table,
    context_from_config,
)
from compare.analysis.person_speeds import keyframe_speeds
from compare.analysis.report import PLOTS_DIR, summary_markdown, write_markdown
from compare.analysis.results import CONFIG_FILE, REPLAY_FILE, RUN_REPORT_FILE, load_summary
from compare.config import Config, ConfigError, load_config

_MARGIN_NOTE = (
    "Margins: the worst safety margin of each set-task group over the run, in the group's unit (negative ="
    " violated; in brackets the violation episodes and their total time); n/a when the scenario has no task of"
    " that group. Obstacle distances: the ground truth in simulation, the measured ones on hardware."
    " Degraded / failed / fallback steps: the same accounting for every method (docs/design.md §3)."
)


def render_run_report(run_dir: Path, config: Config | None = None) -> Path:
    """Write ``run_dir/report.md`` (atomically) from ``summary.json``, ``plots/`` and the per-step tables.

    Args:
        run_dir: A run directory (``summary.json`` must exist).
        config: The run's config, for the claims; default the directory's ``config.toml`` (none:
            no claims).

    Returns:
        Path of the report.
    """
    run_dir = Path(run_dir)
    summary = load_summary(run_dir)
    out = _header(run_dir, summary)
    out += ["", "## Results", "", summary_markdown(summary), "", _MARGIN_NOTE]
    out += _plot_lines(run_dir)
    out += _claims_lines(run_dir, summary, config)
    return write_markdown(run_dir / RUN_REPORT_FILE, out)


def _header(run_dir: Path, summary: dict[str, Any]) -> list[str]:
    methods: dict[str, dict[str, Any]] = summary.get("methods") or {}
    versions: dict[str, Any] = summary.get("versions") or {}
    first = next(iter(methods.values()), {})
    out = [
        f"# Run report: {summary.get('scenario', '?')} (seed {summary.get('seed', '?')},"
        f" {summary.get('sim_time_s', '?')} s)",
        "",
        f"- robot: {first.get('robot', '?')}; sensing: {first.get('sensing', '?')}",
        f"- git commit: `{versions.get('git_commit', 'unknown')}`; project {versions.get('project', '?')}",
    ]
    files = [f"[{name}]({name})" for name in (CONFIG_FILE, REPLAY_FILE) if (run_dir / name).is_file()]
    if files:
        out.append(f"- config: {' and '.join(files)} (config hash `{summary.get('config_hash', '?')}`)")
    oracle = summary.get("oracle")
    if isinstance(oracle, dict) and oracle.get("label"):
        witness = f" (witness {oracle['witness']})" if oracle.get("witness") else ""
        out.append(f"- the run's verdict: {oracle['label']}{witness}")
    return out


def _plot_lines(run_dir: Path) -> list[str]:
    """Links to the PNGs of ``plots/``, relative to the run directory (only those that exist)."""
    plots_dir = run_dir / PLOTS_DIR
    plots = sorted(plots_dir.glob("*.png")) if plots_dir.is_dir() else []
    out = ["", "## Plots", ""]
    out += [f"- [{p.name}]({p.relative_to(run_dir).as_posix()})" for p in plots]
    if not plots:
        out.append(f"No plots: `tpik-compare plot {run_dir}` draws them.")
    return out


def _claims_lines(run_dir: Path, summary: dict[str, Any], config: Config | None) -> list[str]:
    """The claims section: a case config's claims per method, or why a method was not checked."""
    if config is None:
        if not (run_dir / CONFIG_FILE).is_file():
            return []
        try:
            config, _ = load_config(run_dir / CONFIG_FILE)
        except ConfigError as exc:
            return ["", "## The paper's claims (Sec. IV)", "", f"Not checked: {exc}"]
    if config.scenario.kind not in ("case1", "case2"):
        return []
    out = ["", "## The paper's claims (Sec. IV)", ""]
    ctx = context_from_config(config)
    if ctx is None:
        return [*out, "Not checked: the person of this case config never moves."]
    methods: dict[str, dict[str, Any]] = summary.get("methods") or {}
    covered = [name for name, m in methods.items() if _covers(m, ctx)]
    short = [name for name in methods if name not in covered]
    if covered:
        torso, hand = keyframe_speeds(config)
        label = f"{config.scenario.name} (torso {torso:.2g} m/s, hand {hand:.2g} m/s)"
        out += [
            f"Each claim measured on the run ({config.scenario.kind}; compare/analysis/claims.py): ✓ held, ✗ not,"
            " with what was measured.",
            "",
            claims_table([(label, claims_for_run(run_dir, covered, config))]),
        ]
        out.append("")
    if short:
        shortest = min(float(methods[name].get("sim_time_s") or 0.0) for name in short)
        out.append(
            f"Not checked for {', '.join(short)}: the run covers {shortest:g} s, the claims read it to"
            f" {ctx.run_time_needed_s:g} s ({DEACTIVATION_GRACE_S:g} s after the person's last keyframe at"
            f" {ctx.person.t_gone:g} s)."
        )
    return out


def _covers(entry: dict[str, Any], ctx: ClaimContext) -> bool:
    """Whether one method's run lasted as long as the claims read it (within one control period)."""
    run_s = float(entry.get("sim_time_s") or 0.0)
    dt = float(entry.get("dt") or 0.0)
    return run_s + dt >= ctx.run_time_needed_s
