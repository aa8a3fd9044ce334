"""What every plot of the project shares: where plots go, the line styles, figures, colours, saving."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from compare.analysis.atomic_files import atomic_write
from compare.analysis.metrics import SetTaskInfo

PLOTS_DIR = "plots"
DPI = 110
SAFETY_STYLE: dict[str, Any] = {"color": "tab:red", "linestyle": "-", "linewidth": 1.2}
PHYSICAL_STYLE: dict[str, Any] = {"color": "tab:red", "linestyle": ":", "linewidth": 1.0}
ACTIVE_STYLE: dict[str, Any] = {"color": "tab:orange", "alpha": 0.15, "linewidth": 0}
OCCLUDED_STYLE: dict[str, Any] = {"color": "tab:purple", "marker": ".", "markersize": 3, "linestyle": "none"}


def figure(nrows: int = 1, ncols: int = 1, height_in: float = 3.2, width_in: float = 8.0) -> tuple[Figure, Any]:
    """A headless figure with an ``nrows`` × ``ncols`` grid of axes (always 2-D) [inches]."""
    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axes


def save_figure(fig: Figure, path: Path) -> Path:
    """Write ``fig`` to ``path`` atomically (the format from its suffix); return the path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=DPI, format=path.suffix.lstrip(".") or "png"))
    return path


def finite(x: pd.Series | np.ndarray) -> np.ndarray:
    """Float array with ±inf replaced by NaN (gaps in the line instead of broken autoscale)."""
    arr = np.asarray(x, dtype=float).copy()
    arr[~np.isfinite(arr)] = np.nan
    return arr


def method_colors(names: list[str]) -> dict[str, Any]:
    """One colour per method, in order (matplotlib's tab10)."""
    cmap = colormaps["tab10"]
    return {name: cmap(i % 10) for i, name in enumerate(names)}


def wall_axis(steps: pd.DataFrame, task: SetTaskInfo, tol_m: float = 1e-6) -> tuple[int, float, float] | None:
    """Recognise an axis-aligned wall on the end effector from the data.

    A wall ``σ = s·p_a − d`` (s = ±1, a ∈ {x, y, z}) has ``s·ee_a − σ`` constant over the run.

    Returns:
        ``(axis index, s, d)``, or None when σ is not such a function of the EE position.
    """
    sigma = steps[f"sigma:{task.name}"].to_numpy(dtype=float)
    for a, axis in enumerate("xyz"):
        col = f"ee_{axis}"
        if col not in steps.columns:
            continue
        p = steps[col].to_numpy(dtype=float)
        ok = np.isfinite(p) & np.isfinite(sigma)
        if not np.any(ok):
            continue
        for s in (1.0, -1.0):
            d = s * p[ok] - sigma[ok]
            if np.ptp(d) < tol_m:
                return a, s, float(np.median(d))
    return None
