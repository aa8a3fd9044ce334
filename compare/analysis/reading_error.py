r"""How far the measured obstacle distances were from the truth, per method, over runs or sweeps.

Each step table holds, per control point P, the distance the obstacle source measured
(``dist_meas:P``, +inf: nothing within ρ) and the ground truth to the person's capsules
(``dist_true:P``). Over the steps × control points with the person truly within ``within_m``
the reading error is

.. math:: e = d_\text{meas} - d_\text{true}\quad[\text{m}],

negative when the reading is short of the truth (conservative: the arm keeps farther away) and
positive when it reads too far (the dangerous side). Reported per directory and method: the
samples, the median, mean, 5th and 95th percentiles of e, the shares read short and read far
by more than :data:`OFF_M`, the largest over-estimate, the share read from occluded space (``occluded:P``)
and the share missed (no reading although the person was within ``within_m``).

``python -m compare.analysis.reading_error DIR [DIR ...] [--method M] [--within 0.45] [--runs N]``
prints them; each DIR is a run (``summary.json``) or a sweep (``runs/``).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from compare.analysis.results import SUMMARY_FILE, load_steps, run_dirs
from compare.arguments import ArgumentParser, existing_dir, output_path, positive_float, positive_int

OFF_M = 0.01
"""A reading shorter (longer) than the truth by more than this counts as read short (far) [m]."""


def step_errors(steps: pd.DataFrame, within_m: float) -> tuple[np.ndarray, int, int]:
    """Reading errors e [m] of one step table where the truth is within ``within_m``.

    Returns:
        (e of the samples with a reading, how many of them were read from occluded space, how many
        samples had no reading).
    """
    errors: list[np.ndarray] = []
    occluded = missed = 0
    for col in (c for c in steps.columns if c.startswith("dist_true:")):
        cp = col.split(":", 1)[1]
        truth = steps[col].to_numpy(dtype=float)
        meas = steps[f"dist_meas:{cp}"].to_numpy(dtype=float)
        near = np.isfinite(truth) & (truth < within_m)
        read = near & np.isfinite(meas)
        missed += int((near & ~np.isfinite(meas)).sum())
        if f"occluded:{cp}" in steps.columns:
            occluded += int(steps[f"occluded:{cp}"].to_numpy(dtype=bool)[read].sum())
        errors.append(meas[read] - truth[read])
    return (np.concatenate(errors) if errors else np.zeros(0)), occluded, missed


def summarize_errors(errors: np.ndarray, occluded: int, missed: int) -> dict[str, Any]:
    """The figures of the module docstring (errors [m] in, [mm] out); ``samples`` counts the missed too."""
    n = errors.size
    out: dict[str, Any] = {"samples": n + missed}
    if n == 0:
        return {**out, "missed_share": 1.0 if missed else float("nan")}
    mm = 1e3 * errors
    return {
        **out,
        "median_mm": float(np.median(mm)),
        "mean_mm": float(np.mean(mm)),
        "p5_mm": float(np.percentile(mm, 5)),
        "p95_mm": float(np.percentile(mm, 95)),
        "short_share": float(np.mean(errors < -OFF_M)),
        "far_share": float(np.mean(errors > OFF_M)),
        "largest_over_mm": float(np.max(mm)),
        "occluded_share": occluded / n,
        "missed_share": missed / (n + missed),
    }


def reading_errors(
    directory: Path, methods: Sequence[str] = (), within_m: float = 0.45, max_runs: int | None = None
) -> list[dict[str, Any]]:
    """One row per method of ``directory`` (only ``methods`` when given): :func:`summarize_errors` of all its runs."""
    pooled: dict[str, tuple[list[np.ndarray], list[int], list[int]]] = {}
    for run in run_dirs(directory, max_runs):
        summary = json.loads((run / SUMMARY_FILE).read_text(encoding="utf-8"))
        for method in summary.get("methods") or {}:
            if methods and method not in methods:
                continue
            steps = load_steps(run, method)
            e, occ, miss = step_errors(steps, within_m)
            acc = pooled.setdefault(method, ([], [], []))
            acc[0].append(e)
            acc[1].append(occ)
            acc[2].append(miss)
    rows = []
    for method, (errs, occ, miss) in pooled.items():
        figures = summarize_errors(np.concatenate(errs), sum(occ), sum(miss))
        rows.append({"directory": str(directory), "method": method, "runs": len(errs), **figures})
    return rows


def main(argv: list[str] | None = None) -> int:
    """Print the reading errors per directory and method; ``--json`` writes them too."""
    parser = ArgumentParser(
        prog="python -m compare.analysis.reading_error",
        description="Measured obstacle distances against the truth where the person is within --within:\n"
        "median, mean, 5th/95th percentile of measured - true [mm] (negative: read short, conservative),\n"
        "the shares read short and far by more than 1 cm, the largest over-estimate [mm], the shares read from\n"
        "occluded space and missed, per directory and method.",
    )
    parser.add_argument(
        "directories", nargs="+", type=existing_dir, help="run (summary.json) or sweep (runs/) directories"
    )
    parser.add_argument(
        "-m", "--method", action="append", default=[], help="only this method (repeatable; default: all)"
    )
    parser.add_argument(
        "--within",
        type=positive_float,
        default=0.45,
        metavar="M",
        help="true distance below which a step counts [m] (0.45)",
    )
    parser.add_argument("--runs", type=positive_int, default=None, metavar="N", help="only the first N runs of a sweep")
    parser.add_argument("--json", type=output_path, default=None, metavar="FILE", help="also write the rows as JSON")
    args = parser.parse_args(argv)
    for directory in args.directories:
        if not run_dirs(directory):
            parser.error(f"{directory} is neither a run (summary.json) nor a sweep (runs/) directory")
    rows = [row for d in args.directories for row in reading_errors(d, args.method, args.within, args.runs)]
    if not rows:
        print("no run of the selected methods")
        return 0
    print(pd.DataFrame(rows).round(3).to_string(index=False))
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
