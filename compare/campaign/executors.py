"""Where the runs of a sweep execute: local worker processes (default) or a Ray cluster.

Both executors run the same function on the same (config, seed) jobs, so a run's
``summary.json`` is the same whichever executed it (timings aside: see
:data:`compare.analysis.results.TIMING_KEYS`).

* :class:`LocalExecutor`: a :class:`concurrent.futures.ProcessPoolExecutor`; each worker writes
  its run directory directly.
* :class:`RayExecutor`: one Ray task per run (``num_cpus=1``). The worker simulates into a
  temporary directory on its own node and returns the files; the driver writes them into the
  sweep directory (each atomically, ``summary.json`` last and merged with the methods the run
  already had), so the cluster needs no shared file system. The
  nodes must have this project installed (``pip install -e '.[cluster]'``, same version), and
  ``MUJOCO_GL=egl`` is set for the workers.

``tpik-compare sweep CONFIG --executor ray`` starts a local Ray instance with ``--workers`` CPUs;
``--address ADDR`` (e.g. ``ray://head:10001`` or ``auto``) joins an existing cluster instead.
"""

from __future__ import annotations

import abc
import json
import logging
import os
import tempfile
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from compare.analysis.atomic_files import write_bytes_atomic
from compare.analysis.results import CONFIG_FILE, LOCK_FILE, SUMMARY_FILE, clear_run_results, merge_run_summary
from compare.campaign.realize import realize_with_verdict
from compare.config import Config, ConfigError
from compare.run import run_scenario

log = logging.getLogger(__name__)

EXECUTORS = ("local", "ray")
"""Names accepted by :func:`make_executor` (``--executor``)."""


@dataclass(frozen=True)
class Job:
    """One run of a sweep.

    Attributes:
        config: The seeded configuration (``scenario.seed`` set).
        config_text: The sweep's TOML text, copied into the run directory.
        run_dir: Where the run's results go (``<sweep>/runs/00042``).
        overwrite: Discard what ``run_dir`` holds first (its summary was unreadable); otherwise
            the run's methods (``config.methods.names``: the missing ones) are added to it.
    """

    config: Config
    config_text: str
    run_dir: Path
    overwrite: bool = False


Done = Callable[[Path, str | None], None]
"""Called once per finished job with its run directory and an error message (None = fine)."""


class ExecutorUnavailable(ConfigError):
    """The executor cannot be used here (e.g. Ray is not installed); the message says how to fix it."""


class SweepExecutor(abc.ABC):
    """Runs sweep jobs somewhere and reports each one as it finishes."""

    name: str = "?"

    @abc.abstractmethod
    def run(self, jobs: Sequence[Job], done: Done) -> None:
        """Run every job; call ``done`` for each as it finishes (in completion order)."""

    def describe(self) -> dict[str, Any]:
        """What ran the sweep, for ``sweep_summary.json``."""
        return {"executor": self.name}


def run_job(config: Config, config_text: str, run_dir: Path, overwrite: bool = False) -> str | None:
    """Worker body: one seed, no plots, no progress bar; returns an error message or None."""
    os.environ.setdefault("MUJOCO_GL", "egl")

    try:
        summary = run_scenario(
            config,
            run_dir,
            config_text=config_text,
            progress=False,
            make_plots=False,
            overwrite=overwrite,
            prepare=realize_with_verdict,
            report=False,
        )
    except Exception as exc:  # keep the sweep going; the run is retried on the next invocation
        return f"{type(exc).__name__}: {exc}"
    errors = summary.get("errors") or {}
    return "; ".join(f"{k}: {v}" for k, v in errors.items()) or None


def _run_local(config: Config, config_text: str, run_dir: Path, overwrite: bool) -> tuple[Path, str | None]:
    return run_dir, run_job(config, config_text, run_dir, overwrite)


class LocalExecutor(SweepExecutor):
    """Worker processes on this machine.

    Args:
        workers: Number of processes.
    """

    name = "local"

    def __init__(self, workers: int = 2) -> None:
        self.workers = max(1, int(workers))

    def run(self, jobs: Sequence[Job], done: Done) -> None:
        """Run ``jobs`` on a process pool."""
        if not jobs:
            return
        with ProcessPoolExecutor(max_workers=self.workers) as pool:
            futures = [pool.submit(_run_local, j.config, j.config_text, j.run_dir, j.overwrite) for j in jobs]
            for fut in as_completed(futures):
                run_dir, error = fut.result()
                done(run_dir, error)

    def describe(self) -> dict[str, Any]:
        """Executor name and worker count."""
        return {"executor": self.name, "workers": self.workers}


