"""Held share against the person's speed, one panel per method, one line per setup: ``setups_speed.png``.

Reads the result of :func:`compare.campaign.setups.compare_setups` (``setups.json``): per method and
setup, the share of runs that held the obstacle threshold in each bin of the person's peak torso
speed, with its Wilson 95 % interval as error bars.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from compare.analysis.plot_style import figure, save_figure

SPEED_PLOT = "setups_speed.png"
MAX_COLUMNS = 3
"""Panels per row; more methods wrap onto further rows."""


def plot_held_by_speed(result: dict[str, Any], path: Path) -> Path | None:
    """Draw the held share per speed bin of every (method, setup) to ``path``; None without bins."""
    methods = {
        name: m
        for name, m in result.get("methods", {}).items()
        if any(e.get("held_by_torso_speed") for e in m["setups"].values())
    }
    if not methods:
        return None
    cols = min(len(methods), MAX_COLUMNS)
    rows = -(-len(methods) // cols)
    fig, axes = figure(rows, cols, height_in=3.4 * rows, width_in=max(4.0, 3.6 * cols))
    panels = list(axes.flat)
    for ax in panels[len(methods) :]:
        ax.set_visible(False)
    for ax, (name, m) in zip(panels, methods.items(), strict=False):
        for k, (label, entry) in enumerate(m["setups"].items()):
            bins = [b for b in entry.get("held_by_torso_speed") or [] if b["held"]["rate"] is not None]
            if not bins:
                continue
            x = np.array([0.5 * (b["low"] + b["high"]) for b in bins]) + 0.01 * (k - 1)
            y = np.array([b["held"]["rate"] for b in bins])
            lo = y - np.array([b["held"]["ci95"][0] for b in bins])
            hi = np.array([b["held"]["ci95"][1] for b in bins]) - y
            ax.errorbar(x, 100 * y, yerr=100 * np.vstack([lo, hi]), marker="o", capsize=3, label=label)
        ax.set_title(f"{name} ({m['paired_runs']} seeds)")
        ax.set_xlabel("person's peak torso speed [m/s]")
        ax.set_ylim(0.0, 100.0)
        ax.grid(alpha=0.3)
    for row in axes:
        row[0].set_ylabel("runs held [%] (Wilson 95 %)")
    axes[0, -1].legend(loc="upper right", fontsize="small")
    return save_figure(fig, Path(path))
