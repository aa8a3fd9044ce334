r"""A new per-run metric in one file: how far the end effector travelled (``docs/extending.md``).

.. math:: L = \sum_k \lVert p_{k+1} - p_k \rVert

over the EE positions :math:`p_k` (``ee_x``, ``ee_y``, ``ee_z`` [m]) of the per-step table.
Import it (``[extensions] modules = ["ee_path_length.py"]`` in a scenario TOML) and every run's
``summary.json`` holds ``ee_path_length_m`` per method, a sweep's ``sweep_runs.csv`` has its
column and ``sweep_summary.json`` its median and largest value over the runs; the run table and
the sweep report show it.
"""

from __future__ import annotations

import numpy as np

from compare.analysis.metric import Metric, RunSteps
from compare.analysis.metrics import register_metric


def ee_path_length(run: RunSteps) -> float | None:
    """Length of the EE path [m]; steps without a finite position are left out (None: under two)."""
    p = np.column_stack([run.column(axis) for axis in ("ee_x", "ee_y", "ee_z")])  # (T, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else None


register_metric(
    Metric(
        "ee_path_length_m",  # the key in summary.json and the column of sweep_runs.csv
        "m",
        ee_path_length,
        aggregate=("median", "max"),  # sweep_summary.json: {"median": ..., "max": ...} over the runs
        label="EE path",  # the run table's column "EE path [m]"; the sweep report's per statistic
        fmt=".3f",
    )
)