def run_packed(config: Config, config_text: str) -> tuple[dict[str, bytes], str | None]:
    """Ray worker body: run into a temporary directory and return its files (relative path → bytes)."""
    with tempfile.TemporaryDirectory(prefix="tpik-run-") as tmp:
        error = run_job(config, config_text, Path(tmp))
        files = pack(Path(tmp))
    return files, error


def pack(run_dir: Path) -> dict[str, bytes]:
    """The result files of a run directory (relative path → bytes), without its lock file."""
    return {
        p.relative_to(run_dir).as_posix(): p.read_bytes()
        for p in sorted(run_dir.rglob("*"))
        if p.is_file() and p.name != LOCK_FILE
    }


def unpack(files: dict[str, bytes], run_dir: Path, overwrite: bool = False) -> None:
    """Write a run's files into ``run_dir``, each atomically; ``summary.json`` last, merged.

    The incoming methods join those ``run_dir`` already holds (``overwrite``: the old results are
    removed first); ``config.toml`` is kept when there is one.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    if overwrite:
        clear_run_results(run_dir)
    for rel in sorted(files):
        target = run_dir / rel
        if rel == SUMMARY_FILE or (rel == CONFIG_FILE and target.exists()):
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(target, files[rel])
    if SUMMARY_FILE in files:
        merge_run_summary(run_dir, json.loads(files[SUMMARY_FILE].decode("utf-8")))


class RayExecutor(SweepExecutor):
    """One Ray task per run, on a local Ray instance or an existing cluster.

    Args:
        workers: CPUs of the local instance started when ``address`` is None (ignored otherwise).
        address: Address of a running cluster (``auto``, ``ray://host:10001``, ...); None = start
            a local instance for this sweep and stop it afterwards.
        max_in_flight: Tasks submitted ahead of the finished ones (bounds driver memory).
    """

    name = "ray"

    def __init__(self, workers: int = 2, address: str | None = None, max_in_flight: int = 64) -> None:
        try:
            import ray  # noqa: F401  # Deferred: Ray is the optional extra 'cluster'
        except ImportError:
            raise ExecutorUnavailable("--executor ray needs Ray: pip install -e '.[cluster]' (ray>=2.9)") from None
        self.workers = max(1, int(workers))
        self.address = address
        self.max_in_flight = max(1, int(max_in_flight))
        self._cluster_cpus: float | None = None

    def run(self, jobs: Sequence[Job], done: Done) -> None:
        """Submit every job as a Ray task; write each run's files as it completes."""
        import ray  # Deferred: Ray is the optional extra 'cluster'

        if not jobs:
            return
        started_here = False
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {
                "include_dashboard": False,
                "log_to_driver": False,
                "configure_logging": False,
                "runtime_env": {"env_vars": {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}},
            }
            if self.address is None:
                kwargs.update(num_cpus=self.workers, object_store_memory=200 * 1024**2)
            else:
                kwargs["address"] = self.address
            ray.init(**kwargs)
            started_here = True
        try:
            self._cluster_cpus = float(ray.cluster_resources().get("CPU", 0.0))
            task = ray.remote(num_cpus=1, max_retries=1)(run_packed)
            pending: dict[Any, Job] = {}
            queue = list(jobs)
            while queue or pending:
                while queue and len(pending) < self.max_in_flight:
                    job = queue.pop(0)
                    pending[task.remote(job.config, job.config_text)] = job
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    job = pending.pop(ref)
                    try:
                        files, error = ray.get(ref)
                    except Exception as exc:  # a lost worker or node: report, the run is redone next time
                        done(job.run_dir, f"ray: {type(exc).__name__}: {exc}")
                        continue
                    unpack(files, job.run_dir, job.overwrite)
                    done(job.run_dir, error)
        finally:
            if started_here:
                ray.shutdown()

    def describe(self) -> dict[str, Any]:
        """Executor name, address and CPUs of the cluster."""
        return {
            "executor": self.name,
            "address": self.address or "local",
            "workers": self.workers if self.address is None else None,
            "cluster_cpus": self._cluster_cpus,
        }


def make_executor(name: str, workers: int = 2, address: str | None = None) -> SweepExecutor:
    """The executor called ``name`` (``local`` or ``ray``).

    Raises:
        ExecutorUnavailable: Unknown name, ``--address`` without Ray, or Ray not installed.
    """
    if name == "local":
        if address is not None:
            raise ExecutorUnavailable("--address is only used with --executor ray")
        return LocalExecutor(workers)
    if name == "ray":
        return RayExecutor(workers, address)
    raise ExecutorUnavailable(f"unknown executor '{name}'; available: {', '.join(EXECUTORS)}")
