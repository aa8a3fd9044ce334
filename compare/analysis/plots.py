"""Figures of a run (the paper's Figs. 3–5, 8–10, and timing vs safety) and of a sweep.

Everything is drawn on :class:`matplotlib.figure.Figure` objects with the Agg canvas, without
``pyplot``: no display, no global backend switch, safe in worker processes. Files are PNG
under ``<results>/plots/``.

Thresholds come from the ``set_tasks`` list that :func:`compare.analysis.metrics.compute_summary`
stores in each method's entry of ``summary.json``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

from compare.analysis.metrics import (
    GROUPS,
    VIOLATION_TOLERANCE,
    SetTaskInfo,
    group_summary,
    set_tasks_from_summary,
    summary_groups,
)
from compare.analysis.paper_figures import plot_paper_figures
from compare.analysis.plot_style import (
    ACTIVE_STYLE,
    OCCLUDED_STYLE,
    PHYSICAL_STYLE,
    PLOTS_DIR,
    SAFETY_STYLE,
    figure,
    finite,
    method_colors,
    save_figure,
    wall_axis,
)
from compare.analysis.plots_prediction import plot_predictions
from compare.analysis.results import RUNS_DIR, collect_sweep, load_steps, load_summary, safe_name, summarize_sweep_rows
from compare.analysis.statistics import rate_value

log = logging.getLogger(__name__)

GROUP_UNITS = {"joint_limits": "rad", "walls": "m", "obstacles": "m"}
GROUP_TITLES = {"joint_limits": "joint limits", "walls": "virtual walls", "obstacles": "obstacles"}


def _shade(ax: Axes, t: np.ndarray, mask: np.ndarray | None, label: str | None = None) -> None:
    if mask is None or not np.any(mask):
        return
    ax.fill_between(t, 0, 1, where=mask, transform=ax.get_xaxis_transform(), label=label, **ACTIVE_STYLE)


def _active(steps: pd.DataFrame, name: str) -> np.ndarray | None:
    col = f"active:{name}"
    if col not in steps.columns:
        return None
    return steps[col].astype("boolean").fillna(False).to_numpy(dtype=bool)


def _occluded(steps: pd.DataFrame, cp: str) -> np.ndarray | None:
    """Steps whose reading of ``cp`` was assumed from hidden space (finite and occluded); None if none."""
    col = f"occluded:{cp}"
    if col not in steps.columns or f"dist_meas:{cp}" not in steps.columns:
        return None
    mask = steps[col].to_numpy(dtype=bool) & np.isfinite(steps[f"dist_meas:{cp}"].to_numpy(dtype=float))
    return mask if mask.any() else None


def _legend_outside(ax: Axes) -> None:
    """Legend to the right of the axes, off the data (constrained layout makes room)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", borderaxespad=0.0)


def _has_data(x: np.ndarray) -> bool:
    return bool(np.any(np.isfinite(x)))


def _log_x(ax: Axes) -> None:
    """Log x axis labelled 1, 2, 5 × 10^k in plain numbers (the default labels overlap)."""
    ax.set_xscale("log")
    ax.xaxis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _pos: f"{x:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


def _hline(ax: Axes, y: float, style: dict[str, Any], label: str | None = None) -> None:
    if math.isfinite(y):
        ax.axhline(y, label=label, **style)


# ------------------------------------------------------------------------------------------- per run


def plot_ee_error(steps: pd.DataFrame, method: str, path: Path, tolerance_m: float | None = None) -> Path:
    """EE position error over time (paper Fig. 3), waypoint switches as vertical lines."""
    fig, axes = figure()
    ax = axes[0, 0]
    t = steps["t"].to_numpy(dtype=float)
    ax.plot(t, finite(steps["ee_error_m"]), color="tab:blue", label="‖p_d − p‖")
    if "waypoint" in steps.columns:
        wp = steps["waypoint"].to_numpy()
        for i in np.flatnonzero(wp[1:] != wp[:-1]) + 1:
            ax.axvline(t[i], color="0.6", linewidth=0.8, linestyle="--")
    if tolerance_m:
        ax.axhline(tolerance_m, color="0.4", linewidth=0.8, linestyle=":", label=f"tolerance {tolerance_m:g} m")
    ax.set(xlabel="t [s]", ylabel="EE position error [m]", title=f"{method}: end-effector position error")
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    _legend_outside(ax)
    return save_figure(fig, path)


