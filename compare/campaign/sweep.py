"""Randomized batches: many seeds of one scenario family, resumable, on local processes or Ray.

``run_sweep`` runs seeds ``seed .. seed + n − 1``; a run whose ``summary.json`` already holds
every method is skipped, so an interrupted campaign is resumed by running the same command
again. The executor (:mod:`compare.campaign.executors`) only decides *where* a run executes: the same
seed gives the same results on either.

Afterwards the sweep directory holds ``runs/<index>/`` (one run each), ``sweep_runs.csv`` (one
row per run and method), ``sweep_summary.json`` (per-method aggregates plus a ``campaign``
entry: executor, workers, wall time), ``plots/`` and ``sweep_report.md``.
"""

from __future__ import annotations

import logging
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from compare.analysis.avoidability import has_oracle, oracle_sweep_summary
from compare.analysis.results import (
    SWEEP_SUMMARY_FILE,
    collect_sweep,
    is_finished,
    sweep_run_dir,
    write_json_atomic,
    write_sweep_summary,
)
from compare.campaign.executors import Job, SweepExecutor, make_executor
from compare.config import Config, parse_config

log = logging.getLogger(__name__)


def _seeded(config: Config, seed: int, methods: list[str] | None) -> Config:
    data = config.model_dump(mode="python")
    data["scenario"]["seed"] = seed
    if methods:
        data["methods"] = {
            "names": methods,
            "settings": {k: v for k, v in config.methods.settings.items() if k in methods},
        }
    return parse_config(data)


def sweep_jobs(
    config: Config, config_text: str, out_dir: Path, n: int, methods: list[str] | None = None
) -> tuple[list[Job], int]:
    """The runs of a sweep still to do, and how many are already finished."""
    names = methods or list(config.methods.names)
    jobs: list[Job] = []
    skipped = 0
    for i in range(n):
        run_dir = sweep_run_dir(out_dir, i)
        if is_finished(run_dir, names) and (not config.oracle.enabled or has_oracle(run_dir)):
            skipped += 1
            continue
        jobs.append(Job(_seeded(config, config.scenario.seed + i, methods), config_text, run_dir))
    return jobs, skipped


def run_sweep(
    config: Config,
    config_text: str,
    out_dir: Path,
    n: int,
    workers: int = 2,
    methods: list[str] | None = None,
    executor: str | SweepExecutor = "local",
    address: str | None = None,
    progress: bool = True,
    report: bool = True,
    command: str | None = None,
) -> dict[str, Any]:
    """Run seeds ``seed .. seed + n − 1`` of ``config``; skip runs already finished.

    Args:
        config: The scenario family (``kind = "random"`` for a randomized sweep).
        config_text: Its TOML text (copied into the sweep and every run directory).
        out_dir: Sweep directory.
        n: Number of runs.
        workers: Local worker processes, or CPUs of the local Ray instance.
        methods: Methods to run instead of the config's.
        executor: ``local`` (default), ``ray``, or a :class:`~compare.campaign.executors.SweepExecutor`.
        address: Ray cluster address (``--address``); None = a local Ray instance.
        progress: Show a progress bar.
        report: Write the plots and ``sweep_report.md`` at the end.
        command: Command line recorded in the summary and the report (default: ``sys.argv``).

    Returns:
        The sweep summary written to ``out_dir/sweep_summary.json``.

    Raises:
        compare.campaign.executors.ExecutorUnavailable: The executor cannot run here.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "config.toml").write_text(config_text, encoding="utf-8")
    runner = executor if isinstance(executor, SweepExecutor) else make_executor(executor, workers, address)
    jobs, skipped = sweep_jobs(config, config_text, out_dir, n, methods)
    failures: list[str] = []
    columns = (TextColumn("[bold]sweep"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
    start = time.perf_counter()
    with Progress(*columns, disable=not progress) as bar:
        task = bar.add_task("runs", total=n, completed=skipped)

        def done(run_dir: Path, error: str | None) -> None:
            if error:
                failures.append(f"{run_dir.name}: {error}")
                log.warning("run %s failed: %s", run_dir.name, error)
            bar.advance(task)

        runner.run(jobs, done)
    wall = time.perf_counter() - start
    if skipped:
        log.info("skipped %d finished runs", skipped)
    collect_sweep(out_dir)
    summary = write_sweep_summary(out_dir)
    summary["skipped_finished_runs"] = skipped
    summary["campaign"] = {
        **runner.describe(),
        "runs_requested": n,
        "runs_executed": len(jobs),
        "wall_time_s": wall,
        "wall_time_per_run_s": wall / len(jobs) if jobs else None,
        "command": command or " ".join(shlex.quote(a) for a in sys.argv),
        "plant": _plant(config),
    }
    if failures:
        summary["failed_runs"] = failures
    split = oracle_sweep_summary(out_dir)
    if split is not None:  # avoidable / unavoidable obstacle violations (compare.analysis.avoidability)
        summary["oracle"] = split["oracle"]
        for name, extra in split["methods"].items():
            summary["methods"].setdefault(name, {}).update(extra)
    write_json_atomic(out_dir / SWEEP_SUMMARY_FILE, summary)
    if report:
        try:
            from compare.analysis.plots import plot_campaign, plot_sweep

            plot_sweep(out_dir)
            plot_campaign(out_dir)
        except Exception as exc:  # plots must never lose the results
            log.warning("sweep plots failed: %s", exc)
        try:
            from compare.analysis.report import render_sweep_report

            render_sweep_report(out_dir)
        except Exception as exc:
            log.warning("sweep report failed: %s", exc)
    return summary


def _plant(config: Config) -> dict[str, object]:
    """What the runs were simulated with: sensing, simulation and (dynamic) joint drive."""
    sc = config.scenario
    plant: dict[str, object] = {"sensing": sc.sensing, "simulation": sc.simulation}
    if sc.simulation == "dynamic":
        plant["drive"] = sc.drive
        if sc.drive == "decoupled":
            plant["drive_bandwidth_rad_s"] = sc.drive_bandwidth_rad_s
    return plant
