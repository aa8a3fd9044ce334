"""Up-front checks of an output directory: writable, and room for the results expected.

Both are checked before the first control step (:class:`compare.analysis.results.ResultsWriter`
and :func:`compare.campaign.sweep.run_sweep` call :func:`check_output_dir`), so a full disk or a
read-only directory is one line at the start, not a traceback after hours of simulation.

The size of a run is predictable: its per-step tables have one row per control step
(duration × control rate) and one column per recorded quantity (:func:`step_columns`). Parquet
stores our columns in about 3.8 bytes per value plus about 575 bytes of metadata per column and
file (measured on case 2: 74 columns, 1 to 1200 rows); :data:`BYTES_PER_VALUE` and
:data:`BYTES_PER_COLUMN` keep a margin above that.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from compare.analysis.exceptions import OutputUnusable

BYTES_PER_VALUE = 6.0
"""Bytes per (step, column) of a Parquet per-step table, with a margin (measured: 3.8)."""

BYTES_PER_COLUMN = 700
"""Fixed bytes per column of a Parquet file (schema, statistics; measured: 575)."""

SUMMARY_BYTES_PER_METHOD = 16_000
"""``summary.json`` size per method (measured: ~10 kB)."""

PLOTS_BYTES_PER_METHOD = 1_500_000
"""PNG plots of one method of a ``run`` (sweeps draw no per-run plots)."""

RESERVE_BYTES = 16 * 1024**2
"""Free space left over after the results (logs, temporary files of the atomic writes)."""


def step_columns(nq: int, n_set_tasks: int, n_obstacle_tasks: int, n_control_points: int = 3) -> int:
    """Columns of a per-step table (:mod:`compare.loop.closed_loop`, ISO/TS 15066, faults).

    9 timing/EE columns, q and q̇ per joint, σ and active per set task, the ground truth of each
    obstacle task, measured and true distance, ``occluded`` and ``camera`` per control point, 6
    status columns, the 4 ISO columns per control point (fault flags, only with ``[faults]``, are
    not counted).
    """
    return 9 + 2 * nq + 2 * n_set_tasks + n_obstacle_tasks + 4 * n_control_points + 6 + 4 * n_control_points


def run_bytes(steps: int, columns: int, methods: int, plots: bool) -> int:
    """Expected size of one run directory [bytes]."""
    per_method = columns * (BYTES_PER_COLUMN + steps * BYTES_PER_VALUE) + SUMMARY_BYTES_PER_METHOD
    if plots:
        per_method += PLOTS_BYTES_PER_METHOD
    return int(per_method * methods)


def _megabytes(n: float) -> str:
    return f"{n / 1e6:.0f} MB" if n < 1e9 else f"{n / 1e9:.1f} GB"


def check_output_dir(path: Path, expected_bytes: int = 0, what: str = "the results") -> None:
    """Create ``path`` if needed and check that it can be written and has room for ``expected_bytes``.

    Raises:
        OutputUnusable: One line: the directory cannot be created or written (the OS's reason), or
            the file system has less free space than ``expected_bytes`` plus :data:`RESERVE_BYTES`.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputUnusable(f"{path} is a file, not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputUnusable(f"cannot create {path}: {exc.strerror or exc}") from None
    try:
        fd, probe = tempfile.mkstemp(prefix=".write-probe.", dir=path)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputUnusable(f"cannot write to {path}: {exc.strerror or exc}") from None
    if expected_bytes <= 0:
        return
    free = free_bytes(path)
    if free is not None and free < expected_bytes + RESERVE_BYTES:
        raise OutputUnusable(
            f"not enough disk space in {path} for {what}: about {_megabytes(expected_bytes)} needed, "
            f"{_megabytes(free)} free"
        )


def free_bytes(path: Path) -> int | None:
    """Free space of the file system of ``path`` for this user [bytes] (None if unknown)."""
    with contextlib.suppress(OSError):
        return int(shutil.disk_usage(path).free)
    return None