def plot_distances(
    steps: pd.DataFrame,
    method: str,
    control_points: Sequence[str],
    obstacle_tasks: Sequence[SetTaskInfo],
    path: Path,
) -> Path | None:
    """Distance of each control point to the closest obstacle (paper Figs. 4/9).

    Ground truth solid, measured dashed, the obstacle safety threshold as a red line, steps
    where the control point's obstacle task is active shaded; readings assumed from hidden space
    (``occluded:<cp>``, not measured) marked with purple dots. None if there are no distance
    columns, or no finite distance and no obstacle task.
    """
    cps = [
        cp
        for cp in control_points
        if any(_has_data(finite(steps[c])) for c in (f"dist_true:{cp}", f"dist_meas:{cp}") if c in steps.columns)
    ]
    if not cps and not obstacle_tasks:
        return None
    cps = cps or [cp for cp in control_points if f"dist_true:{cp}" in steps.columns]
    if not cps:
        return None
    t = steps["t"].to_numpy(dtype=float)
    fig, axes = figure(len(cps), 1, height_in=2.2 * len(cps) + 0.6)
    for ax, cp in zip(axes[:, 0], cps, strict=True):
        for kind, style in (("true", {"color": "tab:blue"}), ("meas", {"color": "tab:green", "linestyle": "--"})):
            d = finite(steps[f"dist_{kind}:{cp}"]) if f"dist_{kind}:{cp}" in steps.columns else np.array([np.nan])
            if _has_data(d):
                ax.plot(t, d, label="true" if kind == "true" else "measured", **style)
        occluded = _occluded(steps, cp)
        if occluded is not None:
            meas = finite(steps[f"dist_meas:{cp}"])
            ax.plot(t[occluded], meas[occluded], **OCCLUDED_STYLE, label="assumed (occluded)")
        own = [task for task in obstacle_tasks if task.name.endswith(cp)] or list(obstacle_tasks)
        for k, value in enumerate(sorted({task.safety_lower for task in own})):
            _hline(ax, value, SAFETY_STYLE, "safety threshold" if k == 0 else None)
        for k, value in enumerate(sorted({task.physical_lower for task in own})):
            _hline(ax, value, PHYSICAL_STYLE, "physical threshold" if k == 0 else None)
        for task in own if len(own) == 1 else []:
            _shade(ax, t, _active(steps, task.name), "task active")
        ax.set_ylabel(f"{cp} [m]")
        ax.set_ylim(bottom=0.0)
        ax.grid(alpha=0.3)
    axes[0, 0].set_title(f"{method}: control point to closest obstacle")
    # One legend for every panel: a series may appear only in a lower one (e.g. occluded readings).
    entries: dict[str, Any] = {}
    for ax in axes[:, 0]:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    if entries:
        axes[0, 0].legend(
            list(entries.values()), list(entries), loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small"
        )
    axes[-1, 0].set_xlabel("t [s]")
    return save_figure(fig, path)


def plot_joints(steps: pd.DataFrame, method: str, joint_tasks: Sequence[SetTaskInfo], path: Path) -> Path | None:
    """Joint positions of the joint-limit tasks with safety and physical limits (Figs. 5/10)."""
    tasks = [task for task in joint_tasks if f"sigma:{task.name}" in steps.columns]
    if not tasks:
        return None
    t = steps["t"].to_numpy(dtype=float)
    fig, axes = figure(len(tasks), 1, height_in=2.0 * len(tasks) + 0.6)
    for ax, task in zip(axes[:, 0], tasks, strict=True):
        ax.plot(t, finite(steps[f"sigma:{task.name}"]), color="tab:blue", label="q")
        _hline(ax, task.safety_lower, SAFETY_STYLE, "safety limits")
        _hline(ax, task.safety_upper, SAFETY_STYLE)
        _hline(ax, task.physical_lower, PHYSICAL_STYLE, "physical limits")
        _hline(ax, task.physical_upper, PHYSICAL_STYLE)
        _shade(ax, t, _active(steps, task.name), "task active")
        ax.set_ylabel(f"{task.name} [rad]")
        ax.grid(alpha=0.3)
    axes[0, 0].set_title(f"{method}: joints with limits")
    _legend_outside(axes[0, 0])
    axes[-1, 0].set_xlabel("t [s]")
    return save_figure(fig, path)


