"""Randomized batches: many seeds of one scenario family on a process pool, resumable."""

from __future__ import annotations

import logging
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from compare.config import Config, parse_config
from compare.results import collect_sweep, is_finished, sweep_run_dir, write_sweep_summary

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


def _run_one(config: Config, config_text: str, run_dir: Path) -> tuple[Path, str | None]:
    """Worker: one seed, no plots, no progress bar; returns (dir, error or None)."""
    import os

    os.environ.setdefault("MUJOCO_GL", "egl")
    from compare.run import run_scenario

    try:
        summary = run_scenario(config, run_dir, config_text=config_text, progress=False, make_plots=False)
    except Exception as exc:  # keep the sweep going; the run is retried on the next invocation
        return run_dir, f"{type(exc).__name__}: {exc}"
    errors = summary.get("errors") or {}
    return run_dir, "; ".join(f"{k}: {v}" for k, v in errors.items()) or None


def run_sweep(
    config: Config,
    config_text: str,
    out_dir: Path,
    n: int,
    workers: int = 2,
    methods: list[str] | None = None,
) -> dict[str, Any]:
    """Run seeds ``seed .. seed + n − 1`` of ``config``; skip runs already finished.

    Returns:
        The sweep summary written to ``out_dir/sweep_summary.json``.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "config.toml").write_text(config_text, encoding="utf-8")
    names = methods or list(config.methods.names)
    jobs: list[tuple[Config, Path]] = []
    skipped = 0
    for i in range(n):
        run_dir = sweep_run_dir(out_dir, i)
        if is_finished(run_dir, names):
            skipped += 1
            continue
        jobs.append((_seeded(config, config.scenario.seed + i, methods), run_dir))
    failures: list[str] = []
    columns = (TextColumn("[bold]sweep"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
    with Progress(*columns) as bar:
        task = bar.add_task("runs", total=n, completed=skipped)
        if jobs:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                futures = [pool.submit(_run_one, cfg, config_text, run_dir) for cfg, run_dir in jobs]
                for fut in as_completed(futures):
                    run_dir, error = fut.result()
                    if error:
                        failures.append(f"{run_dir.name}: {error}")
                        log.warning("run %s failed: %s", run_dir.name, error)
                    bar.advance(task)
    if skipped:
        log.info("skipped %d finished runs", skipped)
    collect_sweep(out_dir)
    summary = write_sweep_summary(out_dir)
    summary.setdefault("skipped_finished_runs", skipped)
    if failures:
        summary.setdefault("failed_runs", failures)
    try:
        from compare.plots import plot_sweep

        plot_sweep(out_dir)
    except Exception as exc:  # plots must never lose the results
        log.warning("sweep plots failed: %s", exc)
    return summary
