"""The figure of ``tpik-compare critical-speed``: minimum distance against approach speed.

Per method, the minimum ground-truth distance of any control point to the person over each run
(faint points: every direction; line: the worst direction) against the person's torso speed
(bottom axis, log) and the hand speed tied to it (top axis); the obstacle safety and physical
thresholds; each method's critical speed in the legend; the kinematic bound (the fastest each
control point can move along the approach direction within the joint velocity limits) as vertical
lines; the verdict's curve (its best witness) when it was computed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from compare.analysis.critical_speed_results import (
    HAND_RANGE_MPS,
    PLOT_FILE,
    TORSO_RANGE_MPS,
    hand_speed,
    load_critical,
    log_map,
)
from compare.analysis.metrics import set_tasks_from_summary
from compare.analysis.plot_style import PHYSICAL_STYLE, PLOTS_DIR, SAFETY_STYLE, figure, method_colors, save_figure
from compare.analysis.results import load_summary

__all__ = ["PLOTS_DIR", "plot_critical_speed"]


def plot_critical_speed(out_dir: Path) -> Path:
    """Draw ``out_dir/critical_speed.png`` from ``critical_speed.json`` and its detail file."""
    out_dir = Path(out_dir)
    result, detail = load_critical(out_dir)
    fig, axes = figure(height_in=4.8, width_in=9.0)
    ax = axes[0, 0]
    colors = method_colors(list(result))
    speeds = detail.get("speeds_mps") or list(TORSO_RANGE_MPS)
    for name, entry in result.items():
        color = colors[name]
        xs = [r["speed_mps"] for r in detail.get("runs", []) if name in r["methods"]]
        ys = [r["methods"][name]["min_distance_m"] for r in detail.get("runs", []) if name in r["methods"]]
        pts = [(x, y) for x, y in zip(xs, ys, strict=True) if y is not None]
        if pts:
            ax.scatter(*zip(*pts, strict=True), s=10, alpha=0.35, color=color)
        curve = [(v, d) for v, d in entry["curve"] if d is not None]
        crit = entry.get("safety_mps")
        phys = entry.get("physical_mps")
        label = f"{name} (critical: safety {_speed(crit, speeds)}, physical {_speed(phys, speeds)})"
        if curve:
            ax.plot(*zip(*curve, strict=True), marker="o", markersize=4, color=color, label=label)
    oracle = detail.get("oracle")
    if isinstance(oracle, dict):
        curve = [(v, d) for v, d in oracle["curve"] if d is not None]
        if curve:
            ax.plot(
                *zip(*curve, strict=True),
                color="black",
                linestyle="--",
                marker="s",
                markersize=3,
                label=f"verdict's best witness, knows the future (critical {_speed(oracle.get('safety_mps'), speeds)})",
            )
    thresholds = _thresholds(out_dir)
    if thresholds[0] is not None:
        ax.axhline(thresholds[0], label=f"safety threshold {thresholds[0]:g} m", **SAFETY_STYLE)
    if thresholds[1] is not None:
        ax.axhline(thresholds[1], label=f"physical threshold {thresholds[1]:g} m", **PHYSICAL_STYLE)
    gain = detail.get("obstacle_gain_per_s")
    if gain and thresholds[0] is not None:
        fine = np.geomspace(min(speeds), max(speeds), 60)
        lag = np.maximum(thresholds[0] - _torso_to_hand(fine) / gain, 0.0)
        ax.plot(fine, lag, color="0.3", linestyle=":", linewidth=1.2, label=f"σ_s − v_hand/K (K = {gain:g} 1/s)")
    bounds = detail.get("kinematic_bound_mps") or {}
    for k, (cp, v) in enumerate(sorted(bounds.items(), key=lambda kv: kv[1])):
        ax.axvline(v, color="0.45", linestyle=(0, (4, 2 + 2 * k)), linewidth=1.0)
        ax.annotate(
            f"{cp} retreat ≤ {v:.2f} m/s",
            (v, 1.0 - 0.22 * k),
            xycoords=("data", "axes fraction"),
            rotation=90,
            va="top",
            ha="right",
            fontsize="x-small",
            color="0.35",
        )
    ax.set_xscale("log")
    ax.set_xlim(min(speeds) / 1.15, max(max(speeds), max(bounds.values(), default=max(speeds))) * 1.15)
    ax.set_xticks(speeds)
    ax.set_xticklabels([f"{v:.2g}" for v in speeds], fontsize="small")
    ax.minorticks_off()
    top = ax.secondary_xaxis("top", functions=(_torso_to_hand, _hand_to_torso))
    top.set_xticks([hand_speed(v) for v in speeds])
    top.set_xticklabels([f"{hand_speed(v):.2g}" for v in speeds], fontsize="x-small")
    top.set_xlabel("hand speed [m/s]")
    ax.set_xlabel("person torso approach speed [m/s] (log)")
    ax.set_ylabel("minimum control point–person distance [m]")
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="x-small", loc="lower left")
    n_dirs = len(detail.get("directions") or [])
    per = f"{n_dirs} direction{'s' if n_dirs != 1 else ''} per speed"
    ax.set_title(f"{detail.get('scenario', '')}: critical approach speed ({per}, {detail.get('sensing', '?')} sensing)")
    return save_figure(fig, out_dir / PLOT_FILE)


def _speed(v: float | None, speeds: list[float]) -> str:
    if v is None:
        return "none"
    return f"≥ {v:.2g} m/s (all held)" if v >= max(speeds) - 1e-12 else f"{v:.2g} m/s"


def _torso_to_hand(x: np.ndarray) -> np.ndarray:
    return log_map(np.asarray(x, dtype=float), TORSO_RANGE_MPS, HAND_RANGE_MPS)


def _hand_to_torso(x: np.ndarray) -> np.ndarray:
    return log_map(np.asarray(x, dtype=float), HAND_RANGE_MPS, TORSO_RANGE_MPS)


def _thresholds(out_dir: Path) -> tuple[float | None, float | None]:
    """Obstacle safety and physical thresholds from the first run's summary."""
    for run in sorted((out_dir / "runs").glob("*")):
        try:
            summary = load_summary(run)
        except (OSError, ValueError):
            continue
        for m in (summary.get("methods") or {}).values():
            tasks = [t for t in set_tasks_from_summary(m) if t.group == "obstacles"]
            if tasks:
                return min(t.safety_lower for t in tasks), min(t.physical_lower for t in tasks)
    return None, None