def plot_ee_walls(steps: pd.DataFrame, method: str, wall_tasks: Sequence[SetTaskInfo], path: Path) -> Path | None:
    """EE x, y, z with the positions of the virtual walls (paper Fig. 8).

    Walls that are not axis-aligned planes on the EE are listed in the title instead.
    """
    tasks = [task for task in wall_tasks if f"sigma:{task.name}" in steps.columns]
    if not tasks or not all(f"ee_{a}" in steps.columns for a in "xyz"):
        return None
    t = steps["t"].to_numpy(dtype=float)
    fig, axes = figure(3, 1, height_in=7.0)
    unmatched = []
    placed: list[list[tuple[SetTaskInfo, float, float]]] = [[], [], []]
    for task in tasks:
        found = wall_axis(steps, task)
        if found is None:
            unmatched.append(task.name)
        else:
            a, s, d = found
            placed[a].append((task, s, d))
    for a, (ax, axis) in enumerate(zip(axes[:, 0], "xyz", strict=True)):
        ax.plot(t, finite(steps[f"ee_{axis}"]), color="tab:blue", label=f"EE {axis}")
        if f"target_{axis}" in steps.columns:
            ax.plot(t, finite(steps[f"target_{axis}"]), color="0.5", linestyle="--", linewidth=0.8, label="target")
        for k, (task, s, d) in enumerate(placed[a]):
            # σ = s·p − d  ⇒  the threshold σ* sits at p = (σ* + d)/s.
            _hline(ax, (task.safety_lower + d) / s, SAFETY_STYLE, "wall (safety)" if k == 0 else None)
            _hline(ax, (task.physical_lower + d) / s, PHYSICAL_STYLE, "physical" if k == 0 else None)
            _shade(ax, t, _active(steps, task.name))
        ax.set_ylabel(f"{axis} [m]")
        ax.grid(alpha=0.3)
        _legend_outside(ax)
    title = f"{method}: end-effector position and virtual walls"
    if unmatched:
        title += f"\n(not axis-aligned on the EE, not drawn: {', '.join(unmatched)})"
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("t [s]")
    return save_figure(fig, path)


def plot_iso15066(steps: pd.DataFrame, method: str, control_points: Sequence[str], path: Path) -> Path | None:
    """ISO/TS 15066 speed-and-separation margin per control point (``compare.analysis.iso15066``).

    Top: margin d − S_p [m] per control point, 0 in red, time below zero shaded. Bottom: the
    estimated human speed v_h and the robot's speed toward the person v_r [m/s]. None when the
    run has no ``iso_margin_m:*`` column or the person was never within range.
    """
    cps = [cp for cp in control_points if f"iso_margin_m:{cp}" in steps.columns]
    if not cps or not any(_has_data(finite(steps[f"iso_margin_m:{cp}"])) for cp in cps):
        return None
    t = steps["t"].to_numpy(dtype=float)
    fig, axes = figure(2, 1, height_in=6.0)
    top, bottom = axes[0, 0], axes[1, 0]
    colors = method_colors(list(cps))
    below = np.zeros(len(t), dtype=bool)
    for cp in cps:
        m = finite(steps[f"iso_margin_m:{cp}"])
        top.plot(t, m, color=colors[cp], label=cp)
        with np.errstate(invalid="ignore"):
            below |= np.nan_to_num(m, nan=0.0) < 0.0
        for kind, style in (("vh_mps", "-"), ("vr_mps", ":")):
            col = f"iso_{kind}:{cp}"
            if col in steps.columns:
                label = f"{cp} v_h (estimated)" if kind == "vh_mps" else f"{cp} v_r"
                bottom.plot(t, finite(steps[col]), color=colors[cp], linestyle=style, label=label)
    top.axhline(0.0, label="S_p reached", **SAFETY_STYLE)
    if np.any(below):
        top.fill_between(
            t, 0, 1, where=below, transform=top.get_xaxis_transform(), color="tab:red", alpha=0.12, linewidth=0
        )
    top.set(ylabel="d − S_p [m]", title=f"{method}: ISO/TS 15066 speed and separation margin (5.5.4)")
    top.grid(alpha=0.3)
    _legend_outside(top)
    bottom.set(xlabel="t [s]", ylabel="speed [m/s]")
    bottom.set_ylim(bottom=0.0)
    bottom.grid(alpha=0.3)
    _legend_outside(bottom)
    return save_figure(fig, path)


