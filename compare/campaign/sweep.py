"""Randomized batches: many seeds of one scenario family, resumable, on local processes or Ray.

``run_sweep`` runs seeds ``seed .. seed + n − 1``. The sweep directory records what it is
(``sweep_manifest.json``, :mod:`compare.campaign.manifest`: config hash, plant, seeds, methods,
project version) before its first run, and a re-run of the same command resumes it:

* a (run, method) pair whose results are complete and readable
  (:func:`compare.analysis.results.finished_methods`) is kept; a missing or incomplete one is run
  (a run whose ``summary.json`` cannot be read is run again whole);
* adding methods (``-m``) or runs (``--n``) runs only the missing pairs;
* a different configuration, plant, first seed, method settings or project version is refused
  with one line, before anything runs (``--overwrite`` discards the directory's sweep, another
  ``--out`` starts a new one);
* the directory must be writable with room for the pairs still to run (an up-front check).

The executor (:mod:`compare.campaign.executors`) only decides *where* a run executes: the same
seed gives the same results on either.

Afterwards the sweep directory holds ``runs/<index>/`` (one run each), ``sweep_runs.csv`` (one
row per run and method), ``sweep_summary.json`` (per-method aggregates over every finished pair
in the directory, plus a ``campaign`` entry: executor, workers, wall time), ``plots/`` and
``sweep_report.md``.
"""

from __future__ import annotations

import logging
import os
import shlex
import sys
import time
from pathlib import Path
from typing import Any

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from compare.analysis.atomic_files import remove_stale_temporaries, write_text_atomic
from compare.analysis.avoidability import oracle_sweep_summary
from compare.analysis.exceptions import ResultsConflict
from compare.analysis.person_speeds import sweep_person_speeds
from compare.analysis.plots import plot_campaign, plot_sweep
from compare.analysis.preflight import check_output_dir
from compare.analysis.report import render_sweep_report
from compare.analysis.results import (
    CONFIG_FILE,
    PLOTS_DIR,
    STEPS_DIR,
    SUMMARY_FILE,
    SWEEP_SUMMARY_FILE,
    DirectoryLock,
    finished_methods,
    is_sweep_dir,
    load_summary,
    run_summaries,
    sweep_run_dir,
    write_json_atomic,
    write_sweep_summary,
)
from compare.campaign.executors import Job, SweepExecutor, make_executor
from compare.campaign.manifest import (
    check_resume,
    clear_sweep,
    load_manifest,
    make_manifest,
    merge_manifests,
    run_config_hash,
    write_manifest,
)
from compare.config import Config, import_extensions, parse_config
from compare.loop.steal_clock import steal_ticks
from compare.run import expected_run_bytes

log = logging.getLogger(__name__)


def seeded_config(config: Config, seed: int, methods: list[str] | None) -> Config:
    """The configuration of one run of a sweep: ``config`` with ``scenario.seed = seed`` and only ``methods``."""
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
    """The runs of a sweep still to do (each with its missing methods), and how many are finished.

    Raises:
        ResultsConflict: A run directory holds a run of another configuration.
    """
    names = methods or list(config.methods.names)
    manifest = make_manifest(config, n, names)
    jobs: list[Job] = []
    skipped = 0
    for i in range(n):
        run_dir = sweep_run_dir(out_dir, i)
        remove_stale_temporaries(run_dir)  # a killed writer's (no worker runs yet; the sweep is locked)
        remove_stale_temporaries(run_dir / STEPS_DIR)
        seed = config.scenario.seed + i
        todo, overwrite = list(names), False
        if (run_dir / SUMMARY_FILE).exists():
            try:
                summary = load_summary(run_dir)
            except (OSError, ValueError):
                log.warning("run %s: summary.json unreadable, running it again", run_dir.name)
                overwrite = True
            else:
                if summary.get("config_hash") != run_config_hash(manifest, i):
                    raise ResultsConflict(
                        f"{run_dir} holds a run of another configuration than this sweep's; "
                        "use --overwrite to discard the sweep, or another --out"
                    )
                done = finished_methods(run_dir, summary)
                todo = [m for m in names if m not in done]
        if not todo:
            skipped += 1
            continue
        jobs.append(Job(seeded_config(config, seed, todo), config_text, run_dir, overwrite))
    return jobs, skipped


