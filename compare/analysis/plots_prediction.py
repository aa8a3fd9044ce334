"""The prediction of a run against the truth: ``plots/<method>_prediction.png``.

Per control point two panels: the distance to the person (true, measured, and the predicted
distance the obstacle task held, :mod:`compare.sensing.prediction`) with the safety threshold;
and the predicted closing speed against the true one
(:func:`compare.analysis.prediction_quality.true_closing_of_steps`). Only for runs with
``[prediction]`` (``dist_pred:<cp>`` columns).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from compare.analysis.metrics import set_tasks_from_summary
from compare.analysis.plot_style import PLOTS_DIR, SAFETY_STYLE, figure, finite, save_figure
from compare.analysis.prediction_quality import run_track, true_closing_of_steps
from compare.analysis.results import load_steps, load_summary, safe_name

log = logging.getLogger(__name__)


def plot_predictions(results_dir: Path) -> list[Path]:
    """``<method>_prediction.png`` for every method of a run recorded with prediction; the files written."""
    results_dir = Path(results_dir)
    summary = load_summary(results_dir)
    methods = summary.get("methods") or {}
    tables = {}
    for name in methods:
        try:
            steps = load_steps(results_dir, name)
        except FileNotFoundError:
            continue
        cps = [c.split(":", 1)[1] for c in steps.columns if c.startswith("dist_pred:")]
        if cps:
            tables[name] = (steps, cps)
    if not tables:
        return []
    _, robot, track = run_track(results_dir)
    paths: list[Path] = []
    for name, (steps, cps) in tables.items():
        safety = [t.safety_lower for t in set_tasks_from_summary(methods[name]) if t.group == "obstacles"]
        t = steps["t"].to_numpy(dtype=float)
        fig, axes = figure(2 * len(cps), 1, height_in=1.9 * 2 * len(cps) + 0.6)
        for k, cp in enumerate(cps):
            ax_d, ax_v = axes[2 * k, 0], axes[2 * k + 1, 0]
            ax_d.plot(t, finite(steps[f"dist_true:{cp}"]), color="tab:blue", label="true")
            ax_d.plot(t, finite(steps[f"dist_meas:{cp}"]), color="tab:green", linestyle="--", label="measured")
            ax_d.plot(t, finite(steps[f"dist_pred:{cp}"]), color="tab:orange", label="predicted (task's point)")
            if safety:
                ax_d.axhline(min(safety), **SAFETY_STYLE, label="safety threshold")
            ax_d.set_ylabel(f"{cp} [m]")
            ax_d.set_ylim(bottom=0.0)
            ax_d.grid(alpha=0.3)
            seen = np.isfinite(steps[f"dist_pred:{cp}"].to_numpy(dtype=float))
            truth = true_closing_of_steps(steps, robot, track, cp)
            ax_v.plot(t, truth, color="tab:blue", label="true closing speed")
            ax_v.plot(t, np.where(seen, steps[f"closing_pred:{cp}"], np.nan), color="tab:orange", label="predicted")
            ax_v.set_ylabel(f"{cp} [m/s]")
            ax_v.grid(alpha=0.3)
        axes[0, 0].set_title(f"{name}: predicted vs true distance and closing speed")
        axes[0, 0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
        axes[1, 0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
        axes[-1, 0].set_xlabel("t [s]")
        paths.append(save_figure(fig, results_dir / PLOTS_DIR / f"{safe_name(name)}_prediction.png"))
    return paths