def _labelled_point(ax: Axes, x: float, x_hi: float | None, y: float, label: str, color: Any) -> None:
    """A method's point ● with a bar to ``x_hi`` ending in |, named in the axes' legend.

    A legend rather than a note beside the point: methods with close figures (the mink peers) would
    write their names over each other.
    """
    err = None if x_hi is None or x_hi < x else np.array([[0.0], [x_hi - x]])
    ax.errorbar([x], [y], xerr=err, fmt="o", color=color, capsize=3, markersize=6, label=label)
    if x_hi is not None and x_hi >= x:
        ax.plot([x_hi], [y], marker="|", color=color, markersize=10)


def _points_legend(ax: Axes) -> None:
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize="small")


def plot_comparison(methods: dict[str, dict[str, Any]], path: Path, title: str = "") -> Path | None:
    """Solve time (median ●, bar to p99) against the worst safety margin, one panel per group.

    x is logarithmic [µs]; y is the group's minimum safety margin in its own unit, with the
    violation boundary (0) in red. Without set tasks the y axis is the final EE error. A group
    beyond joint limits, walls and obstacles (a new safety task's) gets its own panel.
    """
    every = dict.fromkeys([*GROUPS, *(g for m in methods.values() for g in summary_groups(m))])
    groups = [g for g in every if any(group_summary(m, g) is not None for m in methods.values())]
    panels = groups or ["ee_error"]
    fig, axes = figure(1, len(panels), height_in=4.0, width_in=max(5.0, 4.2 * len(panels)))
    colors = method_colors(list(methods))
    for ax, panel in zip(axes[0], panels, strict=True):
        skipped = []
        for name, m in methods.items():
            solve = m.get("solve_time_us") or {}
            x, x_hi = solve.get("median"), solve.get("p99")
            if panel == "ee_error":
                y = (m.get("ee_error_m") or {}).get("final")
            else:
                y = (group_summary(m, panel) or {}).get("safety_margin_min")
            if x is None or y is None or x <= 0:
                skipped.append(name)
                continue
            _labelled_point(ax, x, x_hi, y, name, colors[name])
        _points_legend(ax)
        _log_x(ax)
        ax.set_xlabel("solve time per step [µs] (● median, | p99)")
        if panel == "ee_error":
            ax.set_ylabel("final EE error [m]")
        else:
            ax.axhline(0.0, **SAFETY_STYLE)
            unit = GROUP_UNITS.get(panel, "task unit")
            ax.set_ylabel(f"min safety margin [{unit}] (< 0: violated)")
            ax.set_title(GROUP_TITLES.get(panel, panel) + (f"\n(no data: {', '.join(skipped)})" if skipped else ""))
        ax.grid(alpha=0.3, which="both")
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


