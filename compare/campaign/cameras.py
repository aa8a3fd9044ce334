r"""One camera against two on the same seeds: obstacle violations and time below the physical threshold.

Two sweeps of the same scenario family and seeds, depth sensing, one with the scene's single
camera and one with a second camera (``configs/random.toml`` and
``configs/random_two_cameras.toml``, which differ only by ``[[sensor.cameras]]``): the person's
path, the start pose, the waypoints and camera 1's noise are drawn identically. Per method and
setup, from each run's ``summary.json`` (ground-truth distances):

* **obstacle violation**: the run has an episode below an obstacle task's safety threshold
  (``obstacles.violations`` > 0); rate with its Wilson 95 % interval, and the two setups
  compared pairwise per seed with the exact McNemar test (binomial test on the discordant runs);
* **time below the physical threshold**: ``obstacles.physical_violation_time_s`` per run; mean,
  median, p95, and a Wilcoxon signed-rank test on the per-seed differences;
* **occluded readings**: share of the control steps whose reading was assumed from hidden space
  (from the per-step tables, ``occluded:<cp>``), the quantity the second camera exists to cut.

Run::

    python -m compare.campaign.cameras results/cam1 results/cam2 --out docs/campaign-cameras
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from scipy import stats

from compare.analysis.results import RUNS_DIR, load_steps, load_summary, write_json_atomic
from compare.analysis.statistics import mcnemar, rate
from compare.arguments import ArgumentParser, existing_dir, output_dir

FIGURE = "camera_comparison.png"
RESULT = "camera_comparison.json"


def _runs(sweep_dir: Path) -> pd.DataFrame:
    """One row per (seed, method) of a sweep: violation flag, physical time, occluded share."""
    rows: list[dict[str, Any]] = []
    runs_dir = Path(sweep_dir) / RUNS_DIR
    if not runs_dir.is_dir():
        raise FileNotFoundError(f"{sweep_dir}: no {RUNS_DIR}/ directory (not a sweep)")
    for run_dir in sorted(p for p in runs_dir.iterdir() if p.is_dir()):
        try:
            summary = load_summary(run_dir)
        except (OSError, ValueError):
            continue
        for method, msum in (summary.get("methods") or {}).items():
            obstacles = msum.get("obstacles") or {}
            rows.append(
                {
                    "seed": summary.get("seed"),
                    "method": method,
                    "violation": int(obstacles.get("violations") or 0) > 0,
                    "physical_time_s": float(obstacles.get("physical_violation_time_s") or 0.0),
                    "occluded_share": _occluded_share(run_dir, method),
                }
            )
    return pd.DataFrame(rows, columns=["seed", "method", "violation", "physical_time_s", "occluded_share"])


def _occluded_share(run_dir: Path, method: str) -> float:
    try:
        steps = load_steps(run_dir, method)
    except (OSError, ValueError):
        return math.nan
    cols = [c for c in steps.columns if c.startswith("occluded:")]
    if not cols or steps.empty:
        return math.nan
    return float(steps[cols].to_numpy(dtype=bool).any(axis=1).mean())


def _times(x: np.ndarray) -> dict[str, float | None]:
    if x.size == 0:
        return {"mean": None, "median": None, "p95": None, "max": None}
    return {
        "mean": float(x.mean()),
        "median": float(np.median(x)),
        "p95": float(np.percentile(x, 95)),
        "max": float(x.max()),
    }


def compare_sweeps(one_dir: Path, two_dir: Path) -> dict[str, Any]:
    """Paired comparison of a one-camera and a two-camera sweep (module docstring).

    Returns:
        ``{"one": dir, "two": dir, "methods": {method: {"paired_runs", "violation": {"one",
        "two", "mcnemar_p", "only_one", "only_two"}, "physical_time_s": {"one", "two",
        "wilcoxon_p"}, "occluded_share": {"one", "two"}}}}``.
    """
    one, two = _runs(one_dir), _runs(two_dir)
    paired = one.merge(two, on=["seed", "method"], suffixes=("_one", "_two"))
    out: dict[str, Any] = {"one": str(one_dir), "two": str(two_dir), "methods": {}}
    for method, rows in paired.groupby("method", sort=False):
        v1 = rows["violation_one"].to_numpy(dtype=bool)
        v2 = rows["violation_two"].to_numpy(dtype=bool)
        test = mcnemar(v1, v2)
        only_one, only_two = test["a_only"], test["b_only"]
        t1 = rows["physical_time_s_one"].to_numpy(dtype=float)
        t2 = rows["physical_time_s_two"].to_numpy(dtype=float)
        diff = t1 - t2
        wilcoxon = float(stats.wilcoxon(t1, t2).pvalue) if np.any(diff != 0.0) else 1.0
        out["methods"][str(method)] = {
            "paired_runs": len(rows),
            "violation": {
                "one": rate(int(v1.sum()), v1.size),
                "two": rate(int(v2.sum()), v2.size),
                "only_one": only_one,
                "only_two": only_two,
                "mcnemar_p": test["p_value"],
            },
            "physical_time_s": {"one": _times(t1), "two": _times(t2), "wilcoxon_p": wilcoxon},
            "occluded_share": {
                "one": _nanmean(rows["occluded_share_one"]),
                "two": _nanmean(rows["occluded_share_two"]),
            },
        }
    return out


def _nanmean(x: pd.Series) -> float | None:
    v = pd.to_numeric(x, errors="coerce").to_numpy(dtype=float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else None


def plot_comparison(result: dict[str, Any], path: Path) -> Path:
    """Violation rate (Wilson interval) and time below the physical threshold, one vs two cameras."""
    methods = list(result["methods"])
    fig = Figure(figsize=(10.0, 3.6), layout="constrained")
    FigureCanvasAgg(fig)
    ax_rate, ax_time = fig.subplots(1, 2)
    x = np.arange(len(methods))
    width = 0.36
    for i, (setup, color) in enumerate((("one", "tab:gray"), ("two", "tab:blue"))):
        label = "1 camera" if setup == "one" else "2 cameras"
        rates, lo, hi, means = [], [], [], []
        for m in methods:
            r = result["methods"][m]["violation"][setup]
            rate = r["rate"] if r["rate"] is not None else np.nan
            rates.append(100 * rate)
            lo.append(100 * (rate - (r["ci95"][0] if r["ci95"][0] is not None else rate)))
            hi.append(100 * ((r["ci95"][1] if r["ci95"][1] is not None else rate) - rate))
            mean = result["methods"][m]["physical_time_s"][setup]["mean"]
            means.append(np.nan if mean is None else mean)
        ax_rate.bar(x + (i - 0.5) * width, rates, width, yerr=[lo, hi], color=color, capsize=3, label=label)
        ax_time.bar(x + (i - 0.5) * width, means, width, color=color, label=label)
    for ax, ylabel, title in (
        (ax_rate, "runs with an obstacle violation [%]", "obstacle violations (Wilson 95 %)"),
        (ax_time, "mean time below physical threshold [s]", "time below the physical threshold"),
    ):
        ax.set_xticks(x, methods)
        ax.set_ylabel(ylabel)
        ax.set_title(title)
        ax.grid(axis="y", alpha=0.3)
    n = max((v["paired_runs"] for v in result["methods"].values()), default=0)
    ax_rate.legend(loc="best", fontsize=8)
    fig.suptitle(f"one vs two depth cameras, {n} paired seeds")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def main(argv: list[str] | None = None) -> int:
    """``python -m compare.campaign.cameras ONE_DIR TWO_DIR --out DIR``: JSON and figure."""
    parser = ArgumentParser(
        prog="python -m compare.campaign.cameras",
        description="One vs two depth cameras on the same seeds (two sweeps of one family): obstacle\n"
        "violation rates (McNemar), time below the physical threshold [s] (Wilcoxon) and occluded\n"
        f"readings per method. Writes {RESULT} and {FIGURE} into --out and prints the JSON.",
    )
    parser.add_argument("one", type=existing_dir, help="sweep directory with one camera (runs/)")
    parser.add_argument("two", type=existing_dir, help="sweep directory with two cameras (runs/)")
    parser.add_argument("--out", type=output_dir, required=True, help="output directory (created)")
    args = parser.parse_args(argv)
    for sweep in (args.one, args.two):
        if not (sweep / RUNS_DIR).is_dir():
            parser.error(f"{sweep}: no {RUNS_DIR}/ directory (not a sweep)")
    result = compare_sweeps(args.one, args.two)
    if not result["methods"]:
        parser.error(f"{args.one} and {args.two} share no (seed, method) run")
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / RESULT, result)
    plot_comparison(result, args.out / FIGURE)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
