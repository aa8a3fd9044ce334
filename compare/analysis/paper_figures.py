"""The paper's figures with the methods side by side on shared axes (Figs. 3–5 and 8–10).

One figure per figure of the paper, one column per method, every column on the same x and y
axes, so a difference between methods is seen at a glance (in case 1, TPIK stops in front of
the person while HQP and mink move around them and go on cycling the waypoints):

* case 1: ``paper_fig3_ee_error.png`` (EE position error), ``paper_fig4_distances.png``
  (control point distances and the safety threshold), ``paper_fig5_joints.png`` (joints 2, 4, 6
  with their thresholds), and ``paper_ee_path.png`` (top view of the EE path while the person is
  in, with the person);
* case 2: ``paper_fig8_ee_walls.png`` (EE x, y, z and the walls), ``paper_fig9_distances.png``,
  ``paper_fig10_joints.png``.

The person's presence (from the first motion to the last keyframe) is shaded grey; a set task's
activation (σ in the band of eq. 7, the same test for every method) is shaded orange. The
paper plots the measured distance; here the ground truth is solid and the measured dashed.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle

from compare.analysis.claims import activated, context_from_config
from compare.analysis.metrics import SetTaskInfo
from compare.analysis.plot_style import (
    ACTIVE_STYLE,
    PLOTS_DIR,
    SAFETY_STYLE,
    figure,
    finite,
    save_figure,
    wall_axis,
)
from compare.analysis.results import load_steps, load_summary
from compare.config import ConfigError, load_config
from compare.sensing.person import Person
from compare.sensing.scene import load_workcell

log = logging.getLogger(__name__)

PERSON_STYLE: dict[str, Any] = {"color": "0.5", "alpha": 0.12, "linewidth": 0}
TRUE_STYLE: dict[str, Any] = {"color": "tab:blue"}
MEASURED_STYLE: dict[str, Any] = {"color": "tab:green", "linestyle": "--", "linewidth": 0.8}


def _band(ax: Axes, t: np.ndarray, mask: np.ndarray, style: dict[str, Any], label: str | None = None) -> None:
    if mask is not None and np.any(mask):
        ax.fill_between(t, 0, 1, where=mask, transform=ax.get_xaxis_transform(), label=label, **style)


def _person_mask(t: np.ndarray, timeline: Any) -> np.ndarray:
    if timeline is None:
        return np.zeros(t.shape, dtype=bool)
    return (t >= timeline.t_move) & (t <= timeline.t_gone)


def _grid(rows: int, cols: int, height_per_row: float) -> tuple[Any, Any]:
    fig, axes = figure(rows, cols, height_in=height_per_row * rows + 0.9, width_in=max(6.0, 3.6 * cols))
    for ax in axes.flat[1:]:
        ax.sharex(axes.flat[0])
    for r in range(rows):
        for ax in axes[r, 1:]:
            ax.sharey(axes[r, 0])
            ax.tick_params(labelleft=False)
    return fig, axes


def _frame(ax: Axes, ylabel: str | None, col: int) -> None:
    ax.grid(alpha=0.3)
    if col == 0 and ylabel:
        ax.set_ylabel(ylabel)


def _fig_ee_error(data: list[tuple[str, pd.DataFrame]], ctx: Any) -> Figure:
    fig, axes = _grid(1, len(data), 2.8)
    for col, (name, steps) in enumerate(data):
        ax = axes[0, col]
        t = steps["t"].to_numpy(dtype=float)
        _band(ax, t, _person_mask(t, ctx.person), PERSON_STYLE, "person in" if col == 0 else None)
        ax.plot(t, finite(steps["ee_error_m"]), color="tab:blue")
        ax.set_title(name)
        ax.set_xlabel("t [s]")
        _frame(ax, "EE position error [m]", col)
        ax.set_ylim(bottom=0.0)
    fig.suptitle("Fig. 3 (case 1): end-effector position error")
    if len(data):
        axes[0, 0].legend(fontsize="small", loc="upper right")
    return fig


def _fig_distances(data: list[tuple[str, pd.DataFrame]], ctx: Any, title: str) -> Figure:
    tasks = ctx.group("obstacles")
    fig, axes = _grid(len(tasks), len(data), 1.9)
    columns = [f"dist_{kind}:{cp}" for cp in ctx.control_points for kind in ("true", "meas")]
    peak = max(
        (
            float(np.nanmax(v))
            for _, steps in data
            for c in columns
            if c in steps
            for v in [finite(steps[c])]
            if np.any(np.isfinite(v))
        ),
        default=0.0,
    )
    top = min(3.0, max(1.2, 1.05 * peak))  # the paper's 1.2 m, more when a distance is above it
    drawn = {"true": False, "measured": False}
    for col, (name, steps) in enumerate(data):
        t = steps["t"].to_numpy(dtype=float)
        for row, (task, cp) in enumerate(zip(tasks, ctx.control_points, strict=True)):
            ax = axes[row, col]
            _band(ax, t, _person_mask(t, ctx.person), PERSON_STYLE)
            _band(ax, t, activated(steps, task), ACTIVE_STYLE, "task active (eq. 7)" if row == col == 0 else None)
            for kind, column, style in (
                ("true", f"dist_true:{cp}", TRUE_STYLE),
                ("measured", f"dist_meas:{cp}", MEASURED_STYLE),
            ):
                if column in steps.columns:
                    values = finite(steps[column])
                    ax.plot(t, values, **style)
                    drawn[kind] |= bool(np.any(np.isfinite(values)))
            ax.axhline(task.safety_lower, **SAFETY_STYLE)
            _frame(ax, f"{cp} [m]", col)
            ax.set_ylim(0.0, top)
            if row == 0:
                ax.set_title(name)
        axes[-1, col].set_xlabel("t [s]")
    fig.suptitle(title)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    for kind, style in (("true", TRUE_STYLE), ("measured", MEASURED_STYLE)):
        if drawn[kind]:  # a legend entry only for a line drawn somewhere
            handles.append(Line2D([], [], **style))
            labels.append(kind)
    axes[0, 0].legend(handles, labels, fontsize="x-small", loc="upper right")
    return fig


def _fig_joints(data: list[tuple[str, pd.DataFrame]], ctx: Any, title: str) -> Figure:
    tasks = ctx.group("joint_limits")
    fig, axes = _grid(len(tasks), len(data), 1.8)
    for col, (name, steps) in enumerate(data):
        t = steps["t"].to_numpy(dtype=float)
        for row, task in enumerate(tasks):
            ax = axes[row, col]
            _band(ax, t, _person_mask(t, ctx.person), PERSON_STYLE)
            _band(ax, t, activated(steps, task), ACTIVE_STYLE)
            ax.plot(t, finite(steps[f"sigma:{task.name}"]), color="tab:blue")
            ax.axhline(task.safety_lower, **SAFETY_STYLE)
            ax.axhline(task.safety_upper, **SAFETY_STYLE)
            _frame(ax, f"{task.name} [rad]", col)
            if row == 0:
                ax.set_title(name)
        axes[-1, col].set_xlabel("t [s]")
    fig.suptitle(title)
    return fig


def _fig_ee_walls(data: list[tuple[str, pd.DataFrame]], ctx: Any) -> Figure:
    walls = ctx.group("walls")
    fig, axes = _grid(3, len(data), 2.0)
    for col, (name, steps) in enumerate(data):
        t = steps["t"].to_numpy(dtype=float)
        for row, axis in enumerate("xyz"):
            ax = axes[row, col]
            _band(ax, t, _person_mask(t, ctx.person), PERSON_STYLE)
            ax.plot(t, finite(steps[f"ee_{axis}"]), color="tab:blue")
            _frame(ax, f"EE {axis} [m]", col)
            if row == 0:
                ax.set_title(name)
        for wall in walls:
            if f"sigma:{wall.name}" not in steps.columns:
                continue
            info = SetTaskInfo(wall.name, "walls", -np.inf, wall.safety_lower, wall.safety_upper, np.inf)
            found = wall_axis(steps, info)
            if found is None:
                continue
            a, s, d = found
            axes[a, col].axhline((wall.safety_lower + d) / s, **SAFETY_STYLE)
            _band(axes[a, col], t, activated(steps, wall), ACTIVE_STYLE)
        axes[-1, col].set_xlabel("t [s]")
    fig.suptitle("Fig. 8 (case 2): end-effector position and the virtual walls")
    return fig


def _fig_ee_path(data: list[tuple[str, pd.DataFrame]], ctx: Any, config: Any) -> Figure:
    """Top view of the EE path while the person is in, the waypoints and the person."""
    fig, axes = figure(1, len(data), height_in=3.8, width_in=max(6.0, 3.6 * len(data)))
    person = Person(
        load_workcell(config.scenario.robot), config.person.keyframes, time_scale=config.scenario.time_scale
    )
    t_mid = 0.5 * (ctx.person.t_in + ctx.person.t_leave)
    pose = person.pose_at(t_mid)
    for col, (name, steps) in enumerate(data):
        ax = axes[0, col]
        t = steps["t"].to_numpy(dtype=float)
        inside = (t >= ctx.person.t_move) & (t <= ctx.person.t_gone)
        ax.plot(steps["ee_x"], steps["ee_y"], color="0.8", linewidth=0.8, label="EE, whole run")
        ax.plot(steps["ee_x"][inside], steps["ee_y"][inside], color="tab:blue", label="EE, person in")
        for p in config.waypoints.positions:
            ax.plot(p[0], p[1], marker="x", color="black", markersize=7)
        ax.add_patch(_circle(pose.position, 0.17, "tab:red", "person (torso)"))
        hand = pose.hands["r"]
        ax.plot(hand[0], hand[1], marker="o", color="tab:red", markersize=5, label="hand")
        ax.set_aspect("equal")
        ax.set_xlim(-0.8, 0.8)
        ax.set_ylim(-0.4, 1.3)
        ax.set_title(name)
        ax.set_xlabel("x [m]")
        ax.grid(alpha=0.3)
        if col == 0:
            ax.set_ylabel("y [m]")
            ax.legend(fontsize="x-small", loc="lower left")
    fig.suptitle("Case 1, top view: end-effector path while the person is in (× waypoints)")
    return fig


def _circle(xy: Sequence[float], r: float, color: str, label: str) -> Any:
    return Circle((xy[0], xy[1]), r, color=color, alpha=0.3, label=label)


def paper_figures(results_dir: Path) -> dict[str, Figure]:
    """The paper-style figures of a case-1 or case-2 run directory (module docstring), by file stem.

    Empty for a run that is not a scripted case (or whose ``config.toml`` does not load).
    """
    results_dir = Path(results_dir)
    if not (results_dir / "config.toml").is_file():
        return {}
    try:
        config, _ = load_config(results_dir / "config.toml")
    except ConfigError as exc:
        log.warning("paper figures: %s", exc)
        return {}
    ctx = context_from_config(config)
    if ctx is None:
        return {}
    data = []
    for name in load_summary(results_dir).get("methods") or {}:
        try:
            data.append((name, load_steps(results_dir, name)))
        except FileNotFoundError:
            continue
    if not data:
        return {}
    if ctx.kind == "case1":
        builders = {
            "paper_fig3_ee_error": lambda: _fig_ee_error(data, ctx),
            "paper_fig4_distances": lambda: _fig_distances(data, ctx, "Fig. 4 (case 1): distances"),
            "paper_fig5_joints": lambda: _fig_joints(data, ctx, "Fig. 5 (case 1): joints and thresholds"),
            "paper_ee_path": lambda: _fig_ee_path(data, ctx, config),
        }
    else:
        builders = {
            "paper_fig8_ee_walls": lambda: _fig_ee_walls(data, ctx),
            "paper_fig9_distances": lambda: _fig_distances(data, ctx, "Fig. 9 (case 2): distances"),
            "paper_fig10_joints": lambda: _fig_joints(data, ctx, "Fig. 10 (case 2): joints and thresholds"),
        }
    figures = {}
    for name, build in builders.items():
        try:
            figures[name] = build()
        except Exception as exc:  # one bad figure must not cost the others
            log.warning("paper figure %s failed: %s", name, exc)
    return figures


def plot_paper_figures(results_dir: Path) -> list[Path]:
    """Write :func:`paper_figures` of a run directory to ``plots/<name>.png``; returns the files."""
    out = Path(results_dir) / PLOTS_DIR
    return [save_figure(fig, out / f"{name}.png") for name, fig in paper_figures(results_dir).items()]