def _plot_method(steps: pd.DataFrame, name: str, msum: dict[str, Any], out: Path) -> list[Path]:
    """The per-method figures of :func:`plot_run`; a figure that fails is logged and skipped."""
    tasks = set_tasks_from_summary(msum)
    stem = safe_name(name)
    cps = msum.get("control_points") or [c.split(":", 1)[1] for c in steps.columns if c.startswith("dist_true:")]

    def group(g: str) -> list[SetTaskInfo]:
        return [task for task in tasks if task.group == g]

    figures: list[tuple[str, Callable[[Path], Path | None]]] = [
        ("ee_error", lambda p: plot_ee_error(steps, name, p, msum.get("waypoint_tolerance_m"))),
        ("distances", lambda p: plot_distances(steps, name, cps, group("obstacles"), p)),
        ("joints", lambda p: plot_joints(steps, name, group("joint_limits"), p)),
        ("ee_walls", lambda p: plot_ee_walls(steps, name, group("walls"), p)),
        ("iso15066", lambda p: plot_iso15066(steps, name, cps, p)),
    ]
    paths: list[Path] = []
    for kind, draw in figures:
        try:
            path = draw(out / f"{stem}_{kind}.png")
        except Exception as exc:  # one bad figure must not cost the others
            log.warning("plot %s of %s failed: %s", kind, name, exc)
            continue
        if path is not None:
            paths.append(path)
    return paths


def plot_run(results_dir: Path) -> list[Path]:
    """All figures of one run directory; returns the files written under ``plots/``.

    Per method ``<method>_ee_error.png`` (Fig. 3), ``<method>_distances.png`` (Figs. 4/9),
    ``<method>_joints.png`` (Figs. 5/10), ``<method>_ee_walls.png`` (Fig. 8, when the scenario
    has walls), ``<method>_iso15066.png`` (ISO/TS 15066 margin, when the person came within
    range), ``<method>_prediction.png`` (with ``[prediction]``), and ``comparison.png`` (solve time
    vs worst safety margin, all methods).
    A method whose per-step table is missing only appears in the comparison.
    """
    results_dir = Path(results_dir)
    summary = load_summary(results_dir)
    out = results_dir / PLOTS_DIR
    methods: dict[str, dict[str, Any]] = summary.get("methods") or {}
    paths: list[Path] = []
    for name, msum in methods.items():
        try:
            steps = load_steps(results_dir, name)
        except FileNotFoundError as exc:
            log.warning("%s", exc)
            continue
        paths += _plot_method(steps, name, msum, out)
    if methods:
        robot = next((m["robot"] for m in methods.values() if m.get("robot")), None)  # the config's arm
        arm = f"{robot}, " if robot else ""
        title = f"{summary.get('scenario', '')} ({arm}seed {summary.get('seed', '?')}): cost vs safety"
        path = plot_comparison(methods, out / "comparison.png", title)
        if path is not None:
            paths.append(path)
        paths += plot_paper_figures(results_dir)
        paths += plot_predictions(results_dir)
    return paths


# ------------------------------------------------------------------------------------------- sweeps