def prepare_sweep_dir(config: Config, out_dir: Path, n: int, names: list[str], overwrite: bool) -> dict[str, Any]:
    """Check ``out_dir`` for this sweep (module docstring) and write its manifest; returns it.

    Raises:
        ResultsConflict: Not this sweep's directory (one line saying what differs).
    """
    if (out_dir / SUMMARY_FILE).exists() and not is_sweep_dir(out_dir):
        raise ResultsConflict(f"{out_dir} holds a single run, not a sweep; give the sweep its own --out")
    if overwrite:
        clear_sweep(out_dir)
    remove_stale_temporaries(out_dir)
    remove_stale_temporaries(out_dir / PLOTS_DIR)  # a plot killed mid-write
    old = load_manifest(out_dir)
    new = make_manifest(config, n, names)
    if old is not None:
        check_resume(old, new, out_dir)
    return merge_manifests(old, new)


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
    overwrite: bool = False,
) -> dict[str, Any]:
    """Run seeds ``seed .. seed + n − 1`` of ``config``; keep the (run, method) pairs already finished.

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
        overwrite: Discard the sweep already in ``out_dir`` first.

    Returns:
        The sweep summary written to ``out_dir/sweep_summary.json``.

    Raises:
        compare.config.ConfigError: An ``[extensions]`` module cannot be imported.
        compare.campaign.executors.ExecutorUnavailable: The executor cannot run here.
        compare.analysis.exceptions.ResultsError: ``out_dir`` holds another sweep or a run, is
            being written by another process, cannot be written or has no room for the runs to do.
    """
    out_dir = Path(out_dir)
    names = methods or list(config.methods.names)
    import_extensions(config.extensions.modules)  # their metrics are aggregated here, not in the workers
    check_output_dir(out_dir)
    lock = DirectoryLock(out_dir)
    try:
        manifest = prepare_sweep_dir(config, out_dir, n, names, overwrite)
        runner = executor if isinstance(executor, SweepExecutor) else make_executor(executor, workers, address)
        jobs, skipped = sweep_jobs(config, config_text, out_dir, n, methods)
        pairs = sum(len(j.config.methods.names) for j in jobs)
        if pairs:
            per_pair = expected_run_bytes(config, config.load_robot(), 1, plots=False)
            check_output_dir(out_dir, pairs * per_pair, f"{pairs} (run, method) pairs")
        write_manifest(out_dir, manifest)
        if not (out_dir / CONFIG_FILE).exists():
            write_text_atomic(out_dir / CONFIG_FILE, config_text)
        return _execute(config, out_dir, n, runner, jobs, skipped, pairs, progress, report, command)
    finally:
        lock.release()