def plot_sweep(sweep_dir: Path) -> list[Path]:
    """Figures of a sweep directory; returns the files written under ``plots/``.

    ``sweep_comparison.png``: left, per method the median of the runs' median solve times
    (● , bar to the median of their p99) against the share of runs with any safety violation;
    right, every run: median solve time against total safety-violation time.
    ``sweep_min_distance_cdf.png``: empirical CDF of the minimum obstacle distance per run,
    per method, with the obstacle safety threshold (when the runs have obstacles).
    :func:`plot_campaign` adds the reliability-campaign figures.
    """
    sweep_dir = Path(sweep_dir)
    runs = collect_sweep(sweep_dir)
    out = sweep_dir / PLOTS_DIR
    paths: list[Path] = []
    ok = runs[runs["error"].isna()] if "error" in runs.columns else runs
    if ok.empty:
        log.warning("no finished runs in %s: no sweep plots", sweep_dir)
        return paths
    methods = list(dict.fromkeys(ok["method"]))
    colors = method_colors(methods)
    aggregates = summarize_sweep_rows(runs)

    fig, axes = figure(1, 2, height_in=4.2, width_in=11.0)
    left, right = axes[0]
    for name in methods:
        agg = aggregates.get(name) or {}
        solve = agg.get("solve_time_us") or {}
        x, share = solve.get("median_of_medians"), rate_value(agg.get("share_runs_any_violation"))
        if x is not None and share is not None and x > 0:
            _labelled_point(
                left, x, solve.get("median_of_p99"), 100.0 * share, f"{name} (n={agg['runs']})", colors[name]
            )
        rows = ok[ok["method"] == name]
        x_run = pd.to_numeric(rows.get("solve_median_us"), errors="coerce").to_numpy(dtype=float)
        y_run = np.zeros(len(rows))
        for g in GROUPS:
            col = f"{g}_violation_time_s"
            if col in rows.columns:
                y_run += pd.to_numeric(rows[col], errors="coerce").fillna(0.0).to_numpy(dtype=float)
        right.scatter(x_run, y_run, s=14, alpha=0.6, color=colors[name], label=name)
    _log_x(left)
    left.set(
        xlabel="solve time [µs] (● median of run medians, | median of run p99)",
        ylabel="runs with a safety violation [%]",
        title="per method",
    )
    left.set_ylim(-5.0, 110.0)
    left.grid(alpha=0.3, which="both")
    _points_legend(left)
    _log_x(right)
    right.set(
        xlabel="median solve time of the run [µs]",
        ylabel="safety violation time, summed over groups [s]",
        title="per run",
    )
    right.grid(alpha=0.3, which="both")
    right.legend(fontsize="small")
    scenario = ok["scenario"].dropna().iloc[0] if "scenario" in ok.columns and ok["scenario"].notna().any() else ""
    fig.suptitle(f"sweep {scenario}: {ok['run'].nunique()} runs, cost vs safety")
    paths.append(save_figure(fig, out / "sweep_comparison.png"))

    if "min_obstacle_distance_m" in ok.columns:
        fig, axes = figure(height_in=4.0, width_in=7.0)
        ax = axes[0, 0]
        drawn = False
        for name in methods:
            rows = ok.loc[ok["method"] == name, "min_obstacle_distance_m"]
            n = int(np.isfinite(pd.to_numeric(rows, errors="coerce").to_numpy(dtype=float)).sum())
            drawn |= _ecdf(ax, rows, colors[name], f"{name} (n={n})")
        threshold = _sweep_obstacle_threshold(sweep_dir, ok)
        if threshold is not None:
            ax.axvline(threshold, label=f"safety threshold {threshold:g} m", **SAFETY_STYLE)
        ax.set(
            xlabel="minimum obstacle distance over the run [m]",
            ylabel="share of runs ≤ x",
            title="minimum distance to the person (ground truth)",
        )
        ax.set_ylim(0.0, 1.02)
        ax.grid(alpha=0.3)
        if drawn or threshold is not None:
            ax.legend(fontsize="small", loc="lower right")
        paths.append(save_figure(fig, out / "sweep_min_distance_cdf.png"))
    return paths


def plot_campaign(sweep_dir: Path) -> list[Path]:
    """The reliability-campaign figures of a sweep directory (``plots/``), besides :func:`plot_sweep`'s.

    ``sweep_iso_margin_cdf.png``: CDF of each run's minimum ISO/TS 15066 margin, per method.
    ``sweep_solve_vs_violation.png``: each run's p99 solve time against its worst joint-limit and
    wall safety margins.
    """
    sweep_dir = Path(sweep_dir)
    runs = collect_sweep(sweep_dir)
    ok = runs[runs["error"].isna()] if "error" in runs.columns else runs
    if ok.empty:
        return []
    methods = list(dict.fromkeys(ok["method"]))
    colors = method_colors(methods)
    paths: list[Path] = []
    for draw in (_plot_sweep_iso_cdf, _plot_sweep_solve_vs_violation):
        try:
            path = draw(ok, methods, colors, sweep_dir / PLOTS_DIR)
        except Exception as exc:  # one bad figure must not cost the others
            log.warning("sweep plot %s failed: %s", draw.__name__, exc)
            continue
        if path is not None:
            paths.append(path)
    return paths