def _execute(
    config: Config,
    out_dir: Path,
    n: int,
    runner: SweepExecutor,
    jobs: list[Job],
    skipped: int,
    pairs: int,
    progress: bool,
    report: bool,
    command: str | None,
) -> dict[str, Any]:
    """Run the jobs, then write the sweep summary, plots and report."""
    failures: list[str] = []
    columns = (TextColumn("[bold]sweep"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
    start = time.perf_counter()
    cpu0 = os.times()
    steal0 = machine_steal_s()
    with Progress(*columns, disable=not progress) as bar:
        task = bar.add_task("runs", total=n, completed=skipped)

        def done(run_dir: Path, error: str | None) -> None:
            if error:
                failures.append(f"{run_dir.name}: {error}")
                log.warning("run %s failed: %s", run_dir.name, error)
            bar.advance(task)

        runner.run(jobs, done)
    wall = time.perf_counter() - start
    cpu, cpu_system = _cpu_since(cpu0) if runner.name == "local" else (None, None)
    steal1 = machine_steal_s()
    sim_s = sum(j.config.scenario.sim_time_s * len(j.config.methods.names) for j in jobs)
    if skipped:
        log.info("skipped %d finished runs", skipped)
    summary = write_sweep_summary(out_dir)
    summary["skipped_finished_runs"] = skipped
    summary["campaign"] = {
        **runner.describe(),
        "runs_requested": n,
        "runs_executed": len(jobs),
        "pairs_executed": pairs,
        "wall_time_s": wall,
        "wall_time_per_run_s": wall / len(jobs) if jobs else None,
        # Throughput (docs/benchmarks.md "Campaign throughput"): simulated seconds of the executed
        # (run, method) pairs per CPU second of this process and its workers (local executor only).
        "cpu_time_s": cpu,
        "sim_s_per_cpu_s": sim_s / cpu if cpu else None,
        # The kernel-mode part of cpu_time_s [s]: file writes and their fsync, the steal counter
        # reads of the solver time limit (/proc/stat, [solver_limit] exclude_steal).
        "cpu_system_s": cpu_system,
        # CPU time the hypervisor gave to others while the sweep ran (all vCPUs; None off Linux):
        # the solver time limit's CPU clock counts it on a VM (docs/benchmarks.md, "Deadline misses").
        "steal_time_s": steal1 - steal0 if steal0 is not None and steal1 is not None else None,
        "command": command or " ".join(shlex.quote(a) for a in sys.argv),
        "plant": _plant(config),
    }
    if failures:
        summary["failed_runs"] = failures
    speeds = sweep_person_speeds(run_summaries(out_dir))
    if speeds is not None:
        summary["person"] = {"max_speed_mps": speeds}
    split = oracle_sweep_summary(out_dir)
    if split is not None:  # obstacle violations by the run's verdict (compare.analysis.avoidability)
        summary["oracle"] = split["oracle"]
        for name, extra in split["methods"].items():
            summary["methods"].setdefault(name, {}).update(extra)
        summary["paired_avoidable"] = split["paired_avoidable"]
    write_json_atomic(out_dir / SWEEP_SUMMARY_FILE, summary)
    if report:
        try:
            plot_sweep(out_dir)
            plot_campaign(out_dir)
        except Exception as exc:  # plots must never lose the results
            log.warning("sweep plots failed: %s", exc)
        try:
            render_sweep_report(out_dir)
        except Exception as exc:
            log.warning("sweep report failed: %s", exc)
    return summary


def machine_steal_s(stat: Path = Path("/proc/stat")) -> float | None:
    """Steal time of all CPUs since boot [s]: the 8th value of the ``cpu`` line of ``/proc/stat``.

    Steal is time a virtual machine's CPU was runnable but the hypervisor ran something else
    (USER_HZ ticks, 10 ms). None where the file or the field is missing (not Linux, old kernels).
    """
    try:
        with stat.open(encoding="ascii") as fh:
            fields = fh.readline().split()
    except OSError:
        return None
    ticks = steal_ticks(fields) if fields and fields[0] == "cpu" else None
    return None if ticks is None else ticks / os.sysconf("SC_CLK_TCK")


def _cpu_since(start: os.times_result) -> tuple[float, float]:
    """CPU time [s] of this process and its finished child processes since ``start``: (user + system, system)."""
    now = os.times()
    system = now.system - start.system + now.children_system - start.children_system
    user = now.user - start.user + now.children_user - start.children_user
    return user + system, system


def _plant(config: Config) -> dict[str, object]:
    """What the runs were simulated with: sensing, simulation and (dynamic) joint drive."""
    sc = config.scenario
    plant: dict[str, object] = {"sensing": sc.sensing, "simulation": sc.simulation}
    if sc.simulation == "dynamic":
        plant["drive"] = sc.drive
        if sc.drive == "decoupled":
            plant["drive_bandwidth_rad_s"] = sc.drive_bandwidth_rad_s
    return plant