def _ecdf(ax: Axes, values: pd.Series, color: Any, label: str) -> bool:
    """Empirical CDF of the finite ``values`` (a step from 0 at the smallest); False if none."""
    d = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float)
    d = np.sort(d[np.isfinite(d)])
    if not d.size:
        return False
    ax.step(np.concatenate([[d[0]], d]), np.arange(0, d.size + 1) / d.size, where="post", color=color, label=label)
    return True


def _plot_sweep_iso_cdf(ok: pd.DataFrame, methods: list[str], colors: dict[str, Any], out: Path) -> Path | None:
    """``sweep_iso_margin_cdf.png``: CDF of each run's minimum ISO/TS 15066 margin, per method."""
    if "iso_min_margin_m" not in ok.columns:
        return None
    fig, axes = figure(height_in=4.0, width_in=7.0)
    ax = axes[0, 0]
    drawn = False
    for name in methods:
        rows = ok.loc[ok["method"] == name, "iso_min_margin_m"]
        n = int(pd.to_numeric(rows, errors="coerce").notna().sum())
        drawn |= _ecdf(ax, rows, colors[name], f"{name} (n={n})")
    if not drawn:
        return None
    ax.axvline(0.0, label="S_p reached (margin 0)", **SAFETY_STYLE)
    ax.set(
        xlabel="minimum ISO/TS 15066 margin d − S_p over the run [m]",
        ylabel="share of runs ≤ x",
        title="speed and separation margin (runs with the person within range)",
    )
    ax.set_ylim(0.0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", loc="lower right")
    return save_figure(fig, out / "sweep_iso_margin_cdf.png")


def _plot_sweep_solve_vs_violation(
    ok: pd.DataFrame, methods: list[str], colors: dict[str, Any], out: Path
) -> Path | None:
    """``sweep_solve_vs_violation.png``: each run's p99 solve time against its worst joint / wall margin.

    The legend counts the runs beyond the metrics' violation tolerance (1 mm / 1 mrad).
    """
    panels = [g for g in ("joint_limits", "walls") if f"{g}_safety_margin_min" in ok.columns]
    if not panels or "solve_p99_us" not in ok.columns:
        return None
    fig, axes = figure(1, len(panels), height_in=4.2, width_in=5.5 * len(panels))
    for ax, group in zip(axes[0], panels, strict=True):
        for name in methods:
            rows = ok[ok["method"] == name]
            x = pd.to_numeric(rows["solve_p99_us"], errors="coerce").to_numpy(dtype=float)
            y = pd.to_numeric(rows[f"{group}_safety_margin_min"], errors="coerce").to_numpy(dtype=float)
            keep = np.isfinite(x) & np.isfinite(y) & (x > 0)
            if np.any(keep):
                bad = int(np.count_nonzero(y[keep] < -VIOLATION_TOLERANCE))
                ax.scatter(x[keep], y[keep], s=12, alpha=0.6, color=colors[name], label=f"{name} ({bad} violated)")
        ax.axhline(0.0, **SAFETY_STYLE)
        _log_x(ax)
        ax.set(
            xlabel="p99 solve time of the run [µs]",
            ylabel=f"worst safety margin [{GROUP_UNITS[group]}] (< 0: violated)",
            title=GROUP_TITLES[group],
        )
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="small")
    fig.suptitle("solve time vs safety, one point per run")
    return save_figure(fig, out / "sweep_solve_vs_violation.png")


def _sweep_obstacle_threshold(sweep_dir: Path, ok: pd.DataFrame) -> float | None:
    """Obstacle safety threshold of the first run that stores one (None if none does)."""
    for run in ok["run"].unique()[:5]:
        try:
            summary = load_summary(sweep_dir / RUNS_DIR / str(run))
        except (OSError, ValueError):
            continue
        for msum in (summary.get("methods") or {}).values():
            values = [t.safety_lower for t in set_tasks_from_summary(msum) if t.group == "obstacles"]
            finite = [v for v in values if math.isfinite(v)]
            if finite:
                return min(finite)
    return None
